"""Step 4 of a build: install the staging folder as OUT, writing only what changed.

The staging folder is inside OUT (``.bcfpipe-staging-*``), on the same filesystem. A file whose
bytes are unchanged is not touched, so its mtime stays and build systems downstream
see nothing new; a no-op rebuild leaves OUT exactly as it was. Changed files are moved in one by
one with an atomic rename each (a reader sees the old file or the new one), manifest.json and the
root layer last. While files are being replaced OUT holds a ``.bcfpipe-incomplete`` marker: a
build killed then leaves it behind, and the next build (which accepts such an OUT) replaces
everything that differs and removes it.
"""
from __future__ import annotations

import filecmp
import os
import shutil
from pathlib import Path

from bcfpipe.formats.manifest import FILE as MANIFEST

INCOMPLETE = ".bcfpipe-incomplete"
STAGING_PREFIX = ".bcfpipe-staging-"
OUT_LOCK = ".bcfpipe-lock"  # held by the build writing OUT (bcfpipe.builder.run)


def _ours(rel: Path) -> bool:
    """bcfpipe's own bookkeeping in OUT: the marker, the lock and staging folders."""
    return rel.name in (INCOMPLETE, OUT_LOCK) or rel.parts[0].startswith(STAGING_PREFIX)


def _files(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")
            if (p.is_file() or p.is_symlink()) and not _ours(p.relative_to(folder))}


def _same(a: Path, b: Path) -> bool:
    return b.is_file() and not b.is_symlink() and filecmp.cmp(a, b, shallow=False)


def _last(root_layer: str):
    """Sort key: material files first, then the shared files, manifest.json and the root layer last."""
    def key(rel: str) -> tuple[int, str]:
        return (3 if rel == MANIFEST else 2 if rel == root_layer else 1 if "/" not in rel else 0, rel)
    return key


def is_incomplete(out: Path) -> bool:
    """OUT is being (or was, by a killed build) written by bcfpipe: it holds the marker, or
    nothing but staging folders (a first build that was interrupted)."""
    return (out / INCOMPLETE).exists() or (any(out.iterdir()) and all(_ours(Path(p.name)) for p in out.iterdir()))


def install(staging: Path, out: Path, root_layer: str) -> list[str]:
    """Make ``out`` hold exactly the files of ``staging`` (a folder inside it) and remove
    ``staging``; returns the files created or replaced (relative to ``out``), in write order."""
    if out.is_symlink() or not out.is_dir():
        raise FileExistsError(f"{out} is not a folder")
    new, old = _files(staging), _files(out)
    changed = sorted((f for f in new if not _same(staging / f, out / f)), key=_last(root_layer))
    removed = sorted(old - new)
    if changed or removed or is_incomplete(out):
        (out / INCOMPLETE).touch()
        for rel in changed:
            dst = out / rel
            dst.parent.mkdir(parents=True, exist_ok=True)
            if dst.is_dir() and not dst.is_symlink():
                shutil.rmtree(dst)
            os.replace(staging / rel, dst)
        for rel in removed:
            (out / rel).unlink(missing_ok=True)
        for d in sorted((p for p in out.rglob("*") if p.is_dir() and not p.is_symlink()
                         and not _ours(p.relative_to(out))), reverse=True):
            if not any(d.iterdir()):
                d.rmdir()
        (out / INCOMPLETE).unlink(missing_ok=True)
    shutil.rmtree(staging, ignore_errors=True)
    return changed
