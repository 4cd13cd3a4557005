"""`bcfpipe verify`: run the GLSL decoder through OpenGL and check it against decoder.onnx.

Exit codes: 0 every check passed; 1 a check failed; 2 bad input (no material.json/manifest.json,
unreadable or malformed files) or no OpenGL 4.5 context through EGL.
"""
from __future__ import annotations

import contextlib
import json
import threading
import time
from dataclasses import dataclass

import click
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from bcfpipe.cli.errors import Command
from bcfpipe.errors import EXIT_FAILED, EXIT_OK, EXIT_USAGE
from bcfpipe.train.pace import LINE_SECONDS, Ticker

__all__ = ["verify", "run_verify", "CheckSettings", "print_report", "material_line", "VerifyOutput"]


def _figures(ch: dict) -> str:
    return f"max |GLSL - ONNX| {ch['max_abs']:.3g} ({ch['name']}; tolerance up to {ch['max_tolerance']:.3g})"


def material_line(m) -> str:
    """One material's report on one line (no status word): the material whose texture set it
    shares (its checks are that material's, repeated), each failed check and what it found,
    then the GLSL figures (the largest |GLSL - ONNX|, its channel and that channel's largest
    tolerance: figures --json has too), the checks that passed and those skipped."""
    failed = [f"bad input: {m.input_error}"] if m.input_error else []
    figures, ok = [], []
    worst = None
    if m.channels:
        worst = max([ch for ch in m.channels if not ch["passed"]] or m.channels, key=lambda ch: ch["max_abs"])
    for c in m.checks:
        if c.name == "glsl" and worst is not None and c.passed is not None:
            over = sum(ch["over_tolerance"] for ch in m.channels)
            if over:
                failed.append(f"glsl: {over} of {m.n_points * len(m.channels)} values over tolerance, "
                              f"{_figures(worst)}, worst at {worst['worst']['category']}")
            else:
                figures.append(f"glsl: {_figures(worst)}, {m.n_points} points x {len(m.channels)} channels")
        elif c.name == "vulkan" and c.passed:  # its figure beside OpenGL's
            figures.append(f"vulkan: {c.detail}")
        elif c.passed is False:
            failed.append(f"{c.name}: {c.detail}")
        elif c.passed:
            ok.append(c.name)
    skipped = [c.name for c in m.checks if c.passed is None]
    shares = [f"the texture set of {m.shares}, checked with it"] if m.shares else []
    return "; ".join(shares + failed + figures + [f"ok: {', '.join(ok)}"] * bool(ok)
                     + [f"skipped: {', '.join(skipped)}"] * bool(skipped))


