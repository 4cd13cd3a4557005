"""`bcfpipe plan`: the jobs a build would run, without running them.

Exit codes: 0 the plan was made, 2 the stage cannot be read or an option is bad.
"""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape

from bcfpipe.builder import plan
from bcfpipe.builder import Selection
from bcfpipe.cache.store import LAYOUT
from bcfpipe.cli.options import training_record
from bcfpipe.config import resolve_profile
from bcfpipe.formats.display import bytes_text, dims_text
from bcfpipe.formats.display import bytes_range
from bcfpipe.formats.images import FLOAT_TYPES
from bcfpipe.formats.vocabulary import Decision
from bcfpipe.cli.errors import Command
from bcfpipe.layout.classic import MAX_REPACK_SIDE
from bcfpipe.layout.predict import build_range
from bcfpipe.layout.predict import predict_specs
from bcfpipe.layout.predict import bc_resolution, uses_layout
from bcfpipe.process_env import default_cache_root
from bcfpipe.scan.composition import counted
from bcfpipe.cli.options import all_materials_option, material_option, texel_density_option, training_options, variant_option
from bcfpipe.scan.texture_sets import decoder_index

__all__ = ["plan_cmd"]


def plan_json(bplan) -> dict:
    """The plan as JSON: every job with its content hash, materials, sources (with hashes) and
    options, and ``prediction``: the resolution R, the profiles and probe the build will use, BC@R's
    bytes and the bytes it can ship (`bcfpipe.layout.predict`), with every all-neural candidate's
    bytes and the BC7 quality set's; ``built``: the layout.json of the job's cached build, if any
    (every layout's per-mip figures against BC@R and the BC7 quality set, measured); the packed
    coverage mask is replaced by its covered fraction (already given). ``predicted_bytes``: the
    build's range, every job summed."""
    d = bplan.to_dict()
    preds = [job_prediction(j) for j in bplan.jobs]
    for job, j, p in zip(bplan.jobs, d["jobs"], preds):
        j.pop("coverage", None)
        j["prediction"] = p.to_json() if p is not None else None
        j["built"] = built_layout(job)
    known = [p for p in preds if p is not None]

    lo, hi = build_range(known) if known and len(known) == len(preds) else (None, None)
    d["predicted_bytes"] = {"min": lo, "max": hi} if lo is not None else None
    return d


def job_prediction(job):
    """What the build will weigh for ``job`` and the bytes it can ship (None under --target-psnr)."""
    w, h = job.size
    return predict_specs(job.specs, [s.path for s in job.sources if s.format in FLOAT_TYPES], w, h, job.options,
                         job.vectors)


@click.command("plan", cls=Command)
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@variant_option
@all_materials_option
@material_option
@training_options
@texel_density_option
@click.option("--no-coverage", is_flag=True, help="As for build: train on every texel.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan as one JSON object on stdout.")
def plan_cmd(scene: Path, variants: dict[str, str], all_materials: bool, materials: tuple[str, ...],
             texel_density: float | None, no_coverage: bool, as_json: bool, **_training) -> None:
    """List the training jobs `bcfpipe build SCENE` would run with these options: each job's
    content hash (its cache key), materials, channels, resolution, profile and covered fraction.
    Reads and hashes the textures; trains and writes nothing."""
    training, bench = training_record(click.get_current_context())

    bplan = plan(scene, training, Selection(variants, all_materials, tuple(materials), texel_density,
                                            not no_coverage, bench))
    if as_json:
        click.echo(json.dumps(plan_json(bplan), indent=2))
        return
    con = Console()
    say = lambda text: con.print(text, highlight=False, soft_wrap=True)  # noqa: E731
    say(f"bcfpipe plan: {bplan.scene}")
    _say_warnings(say, bplan)
    for j in bplan.jobs:
        _say_job(say, j)
    _say_decisions(say, bplan)
    _say_range(say, bplan)


def _say_warnings(say, bplan) -> None:
    """The stage's diagnostics, each material's warnings and unused --classic names."""
    for line in counted(bplan.diagnostics):
        say(f"[yellow]usd:[/yellow] {escape(line)}")
    for m in bplan.materials:
        for w in m.warnings:
            say(f"[yellow]warning:[/yellow] {m.path}: {escape(w)}")
    for sem in bplan.unused_classic:
        say(f"[yellow]warning:[/yellow] --classic {escape(sem)}: no modelled material has such a channel")


