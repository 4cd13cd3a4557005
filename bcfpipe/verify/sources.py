"""Does a built stage still reach the scene it was built over?

``<OUT>/<scene>.bcf.usda`` sublayers the untouched input through a path relative to OUT, so a
build moves with its input. An OUT moved alone loses it, and USD then composes only the overrides:
``verify`` would check files that no longer describe a scene, and ``render`` would find no mesh.
Both ask this module first and stop with one line (exit 2) that says what does not resolve.
"""
from __future__ import annotations

import os
from pathlib import Path

from bcfpipe.errors import InputError


class SourceNotFound(InputError):
    """A built stage's sublayer (the input scene, or its overrides) does not resolve (exit 2)."""


def unresolved_sublayers(root_layer: str | os.PathLike) -> list[tuple[str, str]]:
    """(asset path as authored, where it was looked for) for every sublayer of ``root_layer`` that
    USD's resolver does not find."""
    from pxr import Ar, Sdf  # lazy: start-up

    layer = Sdf.Layer.FindOrOpen(str(root_layer))
    if layer is None:
        raise InputError(f"{root_layer}: not a USD layer that opens")
    missing = []
    for asset in layer.subLayerPaths:
        anchored = layer.ComputeAbsolutePath(asset)
        if not str(Ar.GetResolver().Resolve(anchored)):
            missing.append((asset, anchored))
    return missing


def check_sources(root_layer: str | os.PathLike) -> None:
    """Raise `SourceNotFound` when a sublayer of the built stage ``root_layer`` does not resolve."""
    missing = unresolved_sublayers(root_layer)
    if not missing:
        return
    asset, looked = missing[0]
    raise SourceNotFound(
        f"{root_layer}: its sublayer @{asset}@ does not resolve (looked for {looked}); the build folder was "
        "moved without the scene it was built over: move it back beside that scene, or rebuild it where it is now")


def root_layers(out: str | os.PathLike) -> list[Path]:
    """The built stages (``*.bcf.usda``) at the top of a build folder; none for a material folder."""
    folder = Path(out)
    return sorted(folder.glob("*.bcf.usda")) if folder.is_dir() else []
