"""`bcfpipe train`: one texture set -> one exported neural material folder."""
from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console
from rich.table import Table

from bcfpipe.cli.options import training_record
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.cli.errors import Command
from bcfpipe.errors import EXIT_FAILED, InputError
from bcfpipe.export.material import make_config
from bcfpipe.fit import FitMode, fit, prepare, rate
from bcfpipe.cli.options import training_options
from bcfpipe.texset.texture_set import TextureSpec, load_texture_set, semantic_info
from bcfpipe.train.pace import LINE_SECONDS, Ticker

if TYPE_CHECKING:
    from bcfpipe.train.progress import Progress


def _fmt_eta(sec: float) -> str:
    sec = int(max(sec, 0))
    return f"{sec // 60}m{sec % 60:02d}s" if sec >= 60 else f"{sec}s"


def _line(p: Progress, elapsed: float) -> str:
    """One report: a training step's loss and batch PSNR, or how far a phase without a loss is."""
    if math.isfinite(p.loss):
        psnr = f"{p.psnr:5.2f} dB" if math.isfinite(p.psnr) else "  -  "
        return (f"{p.phase:<11} {p.step:>6}/{p.steps:<6} loss {p.loss:.2e}  psnr {psnr}  "
                f"elapsed {_fmt_eta(elapsed)}  eta {_fmt_eta(p.eta)}")
    steps = f"{p.step:>6}/{p.steps:<6}" if p.steps else " " * 13
    eta = f"  eta {_fmt_eta(p.eta)}" if p.steps and math.isfinite(p.eta) else ""
    return f"{p.phase:<11} {steps} elapsed {_fmt_eta(elapsed)}{eta}"


class _Reporter:
    """Progress to stderr: a rich live line on a TTY; otherwise plain lines, every 5 s while
    reports come and at each phase's last step, and at least every `LINE_SECONDS` whatever the
    training does (a `Ticker` repeats the latest report, its elapsed time brought up to date)."""

    EVERY = 5.0

    def __init__(self, quiet: bool, console=None, clock=time.monotonic):
        self.console = console or Console(stderr=True)
        self.quiet = quiet
        self.live = self.console.is_terminal and not quiet
        self.clock = clock
        self.t0 = clock()
        self.last: float | None = None  # when the last plain line was printed
        self.latest: tuple[Progress, float] | None = None  # the latest report and when it came
        self.lock = threading.Lock()
        self.status = None
        self.ticker = None

    def __enter__(self):
        if self.live:
            self.status = self.console.status("starting")
            self.status.__enter__()
        elif not self.quiet:
            self.ticker = Ticker(self.tick).__enter__()
        return self

    def __exit__(self, *exc):
        if self.ticker is not None:
            self.ticker.__exit__(*exc)
        if self.status is not None:
            self.status.__exit__(*exc)

    def __call__(self, p: Progress) -> None:
        with self.lock:
            now = self.clock()
            self.latest = (p, now)
            if self.status is not None:
                self.status.update(_line(p, p.elapsed))
            elif not self.quiet and (self.last is None or now - self.last > self.EVERY or p.step == p.steps):
                self._print(_line(p, p.elapsed), now)

    def tick(self) -> None:
        """A plain line when none was printed for `LINE_SECONDS`."""
        with self.lock:
            now = self.clock()
            quiet_since = self.t0 if self.last is None else self.last
            if self.quiet or self.status is not None or now - quiet_since < LINE_SECONDS:
                return
            if self.latest is None:
                self._print(f"{'starting':<11} {'':13} elapsed {_fmt_eta(now - self.t0)}", now)
            else:
                p, at = self.latest
                self._print(_line(p, p.elapsed + now - at), now)

    def _print(self, line: str, now: float) -> None:
        self.last = now
        self.console.print(line, highlight=False, markup=False, soft_wrap=True)


def _table(res) -> "object":
    """The result (`FitResult`) as the table a person reads."""
    m = res.metrics
    t = Table(title=f"{res.out}  (profile {res.profile}, preset {res.preset}, {res.device})")
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_row("PSNR, all mips", f"{m.psnr:.2f} dB")
    if res.float_psnr is not None:
        t.add_row("PSNR, float model before quantization", f"{res.float_psnr:.2f} dB")
    for g, v in m.psnr_per_group.items():
        t.add_row(f"  PSNR {g}", f"{v:.2f} dB")
    t.add_row("SSIM (mip 0)", f"{m.ssim:.4f}" if m.ssim is not None else "-")
    t.add_row("FLIP (mip 0, colour)", f"{m.flip:.4f}" if m.flip is not None else "-")
    t.add_row("size", f"{res.size_bytes} B ({res.size_bytes / 2**20:.2f} MiB)")
    if (ch := res.choice) is not None:
        worst = ch.worst_margin_db if ch.worst_margin_db is not None else min(ch.margin_per_mip_db)
        t.add_row("layout", ch.chosen)
        t.add_row("  against BC@R", f"{ch.psnr - ch.bc_psnr:+.2f} dB all mips, worst mip {worst:+.2f} dB, "
                                    f"{ch.bc_size_bytes / 2**20:.2f} MiB")
    t.add_row("train time", f"{res.train_seconds:.1f} s")
    if res.encode_seconds is not None:  # a layout fit: BC@R and its repacks, apart from training
        t.add_row("BC encode time", f"{res.encode_seconds:.1f} s")
    return t


