"""`build`: plan, execute and assemble into a staging folder, then swap it in as OUT."""
from __future__ import annotations

import concurrent.futures as cf
import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

from bcfpipe.config import (DEFAULT_DEVICE, DEFAULT_HIDDEN, DEFAULT_INIT, DEFAULT_PRESET, DEFAULT_PROFILE,
                            DEFAULT_SEED)
from bcfpipe.errors import EXIT_OK
from bcfpipe.build.assemble import assemble, default_out
from bcfpipe.build.executor import execute
from bcfpipe.formats.manifest import FILE as MANIFEST, Manifest, is_manifest
from bcfpipe.build.plan import BuildError, BuildPlan, MATERIALS_DIR, ProgressCallback, plan
from bcfpipe.scan.texture_sets import package_split


@dataclass(frozen=True)
class BuildResult:
    """A finished build: where it is and what its manifest says."""

    out: Path
    root_layer: Path
    manifest: Manifest
    plan: BuildPlan

    @property
    def exit_code(self) -> int:
        return self.manifest.exit_code

    @property
    def ok(self) -> bool:
        return self.exit_code == EXIT_OK

    @property
    def failed(self) -> list[str]:
        return self.manifest.failed()


def _is_within(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
        return True
    except ValueError:
        return False


def check_out(out: Path, force: bool, inputs: Iterable[str | os.PathLike]) -> None:
    """Refuse an OUT that would overwrite inputs, or a folder not written by bcfpipe (without force)."""
    for p in inputs:
        p = Path(str(p).split("[", 1)[0]) if package_split(str(p)) else Path(p)
        if _is_within(p, out):
            raise BuildError(f"output folder {out} contains the input {p}; choose another -o")
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir():
        raise BuildError(f"output {out} exists and is not a folder")
    if force or is_manifest(out) or not any(out.iterdir()):
        return
    raise BuildError(f"output folder {out} exists and was not written by bcfpipe (no {MANIFEST}); "
                     "use --force to replace it")


def _install(staging: Path, out: Path) -> None:
    """Move the finished staging folder to ``out`` (replacing an old build)."""
    old = None
    if out.exists() or out.is_symlink():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.replace(out, old)
    os.replace(staging, out)
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


def build(scene: str | os.PathLike, out: str | os.PathLike | None = None, *,
          variants: Mapping[str, str] | Iterable[str] | None = None, all_materials: bool = False,
          profile: str = DEFAULT_PROFILE, preset: str = DEFAULT_PRESET, jobs: int | None = None,
          device: str = DEFAULT_DEVICE, seed: int = DEFAULT_SEED, hidden: int = DEFAULT_HIDDEN, signed: bool = False,
          init: str = DEFAULT_INIT, force: bool = False, progress: ProgressCallback | None = None,
          executor: cf.Executor | None = None, threads: int | None = None) -> BuildResult:
    """Build neural materials for ``scene`` into ``out`` (default ``<scene>.bcf/`` next to it); the
    Python twin of ``bcfpipe build``.

    ``variants``: {set: value} or ["set=value", ...]. ``jobs``: worker processes (default: one per
    core, or per GPU, at most one per job). ``threads``: torch threads per worker (default
    ``config.DEFAULT_THREADS``, 1). ``progress``: a callable receiving event dicts (see
    `execute`). Raises `BuildError` (exit code 2) before any training for bad input or a refused
    ``out``; per-material failures are reported in the result (``exit_code`` 1), never raised.
    """
    t0 = time.perf_counter()
    if jobs is not None and int(jobs) < 1:
        raise BuildError("--jobs must be at least 1")
    if threads is not None and int(threads) < 1:
        raise BuildError("--threads must be at least 1")
    scene_path = Path(scene)
    out_path = Path(out).resolve() if out is not None else default_out(scene_path)
    # Refuse early: before the scan reads every texture, and again once the sources are known.
    check_out(out_path, force, [scene_path])
    bplan = plan(scene_path, variants, all_materials, profile, preset, seed, device, hidden, signed, init)
    check_out(out_path, force, [bplan.scene, *bplan.sources])
    out_path.parent.mkdir(parents=True, exist_ok=True)
    staging = out_path.parent / f".{out_path.name}.tmp-{uuid.uuid4().hex[:8]}"
    staging.mkdir()
    try:
        results = execute(bplan.jobs, staging / MATERIALS_DIR, workers=jobs, executor=executor, progress=progress,
                          threads=threads)
        manifest = assemble(bplan, results, staging, out_path, time.perf_counter() - t0)
        _install(staging, out_path)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return BuildResult(out_path, out_path / manifest.root_layer, manifest, bplan)
