"""The Ray executor: one Ray task per training job, on a local or remote Ray cluster.

Data flow: workers need not share the driver's filesystem. The driver puts each job's source
bytes into the object store once (``ray.put``); the task writes them to its own temporary folder,
trains there, and returns the exported files as bytes. The driver writes them into the build's
staging folder and stores them in the cache (atomically, under the key's lock), exactly as a
local worker would, so the outputs are byte-identical to a local build's. At most
`in_flight_limit` tasks are submitted at once (the cluster's slots plus up to 32), so the driver
and the object store hold the sources of that many jobs, not of the whole scene.

Faults: a task whose worker process dies is retried by Ray (``max_retries``); a Python
exception inside training is not an infrastructure fault and is reported, not retried (the task
returns a failed result). A job that fails for good fails only its materials. Every run of a task
says so on the progress queue, so a retry is counted and reported. Ctrl-C cancels the tasks still queued or running.

Threads and device come from what Ray grants: ``num_cpus`` = the build's ``--threads``, and
``num_gpus`` = 1 when training on CUDA; a task's encodes use its threads. ``--jobs N`` bounds the
build's cores here too: a Ray of the build's own gets N CPUs, and on a cluster at most
N // ``--threads`` tasks run at once (threads at most N).
"""
from __future__ import annotations

import collections
import contextlib
import os
import secrets
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from bcfpipe.builder.executor import cpu_count
from bcfpipe.cache import Cache
from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.builder.executor import JobResult, emit_event, drain_events, train_job, read_sources, store_entry
from bcfpipe.builder.events import EventKind, ProgressCallback, ProgressEvent, result_psnr
from bcfpipe.builder.plan import MaterialJob
from bcfpipe.config import DEFAULT_THREADS
from bcfpipe.errors import Unavailable, WorkFailed, one_line

__all__ = ["RayUnavailable", "require_ray", "execute_ray", "in_flight_limit", "resolve_executor", "EXECUTORS", "MAX_RETRIES"]

EXECUTORS = ("auto", "local", "ray")
MAX_RETRIES = 2  # attempts after a worker process dies


class RayUnavailable(Unavailable):
    """--executor ray without the ray package, or no cluster to reach."""


def resolve_executor(name: str, address: str | None) -> str:
    """'auto' is ray when an address is given or RAY_ADDRESS is set, else local."""
    if name not in EXECUTORS:
        raise RayUnavailable(f"unknown executor {name!r}; choose from {', '.join(EXECUTORS)}")
    if name == "auto":
        return "ray" if (address or os.environ.get("RAY_ADDRESS")) else "local"
    return name


def require_ray():
    try:
        import ray  # lazy: start-up
    except ImportError:
        raise RayUnavailable("--executor ray needs the ray package: pip install 'bcfpipe[ray]' "
                             "(or pip install ray)") from None
    return ray


class _Events:
    """A worker's side of the driver's progress queue: puts without waiting for the queue actor."""

    def __init__(self, queue):
        self.actor = queue.actor

    def put(self, event: dict) -> None:
        self.actor.put_nowait.remote(event)


def _remote_parts(ray):
    """The task, defined once ray is imported."""

    @ray.remote
    def train_task(job: dict, device: str, queue, paths: list[str], *blobs: bytes):
        # no ray.get in here: a task blocked in ray.get lends its CPUs back to Ray, which starts
        # another task on them, and both then train on one CPU's share
        events = _Events(queue)
        events.put(ProgressEvent(EventKind.ATTEMPT, job["name"]))
        granted = ray.get_runtime_context().get_assigned_resources()
        threads = max(1, int(granted.get("CPU", 1)))
        with tempfile.TemporaryDirectory(prefix="bcfpipe-ray-") as tmp:
            out = Path(tmp) / "out"
            r = train_job(job, str(out), threads, device, events, time.perf_counter(),
                           sources=dict(zip(paths, blobs)))
            files = {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.is_file()} if out.is_dir() else {}
        return r, files

    return train_task


def in_flight_limit(resources: dict, threads: int, gpus: int, n_jobs: int) -> int:
    """Tasks submitted at once: one per slot the cluster has, plus up to 32 queued so that a slot
    never waits for the driver. The driver's node holds the sources of that many jobs in its
    object store (a running task's arguments stay there until it ends), not of the whole scene."""
    slots = int(resources.get("GPU", 0)) if gpus else int(resources.get("CPU", 1)) // max(1, threads)
    slots = max(1, slots)
    return max(1, min(n_jobs, slots + min(slots, 32)))


