"""`bcfpipe bench`: what each profile and preset buys against BC, the BC7 quality set and ASTC, measured,
drawn and tabled."""
from __future__ import annotations

import json
from pathlib import Path

import click

from bcfpipe.bench import report as R
from bcfpipe.bench.decode_cost import SIZES
from bcfpipe.bench.sets import from_scene, from_specs
from bcfpipe.cli.errors import Command
from bcfpipe.cli.options import variant_option
from bcfpipe.config import DEFAULT_DEVICE, DEFAULT_SEED, DEFAULT_THREADS, PRESETS, PROFILE_NAMES
from bcfpipe.errors import EXIT_FAILED, InputError
from bcfpipe.extras import require
from bcfpipe.texset.baselines import CODECS, astcenc_path
from bcfpipe.texset.baselines import parse_block

__all__ = ["bench"]

SCENE_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def _list(text: str, what: str, allowed=None) -> tuple[str, ...]:
    items = tuple(x.strip() for x in text.split(",") if x.strip())
    if allowed is not None:
        bad = [x for x in items if x not in allowed]
        if bad:
            raise InputError(f"{what}: unknown {', '.join(bad)}; choose from {', '.join(allowed)}")
    return items


def _size(text: str) -> tuple[int, int]:
    if text in SIZES:
        return SIZES[text]
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--decode-size: expected 1080p, 1440p, 2160p or WxH, got {text!r}") from None
    if w < 1 or h < 1:
        raise InputError(f"--decode-size must be positive, got {text!r}")
    return w, h


def _codecs(baselines: str) -> tuple[str, ...]:
    """--baselines, checked; astc without astcenc exits 2."""
    codecs = _list(baselines, "--baselines", CODECS)
    if "astc" in codecs and astcenc_path() is None:
        raise InputError("astcenc not found: install it (apt-get install astcenc), set $ASTCENC, "
                         "or pass --baselines bc")
    return codecs


def _astc_blocks(text: str) -> tuple[str, ...]:
    """--astc-blocks, each a block size astcenc takes."""
    blocks = _list(text, "--astc-blocks")
    for b in blocks:
        try:
            parse_block(b)
        except ValueError as e:
            raise InputError(f"--astc-blocks: {e}") from None
    return blocks


def _sets(inputs, materials, variants, name):
    """The texture sets to measure: a scene's modelled materials, or one set of texture specs."""
    if len(inputs) == 1 and inputs[0].lower().endswith(SCENE_SUFFIXES) and "=" not in inputs[0]:
        return from_scene(inputs[0], materials, variants)
    if materials:
        raise InputError("--material needs a SCENE, not texture specs")
    return [from_specs(inputs, name)]


def _redraw(inputs, output: Path, as_json: bool) -> None:
    """--redraw: the plots, HTML and markdown of ``output`` again, from its bench.json."""
    if inputs:
        raise InputError("--redraw takes no inputs: it redraws OUTPUT from its bench.json")
    data = R.read_report(output)
    R.write_report(data, output)
    click.echo(json.dumps(data, indent=1) if as_json else f"redrew {output / R.HTML_FILE}")


@click.command("bench", cls=Command)
@click.argument("inputs", nargs=-1, metavar="SCENE | SEMANTIC=FILE[:CHANNELS]...")
@click.option("-o", "--output", "output", type=click.Path(path_type=Path, file_okay=False),
              help="Report folder: index.html, bench.json, summary.md and the PNGs.")
@click.option("--material", "materials", multiple=True, metavar="PRIM",
              help="With a SCENE: bench only the texture set of this material (repeatable).")
@variant_option
@click.option("--name", default=None, help="With texture specs: the set's name in the report (default: first file).")
@click.option("--profiles", default="0.5k,1k", show_default=True, help="Comma list of BCf profiles.")
@click.option("--presets", default="fast,standard", show_default=True, help="Comma list of BCf presets.")
@click.option("--baselines", default="bc,astc", show_default=True,
              help="Comma list of classic codecs: bc (BC1/BC4/BC5 as an engine packs the set), astc.")
@click.option("--astc-blocks", default="4x4,6x6,8x8,12x12", show_default=True, help="ASTC block sizes.")
@click.option("--no-half", is_flag=True, help="Baselines at full resolution only (default: full and half).")
@click.option("--decode-size", default="1080p", show_default=True,
              help="Frame of the decode-cost pass: 1080p, 1440p, 2160p or WxH.")
@click.option("--decode-frames", type=click.IntRange(min=1), default=None,
              help="Frames per pass (default 100 on a GPU, 3 on a software renderer).")
