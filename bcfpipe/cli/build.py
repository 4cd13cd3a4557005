"""`bcfpipe build`: a USD scene in, neural materials and a stage that uses them out.

Exit codes: 0 every modelled material was built (materials the scan skipped are fine); 1 at least
one material failed (the others are still written, and OUT is complete and consistent); 2 bad
arguments, unreadable scene, or an OUT it refuses to replace (nothing is written); 130 interrupted
(Ctrl-C: the workers are stopped, OUT is left as it was).

Live progress goes to stderr (a rich table on a terminal, plain lines otherwise); the summary
table, or with ``--json`` the manifest as one JSON object, goes to stdout.
"""
from __future__ import annotations

import contextlib
import json
import os
from collections import Counter
from dataclasses import replace
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table
from rich.text import Text

from bcfpipe.builder import Execution, Selection, build as run_build
from bcfpipe.builder import ExecutorName
from bcfpipe.builder.ray_executor import require_ray, resolve_executor
from bcfpipe.builder.report import headline_psnr
from bcfpipe.builder.shard import parse_shard, train_shard
from bcfpipe.builder.usd_classic import UNTOUCHED
from bcfpipe.builder.usd_classic import usd_notes
from bcfpipe.cli.options import training_record
from bcfpipe.errors import InputError
from bcfpipe.formats.display import bytes_text
from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.cli.build_display import BuildDisplay
from bcfpipe.cli.errors import Command
from bcfpipe.formats.manifest import Manifest
from bcfpipe.formats.report import BuildReport
from bcfpipe.cli.options import all_materials_option, material_option, training_options, variant_option, texel_density_option
from bcfpipe.layout.choose import ALL_CLASSIC
from bcfpipe.scan.composition import mtlx_documents

__all__ = ["build", "summary_table", "print_summary"]


def _fmt_size(n: int | None) -> str:
    return "" if n is None else bytes_text(n)


COLUMNS = ("material", "status", "outputs", "profile", "PSNR", "size", "train", "encode", "note")
#: what the columns after the material need at least, in characters, for the table form to be readable
_OTHER_COLUMNS_WIDTH = 80


def material_notes(m, r, sharing: dict[str, tuple[str, ...]], usd: dict | None) -> tuple[list[str], list[str]]:
    """(short, detail): the table's note for material ``m`` (report row ``r``), a few words each,
    and what the line under the table says of it in full (the layout's reason, the USD wiring, the
    shared texture set's first material)."""
    failed = m.status == Status.FAILED and bool(m.reason)  # a failure's message is a sentence: said below
    short = ["why: below"] if failed else [m.reason] if m.reason else []
    detail = [m.reason] if failed else []
    if m.status == Status.CONSTANT:
        short.append(f"{len(m.constants)} value(s) authored")
    users = sharing.get(m.job, ()) if m.status == Status.BUILT else ()
    if len(users) > 1:
        short = [f"shared by {len(users)}"]
        detail.append(f"texture set {m.job} shared by {len(users)} materials, trained for {users[0]}"
                      if m.path != users[0] else f"texture set {m.job} shared by {len(users)} materials")
    if m.folded:
        kinds = [f.reason for f in m.folded]
        short.append("folded: " + ", ".join(f"{kinds.count(k)} {k}" for k in
                                            ("constant", "unread", "no-alpha", "duplicate") if k in kinds))
    if m.metrics and m.metrics.detail and m.metrics.detail.covered_fraction is not None:
        short.append(f"PSNR over the {100 * m.metrics.detail.covered_fraction:.0f}% read")
    if r.attempts:
        short.append(f"worker died, retried: {r.attempts} attempts")
    if m.target is not None:
        goal = "met" if m.target.met else "unreachable"
        short.append(f"target {m.target.target_psnr:.1f} dB {goal} after {len(m.target.attempts)} training(s)")
    if m.layout is not None:
        lay = m.layout
        worst = (lay.worst_margin_db if lay.worst_margin_db is not None  # the mips the rule counts
                 else min(lay.margin_per_mip_db) if lay.margin_per_mip_db else 0.0)
        if lay.chosen == ALL_CLASSIC:
            detail.append("layout: BC@R, nothing neural held it at every mip")
        else:
            short.append(f"worst mip {worst:+.1f} dB vs BC@R")
            detail.append(f"layout {lay.chosen}: {lay.psnr - lay.bc_psnr:+.1f} dB all mips, worst mip "
                          f"{worst:+.1f} dB against BC@R")
    if m.layout is not None and m.layout.normal_angle_deg is not None:  # beside the PSNR (issue 57)
        short.append("normal {:.1f}°/{:.1f}° p99".format(*m.layout.normal_angle_deg))
    if m.status == Status.BUILT and usd is not None:
        detail.append(usd.get(m.path, UNTOUCHED))
    return short, detail