class VerifyOutput:
    """`verify`'s human-readable report as it goes, and its heartbeat.

    Called with the `VerifyEvent`s of `bcfpipe.verify.checks.verify`: on ``console`` (None: no
    report, as with --json) the header once OpenGL is up, then one line per material (with
    ``verbose`` its checks and error tables instead), and `finish` the count. On ``heartbeat``
    (None: none), `tick` prints a line on the material and check under way when nothing was
    printed for `LINE_SECONDS`.
    """

    def __init__(self, console=None, verbose: bool = False, heartbeat=None, clock=time.monotonic):
        self.console, self.verbose, self.heartbeat, self.clock = console, verbose, heartbeat, clock
        self.headed = False
        self.done = self.total = 0
        self.where = ("", "starting")  # material, check
        self.since = self.last_line = clock()
        self._lock = threading.Lock()

    def __call__(self, ev) -> None:
        with self._lock:
            if ev.kind == "start":
                self.total = ev.total
                self.header(ev.renderer, ev.tolerance, ev.vulkan)
            elif ev.kind == "check":
                self.where, self.since = (ev.material, ev.check), self.clock()
            elif ev.kind == "done":
                self.done += 1
                self.material(ev.report)

    def _print(self, *args, **kwargs) -> None:
        if self.console is not None:
            self.console.print(*args, **kwargs)
            self.last_line = self.clock()

    def header(self, renderer, tol, vulkan=None) -> None:
        """The OpenGL renderer (when GLSL runs), the Vulkan device (--runtime vulkan) and the
        tolerance, one line each."""
        self.headed = True
        if renderer:
            self._print(f"OpenGL: {renderer['renderer']} | {renderer['version']}", markup=False, highlight=False)
        if vulkan:
            self._print(f"Vulkan: {vulkan['renderer']} | {vulkan['version']}", markup=False, highlight=False)
        tol_text = (f"derived per point (filtering precision 2^-{tol['filter_bits']}, fp16 weights)"
                    if tol["mode"] == "derived" else f"fixed {tol['value']:g}")
        self._print(f"Tolerance: {tol_text}", markup=False, highlight=False)

    def material(self, m) -> None:
        """One material: its line, or with ``verbose`` its checks and error tables."""
        if not self.verbose:
            status = Text("PASS", style="green") if m.passed else Text("FAIL", style="red")
            self._print(Text.assemble(status, f" {m.name}  {material_line(m)}"), soft_wrap=True, highlight=False)
            return

        status = "[green]PASS[/green]" if m.passed else "[red]FAIL[/red]"
        shares = f"; the texture set of {escape(m.shares)}, checked with it" if m.shares else ""
        self._print(f"\n{status} {escape(m.name)}  ({escape(m.folder)}{shares})")
        if m.input_error:
            self._print(f"  [red]bad input:[/red] {escape(m.input_error)}")
        for c in m.checks:
            mark = {True: "[green]ok[/green]  ", False: "[red]FAIL[/red]", None: "[dim]--[/dim]  "}[c.passed]
            self._print(f"  {mark} {c.name:<12} {escape(c.detail)}")
        if m.channels:
            t = Table(title=f"|GLSL - ONNX| over {m.n_points} (u, v, s) points", title_justify="left")
            for col in ("channel", "max abs", "mean abs", "max tol", "mean tol", "over"):
                t.add_column(col, justify="right" if col != "channel" else "left")
            for ch in m.channels:
                t.add_row(ch["name"], f"{ch['max_abs']:.3g}", f"{ch['mean_abs']:.3g}", f"{ch['max_tolerance']:.3g}",
                          f"{ch['mean_tolerance']:.3g}",
                          str(ch["over_tolerance"]) if ch["passed"] else f"[red]{ch['over_tolerance']}[/red]")
            self._print(t)
            t = Table(title="by sample group (all channels)", title_justify="left")
            for col in ("group", "points", "max abs", "mean abs", "over"):
                t.add_column(col, justify="right" if col != "group" else "left")
            for c in m.categories:
                t.add_row(c["category"], str(c["n"]), f"{c['max_abs']:.3g}", f"{c['mean_abs']:.3g}",
                          str(c["over_tolerance"]))
            self._print(t)

    def finish(self, report) -> None:
        """The header if no material came (no OpenGL), the OpenGL error, the count."""
        with self._lock:
            if not self.headed:
                self.header(report.renderer, report.tolerance, report.vulkan)
            if report.gl_error:
                self._print(f"[red]no {report.unavailable}:[/red] {escape(report.gl_error)}", highlight=False)
            n_ok = sum(m.passed for m in report.materials)
            gap = "\n" if self.verbose else ""
            self._print(f"{gap}{n_ok}/{len(report.materials)} material(s) passed")

    def tick(self) -> None:
        """A heartbeat line when nothing was printed for `LINE_SECONDS`."""
        with self._lock:
            now = self.clock()
            if self.heartbeat is None or now - self.last_line < LINE_SECONDS:
                return
            material, check = self.where
            where = f"{material}: {check}" if material else check
            self.heartbeat.print(f"verify: {self.done}/{self.total} material(s) checked; {where}, "
                                 f"{now - self.since:.0f}s in", markup=False, highlight=False, soft_wrap=True)
            self.last_line = now


def print_report(report, console=None, verbose: bool = False) -> None:
    """The whole human-readable report: the header, one line per material (``verbose``: its
    checks, then the error table per channel and per group of sample points), the count."""
    out = VerifyOutput(console or Console(), verbose)
    out.header(report.renderer, report.tolerance, report.vulkan)
    for m in report.materials:
        out.material(m)
    out.finish(report)