def _say_job(say, j) -> None:
    """One job: its size, profile, outputs, coverage and key; how its layout is decided; what it
    ships; its materials."""
    w, h = j.size
    prof = _profile(j)
    read = f"{100 * j.covered_fraction:.0f}% of texels read" if j.covered_fraction is not None else "every texel"
    say(f"[bold]{j.name}[/bold]  {dims_text(w, h)}, profile {prof}, {_outputs(j)} outputs, {read}, "
        f"content hash {j.content_hash[:16]}")

    pred = job_prediction(j)
    if uses_layout(j.options, [sem for sem, _, _ in j.specs]):
        r = bc_resolution(max(w, h), j.options.profile)
        files = {f for sem, f, _ in j.specs if sem in (j.options.classic or ())}
        kept = list(dict.fromkeys(sem for sem, f, _ in j.specs if f in files))  # a packed file goes whole
        held = f"; {', '.join(kept)} kept as BC textures (--classic)" if kept else ""
        bc = f" ({bytes_text(pred.bc_bytes)})" if pred else ""
        if j.options.layout == "auto":
            repack = (" and its BC7 repacks (encoded, not trained)" if pred is None or pred.repack_bytes else
                      "; no BC7 repack fits its bytes") if r <= MAX_REPACK_SIDE else ""
            probe = pred.probe_text() if pred else "a probe (the largest profile within BC@R's bytes)"
            more = (", at most one more training (a mixed layout, a wider T_0 or a mip split), decided when "
                    "trained" if pred is None or pred.probe else "")
            say(f"    layout auto: against BC@{r}{bc}{repack}{held}; {probe}{more} (docs/layout.md)")
            if pred is not None and pred.probe:
                _say_weighed(say, pred)
        else:
            say(f"    layout: against BC@{r}{bc}{held}; the rest neural at {prof}")
    if pred is not None:
        say(f"    ships {pred.size_text()}" + ("" if pred.exact else
                                                 f" (at most BC@{pred.resolution}'s bytes: what training decides)"
                                                 if not j.options.match_bc else " (--match-bc: any size)"))
    built = built_layout(j)
    if built is not None:
        _say_built(say, built)
    for m in j.materials:
        say(f"    {m}")


def _say_weighed(say, pred) -> None:
    """The all-neural candidates' GPU bytes by profile and T_0 width, and the BC7 quality set's."""
    by = {}
    for p, w, b in pred.neural:
        by.setdefault(p, []).append(f"{w} layer{'s' if w > 1 else ''} {bytes_text(b)}")
    text = "; ".join(f"{p}: T_0 of {', '.join(v)}" for p, v in by.items())
    q = f"; the BC7 quality set {bytes_text(pred.bc7_bytes)} (reported against)" if pred.bc7_bytes else ""
    say(f"    weighs neural {text}{q}")


def built_layout(job) -> dict | None:
    """The layout.json of ``job``'s cached build (its content hash in the default cache), if there is
    one: what a build of this job ships, measured. Read only: plan writes nothing."""
    path = default_cache_root() / LAYOUT / "entries" / job.content_hash[:2] / job.content_hash / "layout.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _say_built(say, d: dict) -> None:
    """A cached job's layout: the one shipped, its bytes and its per-mip margins."""
    c = d["chosen"]
    disk = f", {bytes_text(c['disk_bytes'])} on disk (zstd 19)" if c.get("disk_bytes") else ""
    say(f"    cached: ships {c['layout']}, {bytes_text(c['size_bytes'])}{disk}, {c['psnr']:.2f} dB")
    if c.get("margin_per_mip_db"):
        say("      per mip against BC@R: " + " ".join(f"{v:+.1f}" for v in c["margin_per_mip_db"]) + " dB")
    if c.get("margin_vs_bc7_per_mip_db"):
        say("      against the BC7 quality set: " + " ".join(f"{v:+.1f}" for v in c["margin_vs_bc7_per_mip_db"]) + " dB")


def _say_decisions(say, bplan) -> None:
    """The constant and skipped materials (those not selected aside), then the counts."""
    skipped = Counter(m.reason for m in bplan.materials if m.decision == Decision.SKIP)
    for m in bplan.materials:
        if m.decision == Decision.CONSTANT:
            say(f"[cyan]constant[/cyan] {m.path}: {m.message}")
        elif m.decision == Decision.SKIP and m.reason != "not-selected":
            say(f"[yellow]skip: {m.reason}[/yellow] {m.path}: {escape(m.message)}")
    counts = {d: sum(1 for m in bplan.materials if m.decision == d) for d in Decision}
    reasons = ", ".join(f"{n} {r}" for r, n in sorted(skipped.items(), key=lambda kv: (-kv[1], kv[0])))
    say(f"{len(bplan.jobs)} job(s) for {counts['model']} modelled material(s); {counts['constant']} constant, "
        f"{counts['skip']} skipped" + (f" ({reasons})" if reasons else ""))


def _say_range(say, bplan) -> None:
    """The bytes the whole build ships, when every job's can be predicted."""
    preds = [job_prediction(j) for j in bplan.jobs]
    if preds and all(p is not None for p in preds):
        lo, hi = build_range(preds)
        exact = all(p.exact for p in preds)
        say(f"the build ships {bytes_range(lo, hi)}" + ("" if exact else
                                                                        " (each layout decided when trained)"))


def _profile(job) -> str:
    """The profile the job trains at, as `build` reports it (``auto`` resolved from the job's size)."""
    if job.options.target_psnr is not None:
        return f"chosen for target {job.options.target_psnr:g} dB ({'bench' if job.anchors else 'probe'})"
    name, _ = resolve_profile(job.options.profile, max(job.size))
    return name


def _outputs(job) -> int:
    """Decoder outputs: the job's channels, and normal z when a normal map is modelled."""
    _, z = decoder_index(job.channels)
    return len(job.channels) + (z is not None)
