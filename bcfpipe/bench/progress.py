"""Progress of a long bench on stderr: a rich bar with an ETA on a terminal, plain lines otherwise.

Work is counted in estimated seconds (a training cell by its steps x batch, a baseline by its
textures x texels), so the bar and the ETA move with the time things take, not with their count.
"""
from __future__ import annotations

import sys
import time

__all__ = ["BenchProgress", "cell_estimate", "baseline_estimate"]

SECONDS_PER_SAMPLE_STEP = 2.5e-6  # a CPU training step per sample (docs/benchmarks.md, teapot fast / standard)
BASELINE_SECONDS_PER_MTEXEL = 2.5  # encode + decode + metrics of one texture, per million texels


def cell_estimate(total_steps: int, batch: int) -> float:
    return total_steps * batch * SECONDS_PER_SAMPLE_STEP


def baseline_estimate(n_textures: int, texels: int) -> float:
    return max(1.0, n_textures * texels / 1e6 * BASELINE_SECONDS_PER_MTEXEL)


def _fmt(sec: float) -> str:
    sec = int(max(sec, 0))
    return f"{sec // 3600}h{sec % 3600 // 60:02d}m" if sec >= 3600 else f"{sec // 60}m{sec % 60:02d}s"


class BenchProgress:
    """``start(label, weight)`` a task, ``fraction(f)`` within it, ``done()``; an ETA from the
    rate measured so far (estimated seconds of work done per wall second)."""

    def __init__(self, total: float, quiet: bool = False):
        from rich.console import Console  # lazy: start-up

        self.total = max(total, 1e-9)
        self.done_weight = 0.0
        self.weight = 0.0
        self.frac = 0.0
        self.label = ""
        self.quiet = quiet
        self.console = Console(stderr=True)
        self.t0 = time.monotonic()
        self.last = 0.0
        self.bar = None
        if self.console.is_terminal and not quiet:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn  # lazy: start-up

            self.bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                                TimeElapsedColumn(), TextColumn("eta {task.fields[eta]}"), console=self.console)
            self.task = self.bar.add_task("bench", total=self.total, eta="?")

    def __enter__(self):
        if self.bar is not None:
            self.bar.__enter__()
        return self

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.__exit__(*exc)

    @property
    def completed(self) -> float:
        return self.done_weight + self.weight * self.frac

    def eta(self) -> float | None:
        elapsed = time.monotonic() - self.t0
        if self.completed <= 0 or elapsed < 1:
            return None
        return (self.total - self.completed) * elapsed / self.completed

    def start(self, label: str, weight: float) -> None:
        self.label, self.weight, self.frac = label, weight, 0.0
        self._show(force=True)

    def fraction(self, f: float) -> None:
        self.frac = min(max(f, 0.0), 1.0)
        self._show()

    def done(self) -> None:
        self.done_weight += self.weight
        self.weight, self.frac = 0.0, 0.0

    def _show(self, force: bool = False) -> None:
        eta = self.eta()
        text = _fmt(eta) if eta is not None else "?"
        if self.bar is not None:
            self.bar.update(self.task, completed=self.completed, description=self.label, eta=text)
        elif not self.quiet and (force or time.monotonic() - self.last > 10):
            self.last = time.monotonic()
            pct = 100 * self.completed / self.total
            print(f"bench {pct:3.0f}%  {self.label}  elapsed {_fmt(time.monotonic() - self.t0)}  eta {text}",
                  file=sys.stderr, flush=True)
