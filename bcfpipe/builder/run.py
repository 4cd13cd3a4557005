"""`build`: plan; take what the cache holds; train the rest; assemble into a staging folder; then
install it as OUT, writing only the files that changed."""
from __future__ import annotations

import contextlib
import json
import logging
import os
import sys
import shutil
import time
import uuid
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Iterable

from bcfpipe.builder.executor import JobResult, cached_result, execute, set_exr_threads
from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.config import TrainingOptions
from bcfpipe.errors import EXIT_OK, InputError, WorkFailed
from bcfpipe.builder.assemble import assemble, default_out
from bcfpipe.builder.depfile import dependencies, write as write_depfile
from bcfpipe.builder.events import EventKind, ProgressCallback, ProgressEvent, result_psnr
from bcfpipe.builder.report import BuildFacts, make_report
from bcfpipe.builder.sync import OUT_LOCK, STAGING_PREFIX, install, is_incomplete
from bcfpipe.cache import Cache, default_root
from bcfpipe.formats.report import BuildReport
from bcfpipe.formats.manifest import FILE as MANIFEST, Manifest, is_manifest
from bcfpipe.builder.plan import BuildError, BuildPlan, MATERIALS_DIR, plan
from bcfpipe.builder.options import Execution, ExecutorName, Selection
from bcfpipe.pooltrace import trace_pool
from bcfpipe.scan.sources import package_split
from bcfpipe.texset.blocks import blocks_in
from bcfpipe.train.fused.common import kernels_in


log = logging.getLogger("bcfpipe.build")


@dataclass(frozen=True)
class BuildResult:
    """A finished build: where it is and what its manifest says."""

    out: Path
    root_layer: Path
    manifest: Manifest
    plan: BuildPlan
    report: BuildReport

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


def _file_of(path: str | os.PathLike) -> Path:
    """The file on disk of an asset path (a packaged ``pkg.usdz[inner.png]`` is its package)."""
    return Path(str(path).split("[", 1)[0]) if package_split(str(path)) else Path(path)


def _built_scene(out: Path) -> Path | None:
    """The scene whose build ``out`` holds (manifest.json's scene, resolved), or None."""
    try:
        scene = json.loads((out / MANIFEST).read_text()).get("scene")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(scene, str) or not scene:
        return None
    p = _file_of(scene)
    return (out / p).resolve() if not p.is_absolute() else p.resolve()


def check_out(out: Path, force: bool, inputs: Iterable[str | os.PathLike],
              scene: Path | None = None) -> Path | None:
    """Refuse an OUT that would overwrite inputs, a folder bcfpipe did not write (even with
    ``force``: only a folder holding our manifest, or our own leftovers, is ever replaced), or the
    build of another scene than ``scene`` unless ``force``. Returns that other scene when ``force``
    lets its build be replaced (the caller says so once), else None."""
    for p in map(_file_of, inputs):
        if _is_within(p, out):
            raise BuildError(f"output folder {out} contains the input {p}; choose another -o")
    if not out.exists() and not out.is_symlink():
        return None
    if not out.is_dir():
        raise BuildError(f"output {out} exists and is not a folder")
    if is_incomplete(out) or not any(out.iterdir()):
        return None
    if not is_manifest(out):
        raise BuildError(f"output folder {out} exists and was not written by bcfpipe (no {MANIFEST}); "
                         "bcfpipe replaces only its own builds, even with --force: choose another -o")
    other = _built_scene(out)
    if scene is None or other is None or other == Path(scene).resolve():
        return None
    if not force and not other.exists():
        raise BuildError(f"output folder {out} holds a build whose scene ({other}, recorded relative to the folder) "
                         "does not exist: the folder was moved, or its scene deleted; use --force to replace it, "
                         "or choose another -o")
    if not force:
        raise BuildError(f"output folder {out} holds the build of another scene ({other}); "
                         "use --force to replace it, or choose another -o")
    return other


class OutputError(WorkFailed):
    """OUT could not be written once the work ran: disk full while installing, ... (exit code 1)."""


class OutputRefused(InputError):
    """OUT cannot be created or written at all (read-only, under a file, no permission): refused
    before any work, nothing written (exit code 2, as a refused OUT)."""


def _why(exc: BaseException) -> str:
    """The OS's reason (strerror) of a failed write, from an OSError or a pxr error text."""
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    text = str(exc)
    for reason in ("No space left on device", "Read-only file system", "Permission denied", "Disk quota exceeded"):
        if reason in text:
            return reason
    return " ".join(text.split())[:200]


def _stale_staging(out: Path) -> None:
    """Remove staging folders of killed builds of ``out`` (their writer's pid is gone)."""
    for d in out.glob(f"{STAGING_PREFIX}*"):
        try:
            pid = int((d / _PID).read_text())
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(d, ignore_errors=True)
        except (OSError, ValueError):
            pass  # alive, not ours, or being created: leave it


_PID = ".bcfpipe-pid"