def _store(job: MaterialJob, r: JobResult, files: dict[str, bytes], materials_dir: Path,
           cache_root: str | None) -> JobResult:
    """Write a finished task's files into the staging folder and the cache."""
    folder = materials_dir / job.name
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    if cache_root is None or r.status != Status.BUILT:
        return r

    store_entry(Cache(cache_root), job.content_hash, folder, r.result, job.name, take_lock=True)
    return JobResult(r.name, r.status, r.reason, r.seconds, r.device, r.threads, r.result, CacheUse.MISS)


def execute_ray(jobs: Sequence[MaterialJob], materials_dir: str | os.PathLike, address: str | None = None,
                threads: int | None = None, progress: ProgressCallback | None = None,
                cache_root: str | os.PathLike | None = None,
                max_retries: int = MAX_RETRIES, cores: int | None = None) -> tuple[dict[str, JobResult], dict[str, int]]:
    """Train ``jobs`` as Ray tasks into ``materials_dir/<job>/``; returns ({job: JobResult},
    {job: attempts}). Connects to ``address`` (or RAY_ADDRESS), else starts a Ray of its own. Ray's
    own messages (a raylet reporting a dead worker, ...) go to stderr: stdout stays the build's.
    ``cores`` (``--jobs``): the build's cores (module docstring)."""
    with contextlib.redirect_stdout(sys.stderr):
        return _execute(jobs, materials_dir, address, threads, progress, cache_root, max_retries, cores)


def _execute(jobs, materials_dir, address, threads, progress, cache_root, max_retries, cores=None):
    ray = require_ray()
    materials_dir = Path(materials_dir)
    materials_dir.mkdir(parents=True, exist_ok=True)
    if not jobs:
        return {}, {}
    threads = max(1, int(threads)) if threads else DEFAULT_THREADS
    if cores is not None:
        cores = max(1, int(cores))
        threads = min(threads, cores)
    started_here = not ray.is_initialized()
    with contextlib.ExitStack() as stack:
        if started_here:
            stack.enter_context(_connect(ray, address or os.environ.get("RAY_ADDRESS"), cores))
        return _run(ray, jobs, materials_dir, threads, progress, cache_root, max_retries, cores)