def summary_rows(manifest: Manifest, report: BuildReport) -> list[tuple[str, ...]]:
    """One row per material, in `COLUMNS` order (the note short: `material_notes`), then the
    detail under the table says in full: what the end-of-run summary shows."""
    return [row for row, _ in _rows(manifest, report)]


def summary_details(manifest: Manifest, report: BuildReport) -> list[tuple[str, str]]:
    """(material, its notes in full) for each material that has any: the lines under the table."""
    return [(row[0], "; ".join(detail)) for row, detail in _rows(manifest, report) if detail]


def _rows(manifest: Manifest, report: BuildReport) -> list[tuple[tuple[str, ...], list[str]]]:
    out = []
    sharing = {j.name: tuple(j.materials) for j in manifest.jobs}
    usd = usd_notes(os.path.join(report.out, manifest.overrides_layer))  # what the USD layer changed
    for m, r in zip(manifest.materials, report.materials):
        short, detail = material_notes(m, r, sharing, usd)
        head = headline_psnr(m)
        outputs = len({tg.channel for tg in m.targets if tg.channel >= 0})
        profile = (f"{m.profile} {m.preset}" if m.profile and m.preset else m.profile or "")
        if m.layout is not None and m.layout.profile is None:
            profile = "BC@R" if m.layout.chosen == ALL_CLASSIC else "BC7 repack"
        elif m.layout is not None and m.layout.classic:
            profile += " + BC"
        row = (m.path, m.status, str(outputs or ""), profile,
               f"{head:.2f}" if head is not None else "",
               _fmt_size(m.sizes.total_bytes) if m.sizes else "",
               "cached" if r.cache == CacheUse.HIT else f"{r.train_seconds:.1f}s" if r.train_seconds else "",
               "" if r.cache == CacheUse.HIT or r.encode_seconds is None else f"{r.encode_seconds:.1f}s",
               "; ".join(short))
        out.append((row, detail))
    return out


def summary_caption(manifest: Manifest, report: BuildReport) -> str:
    """The totals line under the summary."""
    tot, rt = manifest.totals, report.totals
    cached = f", {rt.cached} from the cache" if rt.cached else ""
    wrote = f"; {rt.written_files} file(s) written" if rt.written_files else "; OUT unchanged"
    encoded = f" (BC encodes {rt.encode_seconds:.1f}s of it, apart from training)" if rt.encode_seconds else ""
    bc_only = len({m.job for m in report.materials if m.status == Status.BUILT and m.cache != CacheUse.HIT
                   and not m.train_seconds})  # the default layout weighed nothing neural: no training
    made = (f"{rt.trained - bc_only} texture set(s) trained and {bc_only} encoded as BC textures only"
            if bc_only else f"{rt.trained} texture set(s) trained")
    return (f"{tot.built} built, {tot.constant} constant, {tot.failed} failed, {tot.skipped} skipped; "
            f"{made}{cached} in {rt.wall_seconds:.1f}s wall{encoded}; "
            f"{_fmt_size(tot.total_bytes)} (sources {_fmt_size(tot.source_bytes)}){wrote}\n"
            "PSNR: dB, the exported files against the source textures, MSE averaged over every mip "
            "(over the texels the meshes read where the note says so)")


