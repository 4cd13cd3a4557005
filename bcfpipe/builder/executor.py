"""Step 2 of a build: train the jobs, each in its own worker process (the local executor)."""
from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import math
import multiprocessing as mp
import os
import queue as queue_mod
import sys
import tempfile
import time
import warnings
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import xxhash

from bcfpipe.cache import Cache
from bcfpipe.formats.fit_result import FitResult
from bcfpipe.formats.record import FormatError
from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.config import DEFAULT_THREADS
from bcfpipe.errors import one_line
from bcfpipe.builder.events import EventKind, ProgressCallback, ProgressEvent, result_psnr
from bcfpipe.builder.plan import MaterialJob
from bcfpipe.errors import WorkFailed
from bcfpipe.pooltrace import trace_pool
from bcfpipe.scan.coverage import unpack
from bcfpipe.scan.sources import package_split, read_asset
from bcfpipe.texset import heap
from bcfpipe.texset.parallel import job_encode_workers
from bcfpipe.texset.parallel import release_workers, set_encode_workers
from bcfpipe.texset.texture_set import TextureSpec, load_texture_set




def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _gpu_count(device: str) -> int:
    if not device.startswith("cuda"):
        return 0
    import torch  # lazy: start-up

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def default_jobs(n_jobs: int, device: str = "cpu") -> int:
    """Worker count: one per GPU on CUDA, else one per core; never more than there are jobs."""
    gpus = _gpu_count(device)
    limit = gpus if gpus else cpu_count()
    return max(1, min(max(n_jobs, 1), limit))


@dataclass(frozen=True)
class Shares:
    """How a build's jobs share the cores: ``workers`` jobs side by side, each with ``threads``
    torch (and OpenImageIO, fused-kernel, BC6H) threads and ``encode`` BC encode workers."""

    workers: int
    threads: int
    encode: int