@contextlib.contextmanager
def _connect(ray, address: str | None, cores: int | None = None):
    """Connect to the cluster at ``address`` ("auto": the one `ray start` last started on this
    machine), or with none start a Ray of this build's own and end it after. An own Ray keeps its
    session files in a temporary folder it removes, and gets a random auth token through the
    environment, so nothing is left behind (Ray would otherwise write ~/.ray/auth_token and
    /tmp/ray/session_*). An own Ray gets ``cores`` CPUs (``--jobs``), else every core."""
    saved = {"RAY_AUTH_TOKEN": os.environ.get("RAY_AUTH_TOKEN")}
    tmp = None
    try:
        if address:
            ray.init(address=address, log_to_driver=False, include_dashboard=False, configure_logging=False)
        else:
            tmp = tempfile.mkdtemp(prefix="bcfray-")  # short: Ray's socket paths have a length limit
            if not saved["RAY_AUTH_TOKEN"]:  # (RAY_AUTH_MODE is read when ray is imported: not set here)
                os.environ["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
            ray.init(address="local", num_cpus=cores or cpu_count(), log_to_driver=False, include_dashboard=False,
                     configure_logging=False, _temp_dir=tmp)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        _restore(saved, tmp)
        where = f"a Ray cluster at {address}" if address else "a local Ray"
        raise RayUnavailable(f"cannot reach {where}: {one_line(exc)}") from None
    try:
        yield
    finally:
        ray.shutdown()
        _restore(saved, tmp)


def _restore(saved: dict, tmp: str | None) -> None:
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    if tmp:  # Ray's processes may still be ending and writing there: try for a while
        for _ in range(50):
            shutil.rmtree(tmp, ignore_errors=True)
            if not os.path.exists(tmp):
                break
            time.sleep(0.2)


def _slots(ray, device: str, threads: int, n_jobs: int) -> tuple[int, int]:
    """(GPUs per task, tasks in flight at most) on this cluster; CUDA without GPUs is refused."""
    gpus = 1 if device.startswith("cuda") else 0
    resources = ray.cluster_resources()
    if gpus and not resources.get("GPU"):  # Ray would wait for one forever
        raise RayUnavailable("training on CUDA needs GPUs, and the Ray cluster has none; "
                             "use --device cpu or add GPU nodes")
    return gpus, in_flight_limit(resources, threads, gpus, n_jobs)


@dataclass
class _Flight:
    """The Ray tasks of one build: each job submitted with its sources' bytes, collected when done."""

    ray: Any
    task: Any  # the remote train_task
    queue: Any
    device: str
    threads: int
    gpus: int
    max_retries: int
    progress: ProgressCallback | None
    refs: dict = field(default_factory=dict)  # object ref -> job
    results: dict = field(default_factory=dict)  # job name -> JobResult

    def finish(self, job: MaterialJob, r: JobResult) -> None:
        self.results[job.name] = r
        emit_event(self.progress, event=EventKind.DONE, job=job.name, status=r.status, reason=r.reason,
              psnr=result_psnr(r.result), seconds=r.seconds, cache=r.cache)

    def submit(self, job: MaterialJob):
        """The job's task ref; None when its sources cannot be read (the job fails)."""
        try:
            src = read_sources(job)  # this job's bytes only: the driver holds at most `window` jobs' sources
        except (OSError, WorkFailed) as exc:  # gone or saved again since the plan: this job fails
            self.finish(job, JobResult(job.name, Status.FAILED, one_line(exc), 0.0, self.device, self.threads))
            return None
        paths = list(src)
        blobs = [self.ray.put(src[p]) for p in paths]
        ref = self.task.options(num_cpus=self.threads, num_gpus=self.gpus, max_retries=self.max_retries,
                                retry_exceptions=False).remote(job.to_dict(), self.device, self.queue, paths, *blobs)
        self.refs[ref] = job
        return ref

    def collect(self, ref, materials_dir, root: str | None) -> None:
        job = self.refs[ref]
        try:
            raw, files = self.ray.get(ref)
            r = _store(job, JobResult.from_dict(raw), files, materials_dir, root)
        except Exception as exc:  # noqa: BLE001 - the task failed for good: its materials fail
            r = JobResult(job.name, Status.FAILED, one_line(exc), 0.0, self.device, self.threads)
        self.finish(job, r)

    def cancel(self) -> None:
        for ref, job in self.refs.items():
            if job.name not in self.results:
                self.ray.cancel(ref, force=True)


def _run(ray, jobs, materials_dir, threads, progress, cache_root, max_retries, cores=None):
    device = jobs[0].options.device
    from ray.util.queue import Queue  # lazy: start-up

    queue = Queue(actor_options={"num_cpus": 0})  # progress events, and one "attempt" per run of a task
    attempts: dict[str, int] = {}

    def forward(ev: ProgressEvent) -> None:
        if ev.event == EventKind.ATTEMPT:
            attempts[ev.job] = attempts.get(ev.job, 0) + 1
        elif progress:
            progress(ev)
    root = str(cache_root) if cache_root is not None else None
    gpus, window = _slots(ray, device, threads, len(jobs))
    if cores is not None:  # --jobs: at most that many cores busy, on any cluster
        window = min(window, max(1, cores // threads))
    flight = _Flight(ray, _remote_parts(ray), queue, device, threads, gpus, max_retries, progress)
    try:
        for job in jobs:
            emit_event(progress, event=EventKind.QUEUED, job=job.name, materials=job.materials)
        waiting = collections.deque(jobs)
        pending: list = []

        def fill() -> None:
            while waiting and len(pending) < window:
                ref = flight.submit(waiting.popleft())
                if ref is not None:
                    pending.append(ref)

        fill()
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=0.2)
            drain_events(queue, forward)
            for ref in ready:
                flight.collect(ref, materials_dir, root)
            fill()
        drain_events(queue, forward)
    except KeyboardInterrupt:  # cancel what is still queued or running; the build then stops cleanly
        flight.cancel()
        raise
    return {j.name: flight.results[j.name] for j in jobs}, attempts