_STYLE = {Status.BUILT: "green", Status.CONSTANT: "cyan", Status.FAILED: "red", Status.SKIPPED: "yellow"}


def summary_table(manifest: Manifest, report: BuildReport) -> Table:
    """The end-of-run table: one row per material (paths never wrapped); `print_summary` prints the
    totals under it."""
    t = Table(title=f"bcfpipe build: {manifest.root_layer}", title_justify="left")
    for col in COLUMNS:
        t.add_column(col, overflow="fold", no_wrap=col == "material",
                     justify="right" if col in ("outputs", "PSNR", "size", "train", "encode") else "left")
    for row in summary_rows(manifest, report):
        t.add_row(row[0], Text(row[1], style=_STYLE.get(row[1], "")), *row[2:])
    return t


def _print_details(console: Console, manifest: Manifest, report: BuildReport) -> None:
    """Under the table: each material's notes in full, one line each (never squeezed into a column)."""
    details = summary_details(manifest, report)
    if details:
        console.print("notes:", highlight=False)
    for path, text in details:
        console.print(Text(f"  {path}: {text}"), soft_wrap=True, highlight=False)


def print_summary(console: Console, manifest: Manifest, report: BuildReport) -> None:
    """The summary as a table when the console is wide enough for its longest path and the other
    columns; else one block per material (the path on its own line, the figures below), so that a
    narrow terminal never breaks a path or squeezes a column to one letter."""
    rows = summary_rows(manifest, report)
    longest = max((len(r[0]) for r in rows), default=0)
    if console.width >= longest + _OTHER_COLUMNS_WIDTH:
        console.print(summary_table(manifest, report))
        console.print(summary_caption(manifest, report), highlight=False, soft_wrap=True)  # as wide as it is
        _print_details(console, manifest, report)
        return
    console.print(f"bcfpipe build: {manifest.root_layer}", highlight=False, soft_wrap=True)
    for row in rows:
        console.print(Text(row[0], style="bold"), soft_wrap=True)
        figures = [f"{name} {value}" + (" dB" if name == "PSNR" else "") for name, value in zip(COLUMNS[2:8], row[2:8])
                   if value]
        line = Text("    ").append(row[1], style=_STYLE.get(row[1], ""))
        for part in figures + ([row[8]] if row[8] else []):
            line.append(f", {part}")
        console.print(line, highlight=False)
    console.print(summary_caption(manifest, report), highlight=False)
    _print_details(console, manifest, report)


def nothing_built(manifest) -> str | None:
    """The stderr line of a build that built nothing (no material trained, shared or made
    constant), with the skip reasons counted; None when something was built."""
    if any(m.status in (Status.BUILT, Status.CONSTANT) for m in manifest.materials):
        return None
    reasons = Counter(m.reason or m.status for m in manifest.materials)
    if not reasons:
        mtlx = mtlx_documents(manifest.diagnostics)
        if mtlx:
            return (f"bcfpipe: nothing built: the stage's materials are in {len(mtlx)} MaterialX document(s) "
                    "(.mtlx) that this USD cannot open; bcfpipe reads UsdPreviewSurface only")
        return "bcfpipe: nothing built: the stage has no materials"
    counted = ", ".join(f"{n} {r}" for r, n in sorted(reasons.items(), key=lambda kv: (-kv[1], kv[0])))
    return (f"bcfpipe: nothing built: {len(manifest.materials)} material(s), none modelled ({counted}); "
            "`bcfpipe scan` explains each")


@click.command("build", cls=Command)
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@click.option("-o", "--out", type=click.Path(path_type=Path, file_okay=False),
              help="Output folder (default: <scene>.bcf/ next to the scene).")
@variant_option
@all_materials_option
@material_option
@training_options
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None, metavar="N",
              help="Cores the build may use: at most N busy at once, every process and thread it starts "
                   "counted. N // --threads materials train side by side, and each one's torch threads, BC "
                   "encoders, evaluation, ONNX and OpenImageIO stay within its share; --jobs 1 uses one core "
                   "everywhere (a --threads above N is cut to N). With --executor ray: a Ray of the build's own "
                   "gets N CPUs, a cluster at most N // --threads tasks at once [default: every core: one "
                   "material per core, or per GPU, each encoding on the cores the others leave].")
