"""What a build reports while it runs: one `ProgressEvent` per queued job, training step (at most a
few a second) and finished job, passed to the ``progress`` callback of `bcfpipe.builder.build`
(the command line's live table and plain lines draw them). Events cross process boundaries (the
local pool's queue, Ray's queue actor) as these records."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from bcfpipe.formats.vocabulary import StrEnum

__all__ = ["EventKind", "ProgressEvent", "ProgressCallback", "result_psnr"]


class EventKind(StrEnum):
    QUEUED = "queued"  # the job is known and waits (every job is announced first)
    PROGRESS = "progress"  # a training phase and step
    DONE = "done"  # built (trained or from the cache) or failed
    ATTEMPT = "attempt"  # a Ray task started (again, after a worker died); counted, not shown
    RETURNED = "returned"  # a local worker's last event before it returns a job: its `done` goes here, in order


@dataclass(frozen=True)
class ProgressEvent:
    event: EventKind
    job: str
    materials: tuple[str, ...] = ()  # queued, done: the materials that share the job
    phase: str = ""  # progress: load, warmup, encode, constrained, finetune, ...
    step: int = 0
    steps: int = 0
    psnr: float | None = None  # progress: of the training batch; done: of the exported files
    eta: float | None = None  # progress: seconds left, estimated
    elapsed: float | None = None
    status: str | None = None  # done: formats.vocabulary.Status
    reason: str | None = None  # done, failed: why, on one line
    seconds: float | None = None  # done: training time
    cache: str | None = None  # done: formats.vocabulary.CacheUse, None for a failure

    def __post_init__(self) -> None:
        object.__setattr__(self, "materials", tuple(self.materials))


ProgressCallback = Callable[[ProgressEvent], None]


def result_psnr(result) -> float | None:
    """`bcfpipe.builder.report.headline_psnr` of a job's `FitResult` (None: no result): what the
    progress lines print, so that they agree with the table."""
    return result.headline_psnr if result is not None else None
