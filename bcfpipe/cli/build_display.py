"""`bcfpipe build`'s live progress: a rich table on a terminal, plain lines otherwise.

`cli/build.py` hands a `BuildDisplay` to the build as its progress callback; it reads the
`ProgressEvent`s of bcfpipe.builder.events and writes to stderr only.
"""
from __future__ import annotations

import threading
import time

from rich.console import Console
from rich.live import Live
from rich.table import Table
from rich.text import Text

from bcfpipe.builder.events import EventKind, ProgressEvent
from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.train.pace import LINE_SECONDS, TICK_SECONDS, Ticker

__all__ = ["BuildDisplay"]


def _fmt_eta(eta) -> str:
    if eta is None:
        return ""
    eta = max(0.0, float(eta))
    return f"{eta:.0f}s" if eta < 90 else f"{eta / 60:.1f}m"


class BuildDisplay:
    """Progress of a build: a live rich table on a terminal, plain lines otherwise.

    Call it with the `ProgressEvent`s of a build (bcfpipe.builder.events); use as a context manager.
    Plain lines: a texture set's end at once; its phase when the phase starts, or, within
    `TICK_SECONDS` of its previous line, that long after it, with every phase it entered since
    (only those of the last second before its end go unnamed); and, while it runs, at least every
    `LINE_SECONDS` (`tick`, once a second while entered). So no phase goes quiet, and no texture
    set prints more than a line a second before it ends.
    """

    STYLE = {"queued": "dim", "running": "cyan", Status.BUILT: "green", Status.FAILED: "red"}

    def __init__(self, console: Console | None = None, live: bool | None = None, clock=time.monotonic):
        self.console = console or Console(stderr=True)
        self.live_mode = self.console.is_terminal if live is None else live
        self.jobs: dict[str, dict] = {}
        self._live: Live | None = None
        self._ticker: Ticker | None = None
        self._lock = threading.RLock()
        self.clock = clock
        self.t0 = self.last_line = clock()

    def __enter__(self) -> "BuildDisplay":
        if self.live_mode:
            self._live = Live(get_renderable=self.table, console=self.console, refresh_per_second=4,
                              transient=False)
            self._live.__enter__()
        else:
            self._ticker = Ticker(self.tick).__enter__()
        return self

    def __exit__(self, *exc) -> None:
        if self._ticker is not None:
            self._ticker.__exit__(*exc)
            self._ticker = None
        if self._live is not None:
            self._live.refresh()
            self._live.__exit__(*exc)
            self._live = None

    def __call__(self, ev: ProgressEvent) -> None:
        with self._lock:
            self._event(ev)

    def _event(self, ev: ProgressEvent) -> None:
        name = ev.job
        st = self.jobs.setdefault(name, {"status": "queued", "phase": "", "step": 0, "steps": 0, "psnr": None,
                                         "eta": None, "materials": [], "since": 0.0,
                                         "line_at": float("-inf"), "entered": []})
        line = None
        if ev.event == EventKind.QUEUED:
            st["materials"] = list(ev.materials)
        elif ev.event == EventKind.PROGRESS:
            if st["status"] in (Status.BUILT, Status.FAILED):  # a late event of a finished job (Ray's are not awaited)
                return
            phase_changed = ev.phase != st["phase"]
            st.update(status="running", phase=ev.phase, step=ev.step, steps=ev.steps, eta=ev.eta)
            if ev.psnr is not None:
                st["psnr"] = ev.psnr
            if phase_changed:
                st["since"] = self.clock()
                st["entered"].append(ev.phase)
                if st["since"] - st["line_at"] >= TICK_SECONDS:
                    line = f"{name}: {', '.join(st['entered'])}"
        elif ev.event == EventKind.DONE:
            st.update(status=ev.status or "?", phase="", eta=None)
            if ev.materials:
                st["materials"] = list(ev.materials)
            if ev.psnr is not None:
                st["psnr"] = ev.psnr
            if st["status"] == Status.BUILT and ev.cache == CacheUse.HIT:
                st["phase"] = "cached"
                psnr = f", PSNR {st['psnr']:.2f} dB" if st["psnr"] is not None else ""
                line = f"{name}: from the cache{psnr}"
            elif st["status"] == Status.BUILT:
                psnr = f", PSNR {st['psnr']:.2f} dB" if st["psnr"] is not None else ""
                line = f"{name}: built in {ev.seconds or 0:.1f}s{psnr}"
            else:
                line = f"{name}: FAILED: {ev.reason}"
        if line and not self.live_mode:
            self._print(line, st)

    def _print(self, line: str, st: dict | None = None) -> None:
        now = self.clock()
        self.console.print(f"[{now - self.t0:6.1f}s] [{self.counts_line()}] {line}",
                           highlight=False, markup=False, soft_wrap=True)
        self.last_line = now
        if st is not None:
            st["line_at"], st["entered"] = now, []

    def tick(self) -> None:
        """Plain mode: each texture set's phases entered and not yet named, `TICK_SECONDS` after
        its last line; then a line on the running texture set longest without one once that is
        `LINE_SECONDS`, no two such lines within `TICK_SECONDS`; with none running, a line on what
        the build waits for after that long a silence."""
        if self.live_mode:
            return
        with self._lock:
            now = self.clock()
            for name, st in self.jobs.items():
                if st["status"] == "running" and st["entered"] and now - st["line_at"] >= TICK_SECONDS:
                    self._print(f"{name}: {', '.join(st['entered'])}", st)
            if now - self.last_line < TICK_SECONDS:
                return
            running = [(st["line_at"], name) for name, st in self.jobs.items() if st["status"] == "running"]
            if running:
                at, name = min(running)
                if now - at >= LINE_SECONDS:
                    self._print(self._running_line(name, now), self.jobs[name])
            elif now - self.last_line >= LINE_SECONDS:
                n = self.counts()
                self._print("planning" if not self.jobs else "waiting for a worker" if n["queued"]
                            else "writing the results")

    def _running_line(self, name: str, now: float) -> str:
        st = self.jobs[name]
        step = f" {st['step']}/{st['steps']}" if st["steps"] else ""
        psnr = f", batch PSNR {st['psnr']:.2f} dB" if st["psnr"] is not None else ""
        eta = f", ETA {_fmt_eta(st['eta'])}" if st["steps"] and st["eta"] is not None else ""
        return f"{name}: {st['phase']}{step}, {now - st['since']:.0f}s in this phase{psnr}{eta}"

    def counts(self) -> dict[str, int]:
        """Texture sets by state: queued, running, done (trained), cached, failed."""
        n = dict.fromkeys(("queued", "running", "done", "cached", "failed"), 0)
        for st in self.jobs.values():
            key = {Status.BUILT: "cached" if st["phase"] == "cached" else "done"}.get(st["status"], st["status"])
            n[key] = n.get(key, 0) + 1
        return n

    def counts_line(self) -> str:
        n = self.counts()
        finished = n["done"] + n["cached"] + n["failed"]
        return (f"{finished}/{len(self.jobs)}: {n['done']} trained, {n['cached']} cached, {n['failed']} failed; "
                f"{n['running']} running, {n['queued']} queued")

    def table(self) -> Table:
        t = Table(title=f"bcfpipe build  {self.counts_line()}", title_justify="left", expand=False)
        for col in ("texture set", "materials", "status", "phase", "step", "PSNR", "ETA"):
            t.add_column(col, overflow="fold", justify="right" if col in ("step", "PSNR", "ETA") else "left")
        for name, st in self.jobs.items():
            mats = st["materials"]
            label = mats[0].rsplit("/", 1)[-1] + (f" +{len(mats) - 1}" if len(mats) > 1 else "") if mats else ""
            step = f"{st['step']}/{st['steps']}" if st["steps"] else ""
            psnr = f"{st['psnr']:.2f}" if st["psnr"] is not None else ""
            t.add_row(name, label, Text(st["status"], style=self.STYLE.get(st["status"], "")), st["phase"], step,
                      psnr, _fmt_eta(st["eta"]))
        return t