@click.option("--features", "features", default="bc6h", show_default=True, metavar="LIST",
              help="Feature formats to train, comma-separated: bc6h (the paper's), bc7; one cell per "
                   "profile, preset and format.")
@click.option("--seed", type=int, default=DEFAULT_SEED, show_default=True)
@click.option("--device", default=DEFAULT_DEVICE, show_default=True, help="auto, cpu or cuda[:N].")
@click.option("--threads", type=click.IntRange(min=1), default=DEFAULT_THREADS, show_default=True,
              help="Torch CPU threads per training.")
@click.option("--keep-materials", is_flag=True, help="Keep each cell's exported material under OUTPUT/materials.")
@click.option("--redraw", is_flag=True, help="Redraw the plots, HTML and markdown of OUTPUT from its bench.json.")
@click.option("-f", "--force", is_flag=True, help="Write into a non-empty OUTPUT.")
@click.option("--json", "as_json", is_flag=True, help="Print bench.json to stdout (progress stays on stderr).")
@click.pass_context
def bench(ctx, inputs, output, materials, variants, name, profiles, presets, baselines, astc_blocks, no_half,
          decode_size, decode_frames, features, seed, device, threads, keep_materials, redraw, force, as_json) -> None:
    """Measure BCf presets and profiles against BC, the BC7 quality set and ASTC on a texture set, and report.

    \b
      bcfpipe bench scene.usda -o report/                 every modelled material
      bcfpipe bench scene.usda --material /World/Looks/Brick -o report/
      bcfpipe bench albedo=d.jpg:rgb normal=n.png:xy -o report/

    For each set: every (profile, preset) BCf cell is trained and measured from its exported files;
    BC (BC1 colour and packed maps, BC5 normal xy, BC4 lone scalars), the BC7 quality set (BC7 for
    colour and packed maps) and ASTC (-thorough) encode every mip at full and half size and at each
    profile's R. All use one metric code: PSNR over all mips, per mip and per channel group, SSIM
    and FLIP at mip 0, GPU bytes and bytes on disk (zstd 19), time, and margins against BC@R. The decode
    cost is a full-screen pass of each BCf material against one sampling the BC textures, frames
    interleaved, on the machine's OpenGL (on llvmpipe only the ratio is meaningful).

    The JSON's keys (format bcfpipe-bench, version 1) are a stable interface.
    Exit codes: 0 ok, 1 a measurement failed, 2 bad arguments or unreadable input.
    """
    require("matplotlib", "bench", "bcfpipe bench")  # before any measuring: its figures need it
    if output is None:
        raise InputError("missing -o/--output REPORT_DIR")
    if redraw:
        _redraw(inputs, output, as_json)
        return
    if not inputs:
        raise InputError("give a SCENE or texture specs (SEMANTIC=FILE[:CHANNELS]); see --help")
    if output.exists() and any(output.iterdir()) and not force:
        raise InputError(f"{output} is not empty; pass --force to write into it")

    from bcfpipe.bench.run import BenchOptions, run_bench  # lazy: start-up

    opts = BenchOptions(profiles=_list(profiles, "--profiles", PROFILE_NAMES),
                        presets=_list(presets, "--presets", tuple(PRESETS)), codecs=_codecs(baselines),
                        features=_list(features, "--features", ("bc6h", "bc7")),
                        astc_blocks=_astc_blocks(astc_blocks), shifts=(0,) if no_half else (0, 1),
                        seed=seed, device=device, threads=threads, decode_size=_size(decode_size),
                        decode_frames=decode_frames, keep_materials=keep_materials)
    sets = _sets(inputs, materials, variants, name)
    quiet = bool(ctx.find_root().obj and ctx.find_root().obj.get("quiet"))
    try:
        data = run_bench(sets, opts, output, quiet=quiet)
    except (FloatingPointError, RuntimeError, MemoryError) as e:
        click.echo(f"bcfpipe bench: a measurement failed: {e}", err=True)
        ctx.exit(EXIT_FAILED)
    R.write_report(data, output)
    failed = [f"{s['name']}: {f['method']}: {f['error']}" for s in data["sets"] for f in s["failed"]]
    if as_json:
        click.echo((output / R.JSON_FILE).read_text(), nl=False)
    else:
        click.echo(R.summary_markdown(R.read_report(output)), nl=False)
        click.echo(f"report: {output / R.HTML_FILE}", err=True)
    for line in failed:
        click.echo(f"bcfpipe bench: training failed: {line}", err=True)
    if failed:
        ctx.exit(EXIT_FAILED)
