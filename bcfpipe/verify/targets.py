"""What `bcfpipe verify` checks: one material folder, a build (its manifest), or a folder of
material folders; every reader goes through bcfpipe.formats."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path


from bcfpipe.errors import InputError
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf
from bcfpipe.formats.record import FormatError
from bcfpipe.verify.glsl import MaterialDesc, read_material


class VerifyInputError(InputError):
    """The folder is not a material / build, or a file cannot be parsed (exit code 2)."""


@dataclass
class Target:
    """One material to verify, and every name (prim path) that uses it."""

    desc: MaterialDesc
    aliases: list[str] = field(default_factory=list)  # every name (prim path) that uses it



def _manifest_targets(root: Path, manifest: mfst.Manifest) -> list[Target]:
    """The built materials of a build manifest, each decoded with its record in the combined
    weights.bin; materials sharing one trained folder and record are verified once (the others
    are kept as aliases)."""
    combined = root / manifest.weights
    by_key: dict[tuple, Target] = {}
    for e in manifest.built():
        if e.outputs is None:
            raise VerifyInputError(f"{root / mfst.FILE}: built material {e.path} has no outputs")
        folder = root / e.outputs.folder
        if not (folder / mf.FILE).is_file():
            raise VerifyInputError(f"{root / mfst.FILE} lists {folder}, which has no {mf.FILE}")
        if not combined.is_file():
            raise VerifyInputError(f"{root / mfst.FILE} points into {combined}, which is missing")
        key = (str(folder.resolve()), e.outputs.weights_offset)
        if key in by_key:
            by_key[key].aliases.append(e.path)
            continue
        if e.outputs.weights_offset is None:  # a --layout auto material of classic textures only
            by_key[key] = Target(read_material(folder, name=e.path), [e.path])
            continue
        by_key[key] = Target(read_material(folder, combined, e.outputs.weights_offset, name=e.path), [e.path])
    return list(by_key.values())


def find_targets(path: str | os.PathLike) -> list[Target]:
    """A material folder (material.json), a build folder (manifest.json), or any folder whose
    subfolders (one or two levels down) hold material.json files."""
    root = Path(path)
    if not root.is_dir():
        raise VerifyInputError(f"{root}: not a folder")
    try:
        if (root / mf.FILE).is_file():
            return [Target(read_material(root))]
        if (root / mfst.FILE).is_file():  # a build: exactly what it built (possibly nothing)
            return _manifest_targets(root, mfst.read(root))
        found = sorted({p.parent for pat in ("*/" + mf.FILE, "*/*/" + mf.FILE) for p in root.glob(pat)})
        targets = [Target(read_material(f, name=str(f.relative_to(root)))) for f in found]
    except FormatError as ex:
        raise VerifyInputError(str(ex)) from None
    if not targets:
        raise VerifyInputError(f"{root}: no {mf.FILE} or {mfst.FILE} here or in its subfolders")
    return targets
