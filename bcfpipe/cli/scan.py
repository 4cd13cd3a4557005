"""`bcfpipe scan`: list a scene's materials and whether `build` would model them.

Exit codes: 0 when the stage was scanned (skipped materials included),
2 when the stage cannot be read, ``--variant`` is malformed, unknown or repeated for one set, or a
texture a build would read is refused (empty, truncated, damaged, NaN/Inf texels): after the
report, the build's own one-line error on stderr.
"""
from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import click
from rich.console import Console
from rich.markup import escape
from rich.text import Text

from bcfpipe.builder.plan import refusal, source_problems
from bcfpipe.errors import EXIT_USAGE
from bcfpipe.formats.display import bytes_range, bytes_text, dims_text, file_name
from bcfpipe.formats.vocabulary import Decision
from bcfpipe.cli.errors import Command
from bcfpipe.cli.options import all_materials_option, material_option, texel_density_option, variant_option
from bcfpipe.layout.predict import predict_specs
from bcfpipe.scan.requirements import requirements
from bcfpipe.scan.results import MaterialScan, StageScan
from bcfpipe.scan.stage import scan_stage
from bcfpipe.scan.composition import counted, mtlx_documents
from bcfpipe.scan.grouping import Grouping, group_materials

__all__ = ["scan"]


def _texture_lines(material: MaterialScan, grouping: Grouping) -> list[Text]:
    """One line per textured input: ``input ← file:channel`` (problems in red, fallbacks in
    yellow), then the channels folded away (constant, duplicate, no alpha)."""
    lines = []
    for inp in material.texture_inputs:
        tex = inp.texture
        assert tex is not None
        name = file_name(tex.asset_path) if tex.asset_path else "(no file)"
        style = None if tex.ok else "yellow" if tex.uses_fallback else "red"
        lines.append(Text(f"{inp.name} ← {name}:{tex.channel}" + (" (fallback)" if tex.uses_fallback else ""),
                          style=style))
    mm = grouping.model_of(material.path)
    for f in mm.folded if mm else ():
        what = f"= {file_name(f.same_as.file)}:{f.same_as.channel}" if f.same_as else f"= {f.value:.4g}"
        lines.append(Text(f"folded {file_name(f.file)}:{f.channel} {f.reason} {what}", style="cyan"))
    return lines


def decision(material: MaterialScan, grouping: Grouping) -> str:
    """model, constant (every textured input folded to a value) or skip: as `plan` and `build`."""
    return grouping.outcome(material)[0]


def _decision_text(material: MaterialScan, grouping: Grouping) -> Text:
    """``model`` in green, ``constant`` in cyan, ``skip: reason`` in yellow."""
    outcome, reason, _ = grouping.outcome(material)
    if outcome == Decision.CONSTANT:
        return Text("constant", style="cyan")
    if outcome == Decision.MODEL:
        return Text("model" + (f": {reason}" if reason else ""), style="red" if reason else "green")
    return Text(f"skip: {reason}", style="yellow")


def _need_line(req: dict | None) -> Text:
    """Texel density, the resolution, profile and size a build would choose, on one line."""
    if not req:
        return Text("")
    parts = []
    d = req.get("density") or {}
    if d.get("texel_density"):
        low = (f" (lowest mesh {d['lowest_mesh_density']:.0f})"
               if d.get("lowest_mesh_density") and d["meshes"] > 1 else "")
        parts.append(f"{d['texel_density']:.0f} px/m{low}")
    if req["decision"] == Decision.MODEL:
        if req.get("covered_fraction") is not None:
            parts.append(f"{100 * req['covered_fraction']:.0f}% of texels read")
        cap = f" capped: {req['texel_density_reached']:.0f} px/m" if req["capped"] else ""
        lay = req.get("layout")
        size = dims_text(req["width"], req["height"])
        if not req["estimated_bytes"]:
            parts.append(f"{size}{cap}, profile {req['profile']}, shared")
        elif lay:  # what the default layout weighs (bcfpipe.layout.predict): R, the probe, BC@R, the range
            parts.append(f"{size}{cap}, layout auto against BC@{lay['resolution']} "
                         f"({bytes_text(lay['bc_bytes'])}), {_probe_words(lay)}, profiles up to "
                         f"{req['profile']}, ships {bytes_range(req['estimated_min_bytes'], req['estimated_bytes'])}")
        else:
            parts.append(f"{size}{cap}, profile {req['profile']}, {bytes_text(req['estimated_bytes'])}")
    text = Text(", ".join(parts), style="dim")
    for note in d.get("notes", [])[:2]:
        text.append(f"; {note}" if text.plain else note, style="yellow")
    return text


