"""`bcfpipe scan`: list a scene's materials and whether `build` would model them.

Exit codes: 0 when the stage was scanned (skipped materials included),
2 when the stage cannot be read or ``--variant`` is malformed or unknown.
"""
from __future__ import annotations

import json
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table
from rich.text import Text

from bcfpipe.formats.vocabulary import Decision
from bcfpipe.cli.errors import Command
from bcfpipe.cli.options import all_materials_option, texel_density_option, variant_option
from bcfpipe.scan.results import MaterialScan, StageScan
from bcfpipe.scan.stage import scan_stage
from bcfpipe.scan.texture_sets import INSTANCED_MESSAGE, Grouping, group_materials

__all__ = ["scan"]


def _texture_lines(material: MaterialScan, grouping: Grouping) -> Text:
    """One line per textured input: ``input ← file:channel`` (problems in red), then the
    channels folded away (constant or duplicate)."""
    text = Text()
    for i, inp in enumerate(material.texture_inputs):
        tex = inp.texture
        assert tex is not None
        name = Path(tex.asset_path).name if tex.asset_path else "(no file)"
        if i:
            text.append("\n")
        text.append(f"{inp.name} ← {name}:{tex.channel}", style=None if tex.ok else "red")
    mm = grouping.model_of(material.path)
    for f in mm.folded if mm else ():
        what = f"= {Path(f.same_as.file).name}:{f.same_as.channel}" if f.same_as else f"= {f.value:.4g}"
        text.append(f"\nfolded {Path(f.file).name}:{f.channel} {f.reason} {what}", style="cyan")
    return text


def decision(material: MaterialScan, grouping: Grouping) -> str:
    """model, constant (every textured input folded to a value) or skip."""
    return Decision.CONSTANT if material.path in grouping.constant else material.decision


def _decision_text(material: MaterialScan, grouping: Grouping) -> Text:
    """``model`` in green, ``constant`` in cyan, or ``skip: reason`` with the message below."""
    if decision(material, grouping) == Decision.CONSTANT:
        return Text("constant", style="cyan").append("\nnothing to train: values authored", style="dim")
    if material.decision == Decision.MODEL:
        return Text("model", style="green")
    text = Text(f"skip: {material.reason}", style="yellow")
    text.append(f"\n{material.message}", style="dim")
    return text


def _need_text(req: dict | None) -> Text:
    """Texel density, the profile and size a build would choose."""
    if not req:
        return Text("")
    text = Text()
    d = req.get("density") or {}
    if d.get("texel_density"):
        text.append(f"{d['texel_density']:.0f} px/m", style="dim")
        if d.get("lowest_mesh_density") and d["meshes"] > 1:
            text.append(f" (lowest mesh {d['lowest_mesh_density']:.0f})")
    for note in d.get("notes", [])[:2]:
        text.append(f"\n{note}" if text.plain else note, style="yellow")
    if req["decision"] == Decision.MODEL:
        cap = f" capped: {req['texel_density_reached']:.0f} px/m" if req["capped"] else ""
        if req.get("covered_fraction") is not None:
            text.append(f"\n{100 * req['covered_fraction']:.0f}% of texels read" if text.plain else
                        f"{100 * req['covered_fraction']:.0f}% of texels read", style="dim")
        line = (f"{req['resolution']}²{cap}, {req['profile']}, ~{req['estimated_bytes'] / 2**20:.2f} MiB"
                if req["estimated_bytes"] else f"{req['resolution']}²{cap}, {req['profile']}, shared")
        text.append(f"\n{line}" if text.plain else line, style="dim")
    return text


def _table(result: StageScan, grouping: Grouping, reqs: dict) -> Table:
    """The per-material table."""
    table = Table(show_lines=False, expand=False)
    table.add_column("material", overflow="fold")
    table.add_column("bound")
    table.add_column("decision", overflow="fold")
    table.add_column("textured inputs", overflow="fold")
    for m in result.materials:
        bound = "yes" if m.bound else "no"
        path = m.path + (f" (+{len(m.aliases)} instances)" if m.aliases else "")
        need = _need_text(reqs["materials"].get(m.path))
        decision = _decision_text(m, grouping)
        if need.plain:
            decision.append("\n").append_text(need)
        table.add_row(path, bound, decision, _texture_lines(m, grouping))
    return table


def _print_human(result: StageScan, grouping: Grouping, reqs: dict, console: Console) -> None:
    """Stage facts, the table and a summary line."""
    console.print(f"[bold]{result.path}[/bold]", highlight=False)
    console.print(
        f"upAxis={result.up_axis}  metersPerUnit={result.meters_per_unit:g}  "
        f"defaultPrim={result.default_prim or '-'}  rendered gprims={result.rendered_gprims}",
        highlight=False,
    )
    for prim, vset, value in result.variant_selections:
        console.print(f"variant {vset}={value} on {prim}", highlight=False)
    for target in result.dangling_bindings:
        console.print(f"[yellow]warning:[/yellow] binding to missing material {target}", highlight=False)
    for error in result.composition_errors:
        console.print(f"[yellow]composition error:[/yellow] {error}", highlight=False)
    for note in result.diagnostics:
        console.print(f"[yellow]usd:[/yellow] {note}", highlight=False)
    if result.materials:
        console.print(_table(result, grouping, reqs))
    for path in sorted(grouping.instanced):
        console.print(f"[yellow]skip:[/yellow] {path}: {INSTANCED_MESSAGE}", highlight=False)
    for path, message in grouping.failed.items():
        console.print(f"[red]unreadable:[/red] {path}: {message}", highlight=False)
    n_model = sum(len(g.materials) for g in grouping.groups)
    n_const = len(grouping.constant)
    console.print(
        f"{len(result.materials)} material(s): {n_model} to model "
        f"({len(grouping.groups)} distinct texture set(s), one training each), "
        f"{n_const} constant (values authored, nothing trained), "
        f"{len(result.materials) - n_model - n_const} not modelled",
        highlight=False,
    )
    tot = reqs["totals"]
    console.print(
        f"a build writes ~{tot['estimated_bytes'] / 2**20:.2f} MiB ({tot['texture_sets']} texture set(s)); "
        f"modelling everything (no folding, no density cap): ~{tot['everything_estimated_bytes'] / 2**20:.2f} MiB "
        f"({tot['everything_texture_sets']} texture set(s))", highlight=False)


@click.command("scan", cls=Command)
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@variant_option
@all_materials_option
@texel_density_option
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout instead of a table.")
def scan(scene: Path, variants: dict[str, str], all_materials: bool, texel_density: float | None,
         as_json: bool) -> None:
    """Scan SCENE's UsdPreviewSurface materials: which ones `build` would model, and why not.

    Also what the scene requires: channels folded (constant or duplicate), the source's texel
    density on the bound meshes, the resolution, profile and size a build would choose, and the
    total against modelling everything. JSON keys: docs/build.md.
    """
    from bcfpipe.scan.requirements import requirements

    result = scan_stage(scene, variants or None, all_materials=all_materials)
    cache: dict = {}
    grouping = group_materials(scene, variants, result.materials, cache, digest=False)
    everything = group_materials(scene, variants, result.materials, cache, digest=False, fold=False)
    reqs = requirements(grouping, everything, texel_density=texel_density)
    if as_json:
        d = result.to_dict()
        for m, md in zip(result.materials, d["materials"]):
            md["decision"] = decision(m, grouping)
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
        click.echo(json.dumps(d, indent=2))
        return
    _print_human(result, grouping, reqs, Console())