def core_shares(n_jobs: int, jobs: int | None, threads: int, device: str = "cpu") -> Shares:
    """The cores of a build's ``n_jobs`` jobs (issue 58).

    ``jobs`` (``--jobs N``) is the build's cores: at most N busy at once. N // ``threads`` jobs
    train side by side (at least 1, at most ``n_jobs``), and each job's share is N // that: its
    threads are at most its share, its encodes use its share (`job_encode_workers`). ``--jobs 1``:
    one job at a time on one core everywhere (torch 1 thread, encodes inline).
    Without ``jobs``: one job per core (per GPU on CUDA), each with ``threads``, its encodes on the
    cores the parallel jobs leave each (at least ``threads``), as fast as the machine allows.
    """
    threads = max(1, int(threads))
    if jobs is None:
        workers = default_jobs(n_jobs, device)
        return Shares(workers, threads, job_encode_workers(threads, min(workers, max(n_jobs, 1))))
    cores = max(1, int(jobs))
    workers = max(1, min(max(n_jobs, 1), cores // threads))
    return Shares(workers, min(threads, cores // workers), job_encode_workers(threads, workers, cores))


@dataclass(frozen=True)
class JobResult:
    """What one job's worker reported: its `FitResult` when built."""

    name: str
    status: str  # built | failed
    reason: str | None
    seconds: float
    device: str
    threads: int
    result: FitResult | None = None
    cache: str | None = None  # "hit" / "miss" with a cache, None without
    attempts: int = 1  # > 1: its worker died and it ran again

    def to_dict(self) -> dict:
        """JSON-able, for a worker's pipe or Ray's object store (`from_dict` reads it back)."""
        return {**{f.name: getattr(self, f.name) for f in fields(self)},
                "result": self.result.to_json() if self.result is not None else None}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "JobResult":
        r = d.get("result")
        return cls(**{**d, "result": FitResult.from_json(r, "result") if r is not None else None})


class _Throttle:
    """Forwards a worker's training progress to the parent's queue, at most ~4 times a second."""

    def __init__(self, queue, name: str):
        self.queue, self.name, self.last_phase, self.last = queue, name, None, 0.0

    def __call__(self, p) -> None:
        now = time.monotonic()
        if p.phase == self.last_phase and now - self.last < 0.25 and p.step != p.steps:
            return
        self.last_phase, self.last = p.phase, now
        psnr = p.psnr if p.psnr == p.psnr and math.isfinite(p.psnr) else None
        self.queue.put(ProgressEvent(EventKind.PROGRESS, self.name, phase=p.phase, step=p.step, steps=p.steps,
                                     psnr=psnr, eta=p.eta, elapsed=p.elapsed))

    def phase(self, phase: str) -> None:
        self.queue.put(ProgressEvent(EventKind.PROGRESS, self.name, phase=phase))


def run_job(job: Mapping[str, Any], out_dir: str, threads: int, device: str, queue=None,
            cache_root: str | None = None, encode_workers: int | None = None) -> dict:
    """Train and export one job into ``out_dir`` (runs in a worker process; never raises).

    With ``cache_root`` the job holds its key's lock while it works: an entry that another build
    stored meanwhile is copied instead of trained (a hit), and a trained result is stored. Returns
    a `JobResult` as a dict. Only this process's own thread settings are changed. BC encodes use
    ``encode_workers`` cores (default ``threads``: bcfpipe.texset.parallel).
    """
    heap.one_arena()  # the job's threads reuse the heap as the fit does (a worker starts none before)
    try:
        return _run_job(job, out_dir, threads, device, queue, cache_root, encode_workers)
    finally:
        if queue is not None:
            with contextlib.suppress(Exception):
                queue.put(ProgressEvent(EventKind.RETURNED, job.get("name", "?")))


def _run_job(job: Mapping[str, Any], out_dir: str, threads: int, device: str, queue, cache_root: str | None,
             encode_workers: int | None = None) -> dict:
    t0 = time.perf_counter()
    name = job.get("name", "?")
    if cache_root is None:
        return train_job(job, out_dir, threads, device, queue, t0, encode_workers=encode_workers)

    try:
        cache = Cache(cache_root)
        key = job["content_hash"]
        with cache.lock(key):
            found = cache.lookup(key)
            if found.entry is not None and (cached := cached_result(found.entry)) is not None:
                found.entry.copy_to(out_dir)
                return JobResult(name, Status.BUILT, None, time.perf_counter() - t0, device, threads,
                                 cached, CacheUse.HIT).to_dict()
            r = JobResult.from_dict(train_job(job, out_dir, threads, device, queue, t0, encode_workers=encode_workers))
            if r.status == Status.BUILT:
                store_entry(cache, key, out_dir, r.result, name)
            return replace(r, cache=CacheUse.MISS).to_dict()
    except BaseException as exc:  # noqa: BLE001 - a failing material must not stop the build
        return JobResult(name, Status.FAILED, one_line(exc), time.perf_counter() - t0, device, threads).to_dict()


def cached_result(entry) -> FitResult | None:
    """A cache entry's result as its record (`bcfpipe.cache.store.Entry.result` holds its JSON);
    None when it does not read as one (the job trains again)."""
    try:
        return FitResult.from_json(entry.result, f"cache entry {entry.key}")
    except FormatError:
        return None


def store_entry(cache, key: str, folder: str | os.PathLike, result: FitResult, name: str,
                take_lock: bool = False) -> None:
    """Put a trained job into the cache, with the key's lock held (by the caller, or taken here).
    A full or read-only cache costs a retrain later, not this build: a warning, not an error."""
    try:
        with cache.lock(key) if take_lock else contextlib.nullcontext():
            cache.put(key, folder, result.to_json())
    except OSError as exc:
        logging.getLogger("bcfpipe.cache").warning("could not store %s in the cache %s: %s",
                                                   name, cache.root, exc.strerror or exc)


def train_job(job: Mapping[str, Any], out_dir: str, threads: int, device: str, queue, t0: float,
               sources: Mapping[str, bytes] | None = None, encode_workers: int | None = None) -> dict:
    """Train one job into ``out_dir``. Its source files are read where the plan found them, or,
    given ``sources`` ({plan path: bytes}, a worker without the driver's filesystem), from those
    bytes. Its BC encodes use ``encode_workers`` cores (default ``threads``)."""
    name = job.get("name", "?")
    try:
        if mp.parent_process() is not None:  # a worker process: keep the build's stdout clean (--json)
            try:
                sys.stdout.flush()
                os.dup2(2, 1)
            except OSError:
                pass
        warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad=True to a scalar")
        import torch  # lazy: start-up (the driver never loads torch: a cache hit needs none)

        from bcfpipe.fit import fit  # lazy: start-up
        from bcfpipe.train.trainer import resolve_device  # lazy: start-up

        share = max(1, encode_workers or threads)  # the cores this job may use
        # torch's count is the job's share outside a training, which runs on its own ``threads``
        # (`trainer.torch_threads`): quicktex's and FLIP's OpenMP follow it (measured: a 2048² BC1
        # level at quicktex level 13 took 5.5 s with torch at 1 thread and 3.0 s at 2), so a job
        # alone on two cores encoded and measured on one
        torch.set_num_threads(share)
        trace_pool("torch-intra-op", torch.get_num_threads())
        try:
            torch.set_num_interop_threads(1)
        except RuntimeError:
            pass
        trace_pool("torch-inter-op", torch.get_num_interop_threads())
        import OpenImageIO as oiio  # lazy: start-up

        oiio.attribute("threads", max(1, threads))
        trace_pool("oiio", oiio.get_int_attribute("threads"))
        set_exr_threads(oiio, share)
        set_encode_workers(share)
        trace_pool("encode-share", share)
        mj = MaterialJob.from_dict(job)
        progress = _Throttle(queue, mj.name) if queue is not None else None
        if progress:
            progress.phase("load")
        ts = _load(mj, sources)
        options = mj.options.with_(device=device, threads=max(1, threads))
        fitted = fit(ts, options, out_dir, wrap=mj.wrap, coverage=_mask(mj, ts), progress=progress,
                     log=progress.phase if progress else None, anchors={(p, q): v for p, q, v in mj.anchors})
        return JobResult(mj.name, Status.BUILT, None, time.perf_counter() - t0, str(resolve_device(device)), threads,
                         replace(fitted.record(), out=None)).to_dict()
    except BaseException as exc:  # noqa: BLE001 - a failing material must not stop the build
        return JobResult(name, Status.FAILED, one_line(exc), time.perf_counter() - t0, device, threads).to_dict()
    finally:
        release_workers()


def set_exr_threads(oiio, n: int) -> None:
    """OpenEXR's own thread pool (OpenImageIO's ``exr_threads``, beside its ``threads``) on ``n``
    cores: ``n`` workers, or none at all for one (-1: the reading thread decodes)."""
    oiio.attribute("exr_threads", n if n > 1 else -1)

    trace_pool("oiio-exr", max(1, oiio.get_int_attribute("exr_threads")))


def _load(mj: MaterialJob, sources: Mapping[str, bytes] | None):
    """The job's texture set, read where the plan found its files or from their ``sources`` bytes."""
    with tempfile.TemporaryDirectory(prefix="bcfpipe-src-") as tmp:
        local = copy_sources(mj, tmp) if sources is None else write_sources(sources, tmp)
        ts = load_texture_set([TextureSpec(sem, local[path], ch) for sem, path, ch in mj.specs],
                              resolution=mj.size if mj.options.resolution else None,
                              fix_nonfinite=mj.options.fix_nonfinite,
                              names={copy: path for path, copy in local.items()})
        return replace(ts, vectors=mj.vectors)


def _mask(mj: MaterialJob, ts):
    """The texels the job's meshes read, at the set's size (None: all)."""
    if mj.coverage is None:
        return None

    return unpack(mj.coverage, ts.width, ts.height)


def _local_name(k: int, path: str) -> str:
    """The k-th source's file name in a worker's folder: it keeps the extension (image readers go
    by it), a packaged file's (``pkg.usdz[inner.png]``) too."""
    return f"{k}_{Path(path.split('[')[-1].rstrip(']')).name}"


def _planned(job: MaterialJob) -> list[tuple[str, str]]:
    """(path, the plan's XXH3-128) of every source file a job reads, once each, in spec order."""
    hashes = {s.path: s.xxh3_128 for s in job.sources}
    return [(p, hashes.get(p, "")) for p in dict.fromkeys(p for _, p, _ in job.specs)]


def write_sources(sources: Mapping[str, bytes], folder: str | os.PathLike) -> dict[str, str]:
    """Write each source's bytes into ``folder``; {plan path: local path}."""
    out = {}
    for k, (path, data) in enumerate(sorted(sources.items())):
        local = Path(folder) / _local_name(k, path)
        local.write_bytes(data)
        out[path] = str(local)
    return out


class SourceChanged(WorkFailed):
    """A source file's bytes are not those the plan hashed (saved again during the build)."""


def _checked(path: str, data_hash: str, planned: str) -> None:
    if planned and data_hash != planned:
        raise SourceChanged(f"{Path(path).name} changed during the build; build again")


def copy_sources(job: MaterialJob, folder: str | os.PathLike) -> dict[str, str]:
    """Copy each source into ``folder`` (a packaged one through USD's resolver), hashing as it goes,
    and check the plan's XXH3-128: training reads the copy, so the bytes it trains on are the
    bytes the cache key names, in O(1 MiB) of memory whatever the size; {plan path: copy}."""
    out = {}
    for k, (path, planned) in enumerate(_planned(job)):
        dst = Path(folder) / _local_name(k, path)
        h = xxhash.xxh3_128()
        if package_split(path):
            data = read_asset(path)
            h.update(data)
            dst.write_bytes(data)
        else:
            with open(path, "rb") as src, open(dst, "wb") as f:
                while chunk := src.read(1 << 20):
                    h.update(chunk)
                    f.write(chunk)
        _checked(path, h.hexdigest(), planned)
        out[path] = str(dst)
    return out


def read_sources(job: MaterialJob) -> dict[str, bytes]:
    """The bytes of every source file a job reads (a packaged file's through USD's resolver),
    checked against the plan's XXH3-128: a file saved again since the plan would otherwise train
    a result that the cache stores under the old bytes' key."""
    out = {}
    for path, planned in _planned(job):
        data = read_asset(path) if package_split(path) else Path(path).read_bytes()
        _checked(path, xxhash.xxh3_128_hexdigest(data), planned)
        out[path] = data
    return out


def drain_events(queue, progress: ProgressCallback | None, returned: Callable[[ProgressEvent], None] | None = None) -> None:
    if queue is None:
        return

    while True:
        try:
            ev = queue.get_nowait()
        except (queue_mod.Empty, EOFError, OSError):
            return
        if ev.event == EventKind.RETURNED:
            if returned:
                returned(ev)
        elif progress:
            progress(ev)


def emit_event(progress: ProgressCallback | None, **event) -> None:
    if progress:
        progress(ProgressEvent(**event))


def _stop(pool: cf.ProcessPoolExecutor) -> None:
    """Cancel what is queued and end the running workers now (Ctrl-C must not wait for them)."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # Python 3.14 has terminate_workers()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=10)


@dataclass(frozen=True)
class _Work:
    """What every job of one `execute` shares: where results go, how its workers train, and where
    they report."""

    materials_dir: Path
    threads: int
    encode: int  # each job's BC encode workers
    devices: Sequence[str]
    queue: Any
    progress: ProgressCallback | None
    cache_root: str | None


def _run_pool(jobs: Sequence[MaterialJob], work: _Work, workers: int,
              executor: cf.Executor | None) -> tuple[dict[str, JobResult], list[MaterialJob]]:
    """Run ``jobs``; returns results and the jobs whose worker process died (to retry alone)."""
    materials_dir, threads, devices, queue = work.materials_dir, work.threads, work.devices, work.queue
    progress, cache_root = work.progress, work.cache_root
    results: dict[str, JobResult] = {}
    broken: list[MaterialJob] = []
    own = executor is None
    pool = executor or cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))
    if own:
        trace_pool("job-pool", workers)
    encode = work.encode
    try:
        futures = {}
        for i, job in enumerate(jobs):
            dev = devices[i % len(devices)]
            fut = pool.submit(run_job, job.to_dict(), str(materials_dir / job.name), threads, dev, queue, cache_root,
                              encode)
            futures[fut] = (job, dev)
            emit_event(progress, event=EventKind.QUEUED, job=job.name, materials=job.materials)
        by_name = {job.name: fut for fut, (job, _) in futures.items()}
        pending = set(futures)

        def finish(fut) -> None:
            job, dev = futures[fut]
            pending.discard(fut)
            try:
                r = JobResult.from_dict(fut.result())
            except BrokenProcessPool:
                broken.append(job)
                return
            except BaseException as exc:  # noqa: BLE001
                r = JobResult(job.name, Status.FAILED, one_line(exc), 0.0, dev, threads)
            results[job.name] = r
            emit_event(progress, event=EventKind.DONE, job=job.name, status=r.status, reason=r.reason,
                  psnr=result_psnr(r.result), seconds=r.seconds, cache=r.cache)

        def returned(ev: ProgressEvent) -> None:
            """A job's `done` where its worker said it returns: after its own progress, before the
            next job's (the queue's order; else a drain shows both running at once)."""
            if by_name.get(ev.job) in pending:
                finish(by_name[ev.job])

        while pending:
            done, _ = cf.wait(pending, timeout=0.2, return_when=cf.FIRST_COMPLETED)
            drain_events(queue, progress, returned)
            for fut in done:
                if fut in pending:
                    finish(fut)
    except BaseException:
        if own:
            _stop(pool)
        raise
    if own:
        pool.shutdown(wait=True)
    drain_events(queue, progress)
    return results, broken


def execute(jobs: Sequence[MaterialJob], materials_dir: str | os.PathLike, workers: int | None = None,
            executor: cf.Executor | None = None, progress: ProgressCallback | None = None,
            threads: int | None = None, cache_root: str | os.PathLike | None = None) -> dict[str, JobResult]:
    """Train every job into ``materials_dir/<job.name>/``; returns {job name: JobResult}.

    Each job runs in a worker process of a spawn-context ``ProcessPoolExecutor`` (or of
    ``executor``, anything with the concurrent.futures interface that runs `run_job`), with
    ``threads`` torch threads each (default ``config.DEFAULT_THREADS``). ``workers`` (``--jobs``)
    bounds the cores: ``workers`` // ``threads`` jobs side by side, each within its share
    (`core_shares`); without it one job per core (or GPU). A job whose worker process
    dies is retried once in a fresh single-worker pool (so one crash cannot take others with it),
    then marked failed.
    ``progress`` receives event dicts: ``queued``, ``progress`` (phase, step, steps, psnr, eta) and
    ``done`` (status, reason, psnr, seconds, cache). With ``cache_root`` each worker looks the job
    up in the cache under its key's lock and stores what it trains (`run_job`).
    """
    materials_dir = Path(materials_dir)
    materials_dir.mkdir(parents=True, exist_ok=True)
    if not jobs:
        return {}
    device = jobs[0].options.device
    shares = core_shares(len(jobs), max(1, int(workers)) if workers else None,
                         max(1, int(threads)) if threads else DEFAULT_THREADS, device)
    workers, threads = shares.workers, shares.threads
    gpus = _gpu_count(device)
    devices = [f"cuda:{i}" for i in range(gpus)] if gpus else [device]
    manager = mp.get_context("spawn").Manager() if progress else None
    if manager is not None:
        trace_pool("progress-queue", 1)  # a server process that forwards events: it waits, it does not compute
    try:
        queue = manager.Queue() if manager else None
        root = str(cache_root) if cache_root is not None else None
        work = _Work(materials_dir, threads, shares.encode, devices, queue, progress, root)
        results, broken = _run_pool(jobs, work, workers, executor)
        for job in broken:
            retry, again = _run_pool([job], work, 1, None)
            results.update(retry)
            if again:
                results[job.name] = JobResult(job.name, Status.FAILED, "worker process died (out of memory?)",
                                              0.0, device, threads)
                emit_event(progress, event=EventKind.DONE, job=job.name, status=Status.FAILED, reason=results[job.name].reason,
                      psnr=None, seconds=0.0)
    finally:
        if manager is not None:
            manager.shutdown()
    return {j.name: results[j.name] for j in jobs}