@texel_density_option
@click.option("--no-coverage", is_flag=True,
              help="Train on every texel, not only on those the bound meshes' uvs cover (the default; "
                   "see docs/build.md).")
@click.option("--cache", "cache_dir", type=click.Path(path_type=Path, file_okay=False),
              help="Cache of trained materials and of BC@R's encoded blocks [default: $BCFPIPE_CACHE, else the user "
                   "cache folder].")
@click.option("--no-cache", is_flag=True, help="Neither read nor write the cache: train every texture set.")
@click.option("--depfile", type=click.Path(path_type=Path, dir_okay=False),
              help="Write the files the result depends on (every composed layer, every texture) as a "
                   "Makefile-syntax depfile, for make or ninja (deps = gcc).")
@click.option("--depfile-target", metavar="NAME",
              help="The depfile's target, like gcc -MT [default: OUT/<scene>.bcf.usda as given].")
@click.option("--executor", "executor_name", type=click.Choice(["auto", "local", "ray"]), default="auto",
              show_default=True,
              help="Where the jobs train: local worker processes, or one Ray task each on a Ray cluster "
                   "(pip install 'bcfpipe[ray]'); auto = ray when --ray-address or RAY_ADDRESS is set.")
@click.option("--ray-address", default=None, metavar="ADDR",
              help="The Ray cluster to use (host:port, or auto for the one `ray start` last started "
                   "here); default RAY_ADDRESS, else a Ray of the build's own, ended after it.")
@click.option("--shard", metavar="I/N", default=None,
              help="Train only shard I of N of the scene's jobs (a job's shard is its content hash mod N) into "
                   "the cache and write nothing else; run every shard (any scheduler), then a plain build "
                   "assembles from the cache without training.")
@click.option("--json", "as_json", is_flag=True,
              help="Print the build report as one JSON object on stdout (schemas/report.schema.json).")
@click.option("--force", is_flag=True, help="Replace the build of another scene in OUT. A folder that bcfpipe did not write (no manifest.json) is never replaced, even with --force.")
@click.option("--verify", "run_verify_after", is_flag=True,
              help="Run `bcfpipe verify` on OUT at the end (GLSL on OpenGL vs ONNX); a failure exits 1.")
@click.option("-v", "--verbose", is_flag=True,
              help="With --verify: per material every check and the error tables (default: one line per material).")
@click.pass_context
def build(ctx: click.Context, scene: Path, out: Path | None, variants: dict[str, str], all_materials: bool,
          materials: tuple[str, ...],
          texel_density: float | None, no_coverage: bool,
          jobs: int | None, cache_dir: Path | None, no_cache: bool, depfile: Path | None,
          depfile_target: str | None, executor_name: str, ray_address: str | None, shard: str | None,
          as_json: bool, force: bool, run_verify_after: bool, verbose: bool, **_training) -> None:
    """Build neural materials for SCENE's textured UsdPreviewSurface materials.

    Writes OUT/<scene>.bcf.usda (open this), overrides.usda, weights.bin, manifest.json and
    materials/<name>/ (DDS features, ONNX, JSON). Trained materials are kept in a content-addressed
    cache: a rebuild trains only texture sets whose bytes or training options changed, and writes
    only files whose bytes changed (a no-op rebuild leaves OUT untouched). Same inputs and options
    on the same device class give byte-identical outputs. See docs/build.md for make, ninja and
    CMake. Exit codes: 0 all built, 1 a material failed, 2 bad input or OUT refused, 130 interrupted.
    """
    training, bench = training_record(ctx)
    quiet = bool((ctx.obj or {}).get("quiet"))
    display = None if quiet else BuildDisplay(Console(stderr=True))
    if no_cache and cache_dir is not None:
        raise click.UsageError("--cache and --no-cache contradict each other")
    selection = Selection(variants, all_materials, tuple(materials), texel_density, not no_coverage, bench)
    execution = Execution(jobs, _executor(executor_name, ray_address), ray_address,
                          False if no_cache else cache_dir, force, depfile, depfile_target)
    if shard is not None:
        refused = ((out, "-o/--out"), (no_cache, "--no-cache"), (depfile, "--depfile"), (run_verify_after, "--verify"))
        _shard(ctx, scene, shard, display, as_json, (training, selection, execution), refused)
        return
    with display or contextlib.nullcontext():
        result = run_build(scene, out, training=training, selection=selection, execution=execution,
                           progress=display)
    code = result.exit_code
    verify_code = None
    if run_verify_after:
        from bcfpipe.cli.verify import run_verify  # lazy: cycle

        # with --json the verify report goes to stderr so stdout stays one JSON object
        verify_code = run_verify(str(result.out), as_json=False,
                                 echo=(lambda m: click.echo(m, err=True)) if as_json else click.echo,
                                 to_stderr=as_json, verbose=verbose, quiet=quiet)
        code = max(code, 0 if verify_code == 0 else 1)
    if as_json:
        click.echo(replace(result.report, verify_exit_code=verify_code).dumps(), nl=False)
    elif not quiet:
        _summary(result)
    if not quiet:
        _warnings(result)
    ctx.exit(code)


