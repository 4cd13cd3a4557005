"""`bcfpipe build --shard I/N`: train one shard of a scene's jobs into the cache, for any scheduler.

A job's shard is its content hash modulo N, so it never moves when other jobs come or go, and N
processes (a Slurm array, a CI matrix, Dask tasks) can each take one shard with no coordination.
A shard writes nothing but cache entries; a final `bcfpipe build SCENE` finds every job in the
cache and assembles without training.
"""
from __future__ import annotations

import os
import shutil
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.config import TrainingOptions
from bcfpipe.builder.options import Execution, Selection
from bcfpipe.builder.events import EventKind, ProgressCallback, ProgressEvent
from bcfpipe.builder.executor import JobResult, execute
from bcfpipe.builder.plan import BuildError, plan
from bcfpipe.cache import Cache, default_root
from bcfpipe.texset.blocks import blocks_in
from bcfpipe.train.fused.common import kernels_in

__all__ = ["parse_shard", "shard_of", "ShardResult", "train_shard"]


def parse_shard(text: str) -> tuple[int, int]:
    """'I/N' with 1 <= I <= N -> (I, N); anything else is a BuildError (exit 2)."""
    try:
        i, n = (int(v) for v in str(text).split("/"))
    except ValueError:
        raise BuildError(f"--shard must look like I/N (e.g. 1/4), got {text!r}") from None
    if not (n >= 1 and 1 <= i <= n):
        raise BuildError(f"--shard {text}: need 1 <= I <= N")
    return i, n


def shard_of(content_hash: str, count: int) -> int:
    """The 1-based shard of a job: its content hash modulo ``count``."""
    return int(content_hash[:16], 16) % count + 1


@dataclass(frozen=True)
class ShardResult:
    shard: tuple[int, int]
    cache: Path
    jobs: tuple[JobResult, ...]  # this shard's jobs: trained ("miss"), found ("hit") or failed
    total_jobs: int  # in the whole scene
    wall_seconds: float

    @property
    def exit_code(self) -> int:
        return 1 if any(j.status != Status.BUILT for j in self.jobs) else 0

    def to_json(self) -> dict[str, Any]:
        return {"shard": list(self.shard), "cache": str(self.cache), "total_jobs": self.total_jobs,
                "wall_seconds": round(self.wall_seconds, 3),
                "jobs": [{"name": j.name, "status": j.status, "reason": j.reason, "cache": j.cache,
                          "seconds": round(j.seconds, 3)} for j in self.jobs]}


def train_shard(scene: str | os.PathLike, shard: tuple[int, int], training: TrainingOptions = TrainingOptions(),
                selection: Selection = Selection(), execution: Execution = Execution(),
                progress: ProgressCallback | None = None) -> ShardResult:
    """Train the jobs of ``shard`` that the cache lacks; store them there, on ``execution``'s cache
    with its worker count. Writes only the cache (its trainings run in a folder under the cache's
    tmp/)."""
    t0 = time.perf_counter()
    cache = execution.cache
    store = Cache(default_root() if cache in (None, True) else cache)
    bplan = plan(scene, training, selection, facts=store.facts)
    i, n = shard
    mine = [j for j in bplan.jobs if shard_of(j.content_hash, n) == i]
    results: dict[str, JobResult] = {}
    todo = []
    for j in mine:
        if store.lookup(j.content_hash).entry is not None:
            results[j.name] = JobResult(j.name, Status.BUILT, None, 0.0, j.options.device, 0, None, CacheUse.HIT)
            if progress:
                progress(ProgressEvent(EventKind.DONE, j.name, j.materials, status=Status.BUILT, seconds=0.0,
                                       cache=CacheUse.HIT))
        else:
            todo.append(j)
    work = store.base / "tmp" / f"shard-{i}-of-{n}.{uuid.uuid4().hex[:8]}"
    try:
        work.mkdir(parents=True)
        with kernels_in(store.root), blocks_in(store.base):  # compiled kernels and BC@R's blocks in its cache
            results.update(execute(todo, work, workers=execution.jobs, progress=progress, threads=training.threads,
                                   cache_root=store.root))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return ShardResult(shard, store.root, tuple(results[j.name] for j in mine), len(bplan.jobs),
                       time.perf_counter() - t0)
