"""`bcfpipe verify` on the constants a build folded (issue #18): through USD, the composed output
stage gives each folded UsdPreviewSurface input the value manifest.json records, with no texture
connected; through OpenImageIO, every texel of each folded source channel is within one 8-bit
step (or one fp16 ulp) of the stored value the build used."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import images
from bcfpipe.formats.images import channel_index as source_channel_index
from bcfpipe.formats.usd_schema import component_index

VALUE_TOLERANCE = 1e-6  # the value is authored as a float: rounding only


def check_usd_values(root: Path, manifest: mfst.Manifest, material: mfst.Material, stage) -> list[str]:
    """Problems with the composed values of ``material``'s constants (empty: all as recorded)."""
    from pxr import UsdShade  # lazy: start-up

    prim = stage.GetPrimAtPath(material.path)
    if not prim:
        return [f"{material.path} is not on the composed stage {manifest.root_layer}"]
    surface, _, _ = UsdShade.Material(prim).ComputeSurfaceSource("")
    if not surface:
        return [f"{material.path} has no surface shader on the composed stage"]
    problems = []
    for c in material.constants:
        inp = surface.GetInput(c.input)
        if not inp or inp.HasConnectedSource():
            problems.append(f"{c.input} is still connected to a texture")
            continue
        v = inp.Get()
        if hasattr(v, "__len__"):  # a vector input: the target's component (a scalar target fills all)
            v = v[component_index(c.target) or 0]
        got = float(v)
        if not abs(got - c.value) <= VALUE_TOLERANCE * max(1.0, abs(c.value)):
            problems.append(f"{c.target} is {got:.6g} on the stage, manifest.json says {c.value:.6g}")
    return problems


def check_source_constancy(root: Path, material: mfst.Material) -> list[str]:
    """Every texel of each channel folded as constant lies within one step of its stored value."""
    from bcfpipe.scan.sources import local_file, package_split  # lazy: start-up

    problems = []
    for f in material.folded:
        if f.reason != "constant":
            continue
        path = f.source if Path(f.source).is_absolute() or package_split(f.source) else str(root / f.source)
        with tempfile.TemporaryDirectory() as tmp:
            try:
                im = images.read(local_file(path, tmp), as_float=True, unassociated_alpha=True, name=f.source)
            except images.ImageReadError as exc:
                problems.append(str(exc))
                continue
        px = im.pixels
        idx = source_channel_index(im.names, f.channel, path)
        is_float = im.is_float
        step = float(np.spacing(np.float16(abs(f.value or 0.0)))) if is_float else 1.0 / 255.0
        worst = float(np.abs(px[..., idx].astype(np.float64) - float(f.value)).max())
        if worst > step + 1e-9:
            problems.append(f"{f.source}:{f.channel} is not constant: a texel differs by {worst:.4g} "
                            f"from {f.value:.6g}")
    return problems


def check_constants(root: Path, manifest: mfst.Manifest) -> list[tuple[str, bool, str]]:
    """(material, passed, detail) for every material of a build with folded constants."""
    from pxr import Usd  # lazy: start-up

    with_constants = [m for m in manifest.materials if m.constants or any(f.reason == "constant" for f in m.folded)]
    # unread channels (st not connected) are checked through their USD values only: the texture varies
    if not with_constants:
        return []
    from bcfpipe.scan.composition import captured_diagnostics  # lazy: start-up

    with captured_diagnostics():  # the build reported the scene's composition errors already
        stage = Usd.Stage.Open(str(root / manifest.root_layer))
    out = []
    for m in with_constants:
        problems = check_usd_values(root, manifest, m, stage) + check_source_constancy(root, m)
        n = len(m.constants)
        out.append((m.path, not problems, "; ".join(problems) or
                    f"{n} input value(s) on the composed stage as recorded, not connected; "
                    f"{sum(f.reason == 'constant' for f in m.folded)} source channel(s) constant within one step"))
    return out