def _abandon(staging: Path, out: Path, created: bool) -> None:
    """Remove a failed build's staging folder, and OUT itself (with its lock) if this build
    created it and nothing else is in it."""
    shutil.rmtree(staging, ignore_errors=True)
    if created and all(p.name == OUT_LOCK for p in _listing(out)):
        try:
            (out / OUT_LOCK).unlink(missing_ok=True)
            out.rmdir()
        except OSError:
            pass


def _listing(folder: Path) -> list[Path]:
    try:
        return list(folder.iterdir())
    except OSError:
        return []


def _cached(bplan: BuildPlan, cache: Cache | None, materials_dir: Path,
            progress: ProgressCallback | None) -> tuple[dict[str, JobResult], list[str]]:
    """Jobs found in the cache, copied into ``materials_dir``; and the damaged entries met."""
    hits: dict[str, JobResult] = {}
    damaged: list[str] = []
    if cache is None:
        return hits, damaged
    for job in bplan.jobs:
        found = cache.lookup(job.content_hash)
        if found.problem:
            damaged.append(f"{job.name}: cache entry {job.content_hash} was damaged ({found.problem}); retraining")
            log.warning(damaged[-1])
        result = cached_result(found.entry) if found.entry is not None else None
        if result is None:  # none, or a result this version does not read: the worker trains it
            continue
        try:
            found.entry.copy_to(materials_dir / job.name)
        except OSError:  # pruned meanwhile: the worker trains it
            shutil.rmtree(materials_dir / job.name, ignore_errors=True)
            continue
        hits[job.name] = JobResult(job.name, Status.BUILT, None, 0.0, job.options.device, 0, result, CacheUse.HIT)
        if progress:
            progress(ProgressEvent(EventKind.DONE, job.name, job.materials, status=Status.BUILT,
                                   psnr=result_psnr(result), seconds=0.0, cache=CacheUse.HIT))
    return hits, damaged


def build(scene: str | os.PathLike, out: str | os.PathLike | None = None, *,
          training: TrainingOptions = TrainingOptions(), selection: Selection = Selection(),
          execution: Execution = Execution(), progress: ProgressCallback | None = None) -> BuildResult:
    """Build neural materials for ``scene`` into ``out`` (default ``<scene>.bcf/`` next to it); the
    Python twin of ``bcfpipe build``.

    ``training``: the training choices, whole (config.TrainingOptions; its ``threads`` are torch
    threads per worker). ``selection``: which materials, and what the scene needs (`Selection`).
    ``execution``: workers, executor, cache, depfile and --force (`Execution`). ``progress``: a
    callable receiving `ProgressEvent`s (see `execute`). Raises `BuildError` (exit code 2) before
    any training for bad input or a refused ``out``; per-material failures are reported in the
    result (``exit_code`` 1), never raised.
    """
    t0 = time.perf_counter()
    if execution.jobs is not None and int(execution.jobs) < 1:
        raise BuildError("--jobs must be at least 1")
    with driver_threads(execution.jobs):
        return _build(scene, out, training, selection, execution, progress, t0)


@contextlib.contextmanager
def driver_threads(jobs: int | None):
    """With ``--jobs N``, the build's own reads (the scan's OpenImageIO, torch where loaded) use at
    most N threads meanwhile; restored after (issue 58). Without it nothing changes."""
    if jobs is None:
        yield
        return
    import OpenImageIO as oiio  # lazy: start-up

    n = max(1, int(jobs))
    before, exr_before = oiio.get_int_attribute("threads"), oiio.get_int_attribute("exr_threads")
    oiio.attribute("threads", min(n, before) if before > 0 else n)
    trace_pool("oiio", oiio.get_int_attribute("threads"), where="driver")
    set_exr_threads(oiio, min(n, exr_before) if exr_before > 0 else n)
    torch = sys.modules.get("torch")  # not imported here for this: the driver trains nothing
    t_before = torch.get_num_threads() if torch is not None else None
    if torch is not None:
        torch.set_num_threads(min(n, t_before))
        trace_pool("torch-intra-op", torch.get_num_threads(), where="driver")
    try:
        yield
    finally:
        oiio.attribute("threads", before)
        oiio.attribute("exr_threads", exr_before)
        if torch is not None:
            torch.set_num_threads(t_before)


def _build(scene, out, training: TrainingOptions, selection: Selection, execution: Execution,
           progress: ProgressCallback | None, t0: float) -> BuildResult:
    scene_path = Path(scene)
    out_given = Path(out) if out is not None else default_out(scene_path, resolve=False)
    out_path = out_given.resolve()
    # Refuse early: before the scan reads every texture, and again once the sources are known.
    check_out(out_path, execution.force, [scene_path], scene_path)
    cache = execution.cache
    store = None if cache is False else Cache(default_root() if cache in (None, True) else cache)
    bplan = plan(scene_path, training, selection, facts=store.facts if store is not None else None)
    check_out(out_path, execution.force, [bplan.scene, *bplan.sources], scene_path)
    # staging lives inside OUT (nothing is written outside OUT and the cache) and on its filesystem,
    # so that installing a file is one rename
    staging = out_path / f"{STAGING_PREFIX}{uuid.uuid4().hex[:8]}"
    created = not out_path.exists()
    try:
        out_lock = _lock_out(out_path)
    except OSError as exc:
        _abandon(staging, out_path, created)
        raise OutputRefused(f"cannot write {out_path}: {_why(exc)}") from None
    try:
        # another build may have written OUT while this one waited: the rules again, under the lock
        replaced = check_out(out_path, execution.force, [bplan.scene, *bplan.sources], scene_path)
        if replaced is not None:
            log.warning("replacing the build of %s in %s (--force)", replaced, out_path)
        run = _Run(bplan, out_path, out_given, staging, created, store, t0)
        return _build_locked(run, execution, training.threads, progress)
    finally:
        out_lock.release()


