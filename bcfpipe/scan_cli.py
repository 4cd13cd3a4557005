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

from .errors import BcfError
from .scan import MaterialScan, ScanError, StageScan, parse_variant, scan_stage

__all__ = ["scan", "ScanInputError"]


class ScanInputError(BcfError):
    """Unreadable stage or bad --variant: one line on stderr, exit code 2."""


def _variants(_ctx: click.Context, _param: click.Parameter, values: tuple[str, ...]) -> dict[str, str]:
    """Parse repeated ``--variant SET=VALUE`` into a dict (later wins)."""
    try:
        return dict(parse_variant(v) for v in values)
    except ScanError as exc:
        raise ScanInputError(str(exc)) from None


def _texture_lines(material: MaterialScan) -> Text:
    """One line per textured input: ``input ← file:channel`` (problems in red)."""
    text = Text()
    for i, inp in enumerate(material.texture_inputs):
        tex = inp.texture
        assert tex is not None
        name = Path(tex.asset_path).name if tex.asset_path else "(no file)"
        if i:
            text.append("\n")
        text.append(f"{inp.name} ← {name}:{tex.channel}", style=None if tex.ok else "red")
    return text


def _decision_text(material: MaterialScan) -> Text:
    """``model`` in green, or ``skip: reason`` with the message below."""
    if material.decision == "model":
        return Text("model", style="green")
    text = Text(f"skip: {material.reason}", style="yellow")
    text.append(f"\n{material.message}", style="dim")
    return text


def _table(result: StageScan) -> Table:
    """The per-material table."""
    table = Table(show_lines=False, expand=False)
    table.add_column("material", overflow="fold")
    table.add_column("bound")
    table.add_column("decision", overflow="fold")
    table.add_column("textured inputs", overflow="fold")
    for m in result.materials:
        bound = "yes" if m.bound else "no"
        path = m.path + (f" (+{len(m.aliases)} instances)" if m.aliases else "")
        table.add_row(path, bound, _decision_text(m), _texture_lines(m))
    return table


def _print_human(result: StageScan, console: Console) -> None:
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
        console.print(_table(result))
    n_model = len(result.to_model)
    keys = {m.texture_set_key for m in result.to_model}
    console.print(
        f"{len(result.materials)} material(s): {n_model} to model "
        f"({len(keys)} distinct texture set(s)), {len(result.skipped)} skipped",
        highlight=False,
    )


@click.command("scan")
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--variant",
    "variants",
    multiple=True,
    callback=_variants,
    metavar="SET=VALUE",
    help="Select VALUE in variant set SET on every prim offering it (repeatable).",
)
@click.option("--all-materials", is_flag=True, help="Also model materials not bound to rendered geometry.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout instead of a table.")
def scan(scene: Path, variants: dict[str, str], all_materials: bool, as_json: bool) -> None:
    """Scan SCENE's UsdPreviewSurface materials: which ones `build` would model, and why not."""
    try:
        result = scan_stage(scene, variants or None, all_materials=all_materials)
    except ScanError as exc:
        raise ScanInputError(str(exc)) from None
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
        return
    _print_human(result, Console())