def _probe_words(lay: dict) -> str:
    """The probe as `LayoutPrediction.probe_text` weighs it, in scan's short form."""
    if lay["probe"] is None:
        return "no probe (nothing neural fits within BC@R's bytes)"
    return f"probe {lay['probe']}" + ("" if lay["probe_fits"] else " (the smallest profile: none fits within BC@R's bytes)")


def _print_material(m: MaterialScan, grouping: Grouping, reqs: dict, console: Console) -> None:
    """A material's block: its path on a line of its own (never broken), the decision and why,
    its textured inputs, what a build would choose, and its warnings, indented below."""
    head = Text(m.path, style="bold")
    if m.aliases:
        head.append(f" (+{len(m.aliases)} instances)")
    head.append("  ").append_text(_decision_text(m, grouping))
    if not m.bound and m.reason != "unbound":
        head.append("  (unbound)", style="dim")
    console.print(head, highlight=False, soft_wrap=True)
    outcome, reason, message = grouping.outcome(m)
    body: list[Text] = []
    if outcome != Decision.MODEL or reason:
        body.append(Text(message, style="dim"))
    elif m.aliases:
        body.append(Text(f"instances: {', '.join(m.aliases[:3])}" + (" …" if len(m.aliases) > 3 else ""),
                         style="dim"))
    body += _texture_lines(m, grouping)
    need = _need_line(reqs["materials"].get(m.path))
    if need.plain:
        body.append(need)
    mm = grouping.model_of(m.path)
    body += [Text(f"warning: {w}", style="yellow") for w in (mm.warnings if mm else m.warnings)]
    for line in body:
        console.print(Text("    ").append_text(line), highlight=False, soft_wrap=True)


def _conclusion(result: StageScan, grouping: Grouping, refusals: list[str], reqs: dict) -> str:
    """What a build of this stage would do, in one sentence, with every skip reason counted."""
    outcomes = [grouping.outcome(m) for m in result.materials]
    n_model = sum(1 for d, r, _ in outcomes if d == Decision.MODEL)
    n_const = sum(1 for d, _, _ in outcomes if d == Decision.CONSTANT)
    skips = Counter(r for d, r, _ in outcomes if d == Decision.SKIP)
    skipped = ", ".join(f"{n} {r}" for r, n in sorted(skips.items(), key=lambda kv: (-kv[1], kv[0])))
    mtlx = mtlx_documents(result.composition_errors)
    if grouping.failed:
        return (f"conclusion: a build stops before training (exit 2): {len(grouping.failed)} material(s) read "
                "textures it cannot read (above)")
    if refusals:
        return (f"conclusion: a build stops before training (exit 2): {len(refusals)} source(s) it refuses "
                "(above)")
    if not result.materials and mtlx:
        return (f"conclusion: a build builds nothing: the stage's materials are in {len(mtlx)} MaterialX "
                f"document(s) (.mtlx) that this USD cannot open, and bcfpipe reads UsdPreviewSurface only")
    if not result.materials:
        return "conclusion: a build builds nothing: the stage has no materials"
    if not n_model and not n_const:
        why = "MaterialX only, which bcfpipe does not read" if set(skips) == {"materialx-only"} else skipped
        return f"conclusion: a build builds nothing: {len(result.materials)} material(s), none modelled ({why})"
    tail = f"; skipped: {skipped}" if skipped else ""
    classic = sum(1 for g in grouping.groups if _classic_only(reqs["materials"].get(g.materials[0])))
    sets = (f"trains {len(grouping.groups) - classic} texture set(s) and encodes {classic} as BC textures only "
            "(no neural layout fits within their BC@R's bytes)" if classic else
            f"trains {len(grouping.groups)} texture set(s)")
    return f"conclusion: a build {sets} for {n_model} material(s) and authors {n_const} constant material(s){tail}"


def _classic_only(req: dict | None) -> bool:
    """Whether the default layout weighs nothing neural for this set (no probe: `predict`)."""
    lay = (req or {}).get("layout")
    return bool(lay) and lay["layout"] == "auto" and lay["probe"] is None