@dataclass(frozen=True)
class _Run:
    """One build under way: its plan, OUT (resolved and as given), staging folder and cache."""

    bplan: BuildPlan
    out: Path
    out_given: Path
    staging: Path
    created: bool  # this build created OUT (a failure removes it again)
    store: Cache | None
    t0: float


def _lock_out(out: Path):
    """OUT's lock (``OUT/.bcfpipe-lock``), acquired: concurrent builds into one OUT take turns, so
    OUT is always one build's complete output. A build that has to wait says so once. The lock
    file stays (removing a lock file others may wait on would let two builds in); a first build
    that fails removes OUT with it, and a build that waited on it then starts over."""
    from filelock import FileLock, Timeout  # lazy: start-up

    said = False
    while True:
        out.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(out / OUT_LOCK))
        try:
            lock.acquire(timeout=0)
        except Timeout:
            if not said:
                log.warning("waiting for another bcfpipe build into %s to finish", out)
                said = True
            lock.acquire()
        if (out / OUT_LOCK).exists():
            return lock
        lock.release()


def _build_locked(run: _Run, execution: Execution, threads: int | None,
                  progress: ProgressCallback | None) -> BuildResult:
    """The build proper, with OUT's lock held: stage, train what the cache lacks, assemble, install."""
    bplan, staging, out_path = run.bplan, run.staging, run.out
    try:
        _stale_staging(out_path)
        staging.mkdir()
        (staging / _PID).write_text(str(os.getpid()))
    except OSError as exc:
        _abandon(staging, out_path, run.created)
        raise OutputRefused(f"cannot write {out_path}: {_why(exc)}") from None
    if progress:  # every job is known from the start: progress counts "k of all"
        for job in bplan.jobs:
            progress(ProgressEvent(EventKind.QUEUED, job.name, job.materials))
    try:
        results, damaged = _cached(bplan, run.store, staging / MATERIALS_DIR, progress)
        todo = [j for j in bplan.jobs if j.name not in results]
        results.update(_train(todo, run, execution, threads, progress))
        (staging / _PID).unlink()
        manifest = assemble(bplan, results, staging, out_path)
        files = sorted(p.relative_to(staging).as_posix() for p in staging.rglob("*") if p.is_file())
        written = install(staging, out_path, manifest.root_layer)
    except BaseException as exc:
        _abandon(staging, out_path, run.created)
        if isinstance(exc, OSError) or type(exc).__name__ == "ErrorException":  # pxr's Tf errors too
            raise OutputError(f"cannot write {out_path}: {_why(exc)}; OUT was left as it was "
                              "(or, if this happened while files were replaced, is marked incomplete and is "
                              "repaired by the next build)") from None
        raise
    dep = None
    if execution.depfile is not None:
        target = execution.depfile_target or (run.out_given / manifest.root_layer).as_posix()
        dep = str(write_depfile(execution.depfile, target, dependencies(bplan.layers, bplan.sources)))
    store = run.store
    facts = BuildFacts(str(run.out_given), files, written, str(store.root) if store else None, damaged,
                       time.perf_counter() - run.t0, dep, execution.executor)
    report = make_report(manifest, results, facts)
    return BuildResult(out_path, out_path / manifest.root_layer, manifest, bplan, report)


def _train(todo: list, run: _Run, execution: Execution, threads: int | None,
           progress: ProgressCallback | None) -> dict[str, JobResult]:
    """Train the jobs the cache lacks into the staging folder, on the executor ``execution`` names."""
    root = run.store.root if run.store else None
    if execution.executor == ExecutorName.RAY:
        from bcfpipe.builder.ray_executor import execute_ray  # lazy: cycle

        done, attempts = execute_ray(todo, run.staging / MATERIALS_DIR, execution.ray_address, threads=threads,
                                     progress=progress, cache_root=root, cores=execution.jobs)
        return {k: replace(r, attempts=attempts.get(k, 1)) for k, r in done.items()}

    # compiled kernels and BC@R's blocks in the build's cache
    with kernels_in(root), blocks_in(run.store.base if run.store else None):
        return execute(todo, run.staging / MATERIALS_DIR, workers=execution.jobs, executor=execution.pool,
                       progress=progress, threads=threads, cache_root=root)
