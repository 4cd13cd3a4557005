"""What a bench measures: texture sets named by the user (the `train` syntax) or by a scene's materials."""
from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from bcfpipe.builder import Selection, plan
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.errors import InputError
from bcfpipe.texset.texture_set import TextureSet, TextureSpec
from bcfpipe.texset.texture_set import load_texture_set

__all__ = ["BenchSet", "from_specs", "from_scene"]


@dataclass(frozen=True)
class BenchSet:
    name: str
    specs: tuple[TextureSpec, ...]
    wrap: str = Wrap.REPEAT
    materials: tuple[str, ...] = ()

    @property
    def slug(self) -> str:
        """A file-name-safe form of the name, for the report's PNGs."""
        return re.sub(r"[^A-Za-z0-9_.-]+", "_", self.name.strip("/")).strip("_") or "set"

    def load(self) -> TextureSet:
        try:
            return load_texture_set(list(self.specs))
        except ValueError as e:
            raise InputError(f"{self.name}: {e}") from None

    def display_specs(self) -> list[str]:
        """The specs with file names only: the report carries no absolute paths."""
        return [str(TextureSpec(s.semantic, Path(s.path).name, s.channels)) for s in self.specs]


def from_specs(texts: Sequence[str], name: str | None = None, wrap: str = Wrap.REPEAT) -> BenchSet:
    """One set from `SEMANTIC=FILE[:CHANNELS]` texts; named after the first file unless ``name``."""
    try:
        specs = tuple(TextureSpec.parse(t) for t in texts)
    except ValueError as e:
        raise InputError(str(e)) from None
    for s in specs:
        if not os.path.isfile(s.path):
            raise InputError(f"no such texture: {s.path}")
    return BenchSet(name or Path(specs[0].path).stem, specs, wrap)


def from_scene(scene: str | os.PathLike, materials: Iterable[str] = (),
               variants: Mapping[str, str] | None = None) -> list[BenchSet]:
    """One set per training job the build would run (materials with the same textures share one);
    ``materials`` keeps the jobs that hold any of those prims (a path or its last component)."""
    bplan = plan(scene, selection=Selection(variants, coverage=False))
    want = list(materials)
    out = []
    for job in bplan.jobs:
        names = {n for m in job.materials for n in (m, m.rstrip("/").rsplit("/", 1)[-1])}
        if want and not names.intersection(want):
            continue
        specs = tuple(TextureSpec(sem, path, ch) for sem, path, ch in job.specs)
        out.append(BenchSet(job.materials[0], specs, job.wrap, tuple(job.materials)))
    missing = [m for m in want if not any(m in {n for x in s.materials for n in (x, x.rsplit("/", 1)[-1])}
                                          for s in out)]
    if missing:
        raise InputError(f"{scene}: no modelled material {', '.join(missing)}; "
                         f"it has {', '.join(m for j in bplan.jobs for m in j.materials) or 'none'}")
    if not out:
        raise InputError(f"{scene}: no material to model (see `bcfpipe scan {scene}`)")
    return out
