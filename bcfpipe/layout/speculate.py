"""The likeliest training, started on a spare core before the probe chooses it (issue 58).

The probe decides which candidate trains, but the candidate a fit trains is most often the widest
all-channel model at the probe's profile that fits within BC@R's bytes (`guess`): on the water
bottle at 1k it is the one that ships. With a core to spare, at a preset where it pays
(`PRESETS`), that candidate's full training starts, silent, on its own thread: where R is below
the set's side, at the fit's start, beside BC@R's full encode (on the cores it leaves, quicktex in
a worker process: `parallel.workers`' ``beside``), the oracle and the probe
(`decide._promising`); elsewhere when the probe starts. When the probe's choice is that candidate
it is adopted: its training has run as long as those already, and its progress is shown from
then on. When the choice is anything else, or the oracle rules out every neural candidate and no
probe runs, it is cancelled, and stops at its next progress report (a T_0 layer encoded, a
phase's steps) while the fit goes on; its files are dropped once it has. Either way what ships is what the sequential fit ships: the same training,
the same schedule, the same thread count (`--threads`), on the texture set's one reference chain.
"""
from __future__ import annotations

import contextlib
import shutil
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from bcfpipe.layout import choose as C
from bcfpipe.layout import kinds as K
from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset.parallel import encode_workers, workers
from bcfpipe.train.progress import Progress, ProgressFn

# At most this many reference values (texels x channels) in a set whose training runs beside the
# probe: each training holds its own encoded copy of the chain (2.7 GiB for an 8192² set of 8
# channels), which beside the probe's would raise an 8K fit's peak memory above its final measure's.
MAX_VALUES = 2048 * 2048 * 16
FOLDER = "speculative"  # under the fit's work folder
# The presets whose probe is long enough for a speculation to pay (docs/benchmarks.md, "Issue 58:
# the likeliest training beside the probe"): adopted, it saves the probe's time (the water bottle's:
# 10-12 s at draft, 39 s at standard); dropped, as most are, it cost the bottle's fit at draft
# 3-4 s (the quality set's estimate moved beside the final measure, its last seconds before it stops).
PRESETS = ("fast", "standard", "paper")


class Cancelled(Exception):
    """The speculative training was not chosen: it stops at its next progress report."""


class _Gate:
    """The speculative training's progress: silent until adopted, then the fit's; raises
    `Cancelled` once cancelled."""

    def __init__(self, progress: ProgressFn | None):
        self.progress = progress
        self.adopted = False
        self.cancelled = threading.Event()
        self.ended: float | None = None  # when the training ended (`time.perf_counter`)

    def __call__(self, p: Progress) -> None:
        if self.cancelled.is_set():
            raise Cancelled()
        if self.adopted and self.progress is not None:
            self.progress(p)


@dataclass
class Speculation:
    """A full training of (``profile``, ``t0_layers``), all channels, running on its own thread."""

    profile: str
    t0_layers: int
    future: Future
    gate: _Gate
    start: float

    def matches(self, c: C.Candidate) -> bool:
        """Whether ``c`` is this training's candidate."""
        return c.kind is K.NEURAL and c.profile == self.profile and c.part.t0_layers == self.t0_layers

    def adopt(self, ctx: K.FitContext) -> K.Weighed:
        """Its result, waited for with its progress shown meanwhile, weighed against ``ctx``'s BC@R."""
        self.gate.adopted = True
        return K.weigh_trained(ctx, self.future.result(), (), self.profile, K.NEURAL, ctx.all_channels)

    def cancel(self) -> float:
        """Ask it to stop at its next progress report (a T_0 layer encoded, a phase's steps), without
        waiting; the seconds it ran (to its end, if it has ended: a short training may, before the
        probe chooses). `join` waits for it."""
        self.gate.cancelled.set()
        return (self.gate.ended or time.perf_counter()) - self.start

    @property
    def pending(self) -> bool:
        """Neither adopted nor cancelled yet."""
        return not self.gate.adopted and not self.gate.cancelled.is_set()

    def join(self, work: Path) -> None:
        """Wait for it to end, then drop its files under ``work``, the fit's folder."""
        try:
            self.future.result()
        except Exception:  # noqa: BLE001 - cancelled, or failed: either way it does not ship
            pass
        shutil.rmtree(work / FOLDER, ignore_errors=True)


def guess(ctx: K.FitContext, bc_bytes: int | None = None) -> tuple[str, int] | None:
    """(profile, T_0 width) of the candidate most likely trained: all channels at the probe's profile,
    the widest T_0 weighed whose bytes fit within BC@R's (``bc_bytes``, exact before it is encoded:
    `LayoutPrediction.bc_bytes`; by default ``ctx.classic``'s); None when none does."""
    n = ctx.ts.num_channels
    bc = ctx.classic.bc.size_bytes if bc_bytes is None else bc_bytes
    fits = [w for w in ctx.widths if ctx.fits_width(n, w) and ctx.sizes[(ctx.p0, w)] <= bc]
    return (ctx.p0, max(fits)) if fits and not ctx.forced else None


def spare_cores(ctx: K.FitContext) -> int:
    """The cores the job may use beyond its trainings' (``--threads``)."""
    return encode_workers() - (ctx.options.threads or 1)


def possible(ctx: K.FitContext) -> bool:
    """Whether a fit may speculate: at a preset where it pays (`PRESETS`), with a core to spare
    beyond the probe's, on a set small enough for two trainings' memory (`MAX_VALUES`)."""
    return (ctx.options.preset in PRESETS and spare_cores(ctx) >= (ctx.options.threads or 1)
            and ctx.ts.data.size <= MAX_VALUES)


def start(ctx: K.FitContext, bc_bytes: int | None = None) -> Speculation | None:
    """`guess`'s candidate trained in full on its own thread, when the fit may speculate
    (`possible`); else None. ``ctx``: sized for the probe (p0, widths, sizes); ``bc_bytes``: BC@R's,
    when it is not yet encoded."""
    g = guess(ctx, bc_bytes) if possible(ctx) else None
    if g is None:
        return None
    profile, width = g
    gate = _Gate(ctx.progress)
    quiet = replace(ctx, progress=gate, log=lambda s: None, out=ctx.out / FOLDER)
    threads = ctx.options.threads or 1

    def run():
        try:
            with workers(threads):
                return K.train_channels(quiet, ctx.all_channels, profile, width=width)
        finally:
            gate.ended = time.perf_counter()

    ctx.log(f"meanwhile training neural {profile}" + (f", T_0 of {width} layers" if width > 1 else "")
            + ", the likeliest choice, on the spare core")
    trace_pool("speculative-training", 1)
    pool = ThreadPoolExecutor(1, thread_name_prefix="bcfpipe-speculative-training")
    future = pool.submit(run)
    pool.shutdown(wait=False)
    return Speculation(profile, width, future, gate, time.perf_counter())


@contextlib.contextmanager
def beside(spec: Speculation | None, ctx: K.FitContext):
    """The fit's encodes meanwhile on the cores ``spec``'s training leaves (`spare_cores`), quicktex
    in worker processes (`parallel.workers`' ``beside``); as they are without ``spec``."""
    if spec is None or spec.future.done():
        yield
        return
    with workers(spare_cores(ctx), beside=True):
        yield