def _executor(name: str, ray_address: str | None):
    """--executor resolved (auto: ray when a Ray address is given); ray without its package exits 2."""
    resolved = ExecutorName(resolve_executor(name, ray_address))
    if resolved == ExecutorName.RAY:
        require_ray()  # without the package: one line, exit 2
    return resolved


def _summary(result) -> None:
    """The human summary on stdout, and where to open the result."""
    probe = Console()
    out = probe if probe.is_terminal else Console(width=160)  # pipes/logs: do not wrap at 80 columns
    print_summary(out, result.manifest, result.report)
    shown = os.path.relpath(result.root_layer)
    out.print(f"open {shown if not shown.startswith('..') else result.root_layer}", highlight=False,
              soft_wrap=True)


def _warnings(result) -> None:
    """On stderr: a build that made nothing, suspect input (e.g. a greyscale normal map: said, not
    refused) and --classic semantics no material has."""
    nothing = nothing_built(result.manifest)
    if nothing:
        click.echo(nothing, err=True)
    for mp in result.plan.materials:
        for w in mp.warnings:
            click.echo(f"bcfpipe: warning: {mp.path}: {w}", err=True)
    for sem in result.plan.unused_classic:
        click.echo(f"bcfpipe: warning: --classic {sem}: no modelled material has such a channel", err=True)


def _shard(ctx: click.Context, scene: Path, text: str, display, as_json: bool, records: tuple,
           refused: tuple) -> None:
    """`build --shard I/N`: train one shard into the cache (bcfpipe.builder.shard). ``records``:
    (training, selection, execution); ``refused``: (given, flag) pairs a shard does not take."""
    shard = parse_shard(text)
    for given, flag in refused:
        if given:
            raise InputError(f"--shard trains into the cache and writes nothing else; drop {flag}")
    with display or contextlib.nullcontext():
        res = train_shard(scene, shard, *records, progress=display)
    quiet = display is None
    if as_json:
        click.echo(json.dumps(res.to_json(), indent=2))
    elif not quiet:
        counts = {k: sum(1 for j in res.jobs if (j.cache if j.status == Status.BUILT else Status.FAILED) == k)
                  for k in (CacheUse.MISS, CacheUse.HIT, Status.FAILED)}
        click.echo(f"shard {shard[0]}/{shard[1]}: {len(res.jobs)} of {res.total_jobs} job(s); {counts['miss']} "
                   f"trained, {counts['hit']} already cached, {counts['failed']} failed; cache {res.cache}")
        for j in res.jobs:
            if j.status != Status.BUILT:
                click.echo(f"  {j.name}: failed: {j.reason}")
    ctx.exit(res.exit_code)