@dataclass(frozen=True)
class CheckSettings:
    """What `run_verify` checks with: the fixed ``tolerance`` (None: the derived per-point bound),
    whether to run the GLSL comparison, the texture unit's ``filter_bits`` (None: the default of
    bcfpipe.verify.checks) and the ``seed`` of the random sample points."""

    tolerance: float | None = None
    glsl: bool = True
    filter_bits: int | None = None
    seed: int = 0
    vulkan: bool = False  # --runtime vulkan: the decoder on Vulkan too, beside OpenGL


def run_verify(path: str, checks: CheckSettings = CheckSettings(), as_json: bool = False, echo=click.echo,
               to_stderr: bool = False, verbose: bool = False, quiet: bool = False) -> int:
    """Verify ``path`` and print the report as it goes, with a heartbeat on stderr unless
    ``quiet``; returns the exit code (what `bcfpipe build --verify` calls)."""
    from bcfpipe.verify import checks as V  # lazy: start-up

    out = VerifyOutput(None if as_json else Console(stderr=to_stderr), verbose,
                       None if quiet else Console(stderr=True))
    filter_bits = V.FILTER_BITS if checks.filter_bits is None else checks.filter_bits
    try:
        with contextlib.nullcontext() if quiet else Ticker(out.tick):
            report = V.verify(path, tolerance=checks.tolerance, glsl=checks.glsl, seed=checks.seed,
                              filter_bits=filter_bits, progress=out, vulkan=checks.vulkan)
    except V.VerifyInputError as e:
        if as_json:
            echo(json.dumps({"path": str(path), "passed": False, "exit_code": EXIT_USAGE, "input_error": str(e)}))
        else:
            click.echo(f"Error: {e}", err=True)
        return EXIT_USAGE
    if as_json:
        echo(json.dumps(report.to_dict(), indent=2))
    else:
        out.finish(report)
    return report.exit_code


@click.command("verify", cls=Command)
@click.argument("out", type=click.Path(exists=True, file_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON report (every figure of -v) instead of text.")
@click.option("--tolerance", type=float, default=None, metavar="X",
              help="Fixed absolute tolerance per output value instead of the derived per-point bound.")
@click.option("--filter-bits", type=click.IntRange(1, 24), default=8, show_default=True,
              help="Fractional precision assumed for the texture unit's bilinear and mip weights.")
@click.option("--no-glsl", is_flag=True, help="Skip the OpenGL comparison (file, weight and OpenImageIO checks only).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the random part of the (u, v, s) grid.")
@click.option("--runtime", type=click.Choice(["opengl", "vulkan"]), default="opengl", show_default=True,
              help="vulkan: also run the shipped SPIR-V decoder (bcfpipe/decoders/) on Vulkan, a GPU's driver or Mesa's "
                   "lavapipe, held to decoder.onnx at the same points, its figure beside OpenGL's.")
@click.option("-v", "--verbose", is_flag=True,
              help="Per material every check and the error tables (default: one line per material).")
@click.pass_context
def verify(ctx: click.Context, out: str, as_json: bool, tolerance: float | None, filter_bits: int, no_glsl: bool,
           seed: int, runtime: str, verbose: bool) -> None:
    """Check the exported material(s) in OUT through the real GLSL decoder.

    OUT is a material folder (material.json) or a build folder (manifest.json, or subfolders with
    material.json). Per material: the files agree with material.json, recorded SHA-256s match,
    weights.bin equals decoder.onnx, OpenImageIO decodes every DDS identically, and
    glsl/bcf_decode.comp run through OpenGL (EGL: GPU driver or Mesa llvmpipe) matches decoder.onnx
    fed features sampled in numpy from the DDS, over a (u, v, s) grid with texel centres and edges,
    wrapping, magnification, fractional lods and lods past the last mip.

    Prints one line per material as it is checked (-v: every check and the error tables), and on
    stderr a line at least every 10 s while a check runs.

    \b
    Exit codes: 0 passed, 1 a check failed, 2 bad input, or no OpenGL (no Vulkan with --runtime vulkan).
    """
    code = run_verify(out, CheckSettings(tolerance, not no_glsl, filter_bits, seed, runtime == "vulkan"),
                      as_json=as_json, verbose=verbose,
                      quiet=bool((ctx.obj or {}).get("quiet")))
    ctx.exit(code if code in (EXIT_OK, EXIT_FAILED, EXIT_USAGE) else EXIT_FAILED)