def _load(textures, resolution: int | None, options, wrap: str):
    """The parsed specs and their texture set; a bad spec, file or option exits 2 in one line."""
    try:
        specs = [TextureSpec.parse(t) for t in textures]
        prepare(options, [semantic_info(s.semantic).name for s in specs])  # before the load: it starts workers
        ts = load_texture_set(specs, resolution=resolution, fix_nonfinite=options.fix_nonfinite)
        make_config(ts, options, wrap)  # the profile, device and wrap against this set
    except ValueError as e:
        raise InputError(str(e)) from None
    return specs, ts


def _anchors(report: dict | None, specs, options):
    """--bench-data's measured cells for this set (None without a report): a report without this
    set's source files exits 2."""
    if report is None:
        return None

    anchors = rate.anchors_from_bench(report, [str(TextureSpec(s.semantic, Path(s.path).name, s.channels))
                                               for s in specs])
    if not anchors:
        raise InputError(f"{options.bench_data} has no texture set with these source files")
    return anchors


@click.command("train", cls=Command)
@click.argument("textures", nargs=-1, required=True, metavar="SEMANTIC=FILE[:CHANNELS]...")
@click.option("-o", "--output", required=True, type=click.Path(file_okay=False), help="Output folder.")
@training_options
@click.option("--resolution", type=int, default=None, help="Resample the texture set to this power of two first.")
@click.option("--wrap", type=click.Choice([w.value for w in Wrap]), default=Wrap.REPEAT.value, show_default=True,
              help="Texture addressing of both axes, used in training and recorded for the runtime (build takes "
                   "each axis from USD's wrapS / wrapT).")
@click.option("-f", "--force", is_flag=True, help="Overwrite a non-empty output folder.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object to stdout (progress stays on stderr).")
@click.pass_context
def train_cmd(ctx, textures, output, resolution, wrap, force, as_json, **_training) -> None:
    """Train one neural material from a texture set and export it to OUTPUT.

    Each TEXTURE names a semantic, an image and the channels it contributes:

    \b
      albedo=diff.jpg:rgb      (alias diffuseColor)
      normal=nrm.png:xy        (2 channels, z reconstructed at decode)
      roughness=arm.jpg:g      occlusion=arm.jpg:r   metallic=arm.jpg:b
      displacement=h.exr:r     opacity=a.png:a       emissiveColor=e.png:rgb
      generic=data.tif:rgba    (anything else)

    With --target-psnr the JSON also has "target": the target, whether it was met, the chosen
    profile and preset and every attempt (docs/rate_control.md).

    The JSON output's keys psnr, ssim, flip, size_bytes and train_seconds are a stable interface.
    Exit codes: 0 ok (a missed --target-psnr included: the JSON and stderr say so), 1 training
    failed, 2 bad arguments or unreadable input.
    """
    options, report = training_record(ctx)
    out = Path(output)
    if out.exists() and any(out.iterdir()) and not force:
        raise InputError(f"{out} is not empty; pass --force to overwrite")
    specs, ts = _load(textures, resolution, options, wrap)
    anchors = _anchors(report, specs, options)
    quiet = ctx.find_root().obj.get("quiet", False) if ctx.find_root().obj else False
    try:
        with _Reporter(quiet) as rep:
            def said(text: str) -> None:
                if not quiet:
                    rep.console.print(text, highlight=False)

            fitted = fit(ts, options, out, wrap=wrap, progress=rep, log=said, anchors=anchors)
    except ValueError as e:
        raise InputError(str(e)) from None
    except (FloatingPointError, RuntimeError, MemoryError) as e:
        click.echo(f"bcfpipe train: training failed: {e}", err=True)
        ctx.exit(EXIT_FAILED)
    record = fitted.record()
    if fitted.mode == FitMode.LAYOUT:
        click.echo(f"bcfpipe train: layout {record.choice.chosen}: {record.choice.reason}", err=True)
    elif fitted.target is not None and (not quiet or not fitted.target.met):
        click.echo(f"bcfpipe train: {fitted.target.summary()}", err=True)
    if as_json:
        click.echo(json.dumps(record.to_json()))
    else:
        Console().print(_table(record))