def _print_human(result: StageScan, grouping: Grouping, reqs: dict, refusals: list[str], console: Console) -> None:
    """Stage facts, one block per material, the variant selections that bind other materials,
    and the conclusion."""
    say = lambda text: console.print(text, highlight=False, soft_wrap=True)  # noqa: E731
    say(f"[bold]{result.path}[/bold]")
    say(f"upAxis={result.up_axis}  metersPerUnit={result.meters_per_unit:g}  "
        f"defaultPrim={result.default_prim or '-'}  rendered gprims={result.rendered_gprims}")
    for prim, vset, value in result.variant_selections:
        say(f"variant {vset}={value} on {prim}")
    if result.dangling_bindings:
        more = len(result.dangling_bindings) - 1
        say(f"[yellow]warning:[/yellow] binding to missing material {result.dangling_bindings[0]}"
            + (f" (and {more} more missing material(s))" if more else ""))
    for error in counted(result.composition_errors):
        say(f"[yellow]composition error:[/yellow] {escape(error)}")
    for note in counted(result.diagnostics):
        say(f"[yellow]usd:[/yellow] {escape(note)}")
    hidden = [m for m in result.materials if m.reason == "not-selected"]
    for m in result.materials:
        if m.reason != "not-selected":
            _print_material(m, grouping, reqs, console)
    if hidden:
        say(f"{len(hidden)} other material(s) not named by --material")
    for vset, value, mats in result.binding_variants:
        say(f"[yellow]variant[/yellow] {vset}={value} binds {len(mats)} material(s) these selections leave "
            f"unbound (e.g. {mats[0]}): add --variant {vset}={value} to scan or build them")
    if result.variants_untried:
        say(f"[dim]{result.variants_untried} more variant choice(s) not tried for bindings[/dim]")
    for path, message in grouping.failed.items():
        say(f"[red]unreadable:[/red] {path}: {escape(message)}")
    tot = reqs["totals"]
    say(f"a build writes {bytes_range(tot['estimated_min_bytes'], tot['estimated_bytes'])} "
        f"({tot['texture_sets']} texture set(s), each layout decided when trained); "
        f"modelling everything (no folding, no density cap): up to {bytes_text(tot['everything_estimated_bytes'])} "
        f"({tot['everything_texture_sets']} texture set(s))")
    for line in refusals:
        say(f"[red]refused:[/red] {escape(line)}")
    say(f"[bold]{_conclusion(result, grouping, refusals, reqs)}[/bold]")


@click.command("scan", cls=Command)
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@variant_option
@all_materials_option
@material_option
@texel_density_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout instead of a table.")
def scan(scene: Path, variants: dict[str, str], all_materials: bool, materials: tuple[str, ...],
         texel_density: float | None, as_json: bool) -> None:
    """Scan SCENE's UsdPreviewSurface materials: which ones `build` would model, and why not.

    Also what the scene requires: channels folded (constant or duplicate), the source's texel
    density on the bound meshes, the resolution, profile and size a build would choose, and the
    total against modelling everything. JSON keys: docs/build.md.

    \b
    Exit codes: 0 scanned (skipped materials included); 2 the stage cannot be read, a bad or
    repeated --variant, or a texture a build would read is refused (unreadable, NaN/Inf texels):
    the build's own one-line error follows the report on stderr.
    """
    result = scan_stage(scene, variants or None, all_materials=all_materials, materials=materials,
                        binding_variants_too=True)
    cache: dict = {}
    grouping = group_materials(scene, variants, result.materials, cache, digest=False)
    everything = group_materials(scene, variants, result.materials, cache, digest=False, fold=False)

    reqs = requirements(grouping, everything, texel_density=texel_density, predict=predict_specs)

    refusals = source_problems(grouping, cache)  # what plan and build refuse, in the same words
    if as_json:
        d = result.to_dict()
        for m, md in zip(result.materials, d["materials"]):
            md["decision"], md["reason"], md["message"] = grouping.outcome(m)
            mm = grouping.model_of(m.path)
            md["folded"] = [f.to_dict() for f in mm.folded] if mm else []
            md["constants"] = [{"target": c.target, "input": c.input, "value": c.value} for c in mm.constants] \
                if mm else []
            md["requirements"] = reqs["materials"].get(m.path)
        d["texture_sets"] = [g.to_dict() for g in grouping.groups]
        d["texel_density_requested"] = texel_density
        d["requirements"] = reqs["totals"]
        d["instanced"] = sorted(grouping.instanced)
        d["unreadable"] = dict(grouping.failed)
        d["refused"] = refusals
        click.echo(json.dumps(d, indent=2))
    else:
        _print_human(result, grouping, reqs, refusals, Console())
    if refusals:  # the build's own line and exit code, on stderr
        raise refusal(refusals)
    if grouping.failed:  # as the build, which refuses an unreadable texture before training
        click.get_current_context().exit(EXIT_USAGE)
