"""`bcfpipe plan`: the jobs a build would run, without running them.

Exit codes: 0 the plan was made, 2 the stage cannot be read or an option is bad.
"""
from __future__ import annotations

import json
from pathlib import Path

import click
from rich.console import Console
from rich.table import Table

from bcfpipe.formats.vocabulary import Decision
from bcfpipe.cli.errors import Command
from bcfpipe.cli.options import all_materials_option, texel_density_option, training_options, variant_option

__all__ = ["plan_cmd"]


def plan_json(bplan) -> dict:
    """The plan as JSON: every job with its content hash, materials, sources (with hashes) and
    options; the packed coverage mask is replaced by its covered fraction (already given)."""
    d = bplan.to_dict()
    for j in d["jobs"]:
        j.pop("coverage", None)
    return d


@click.command("plan", cls=Command)
@click.argument("scene", type=click.Path(path_type=Path, dir_okay=False))
@variant_option
@all_materials_option
@training_options
@texel_density_option
@click.option("--no-coverage", is_flag=True, help="As for build: train on every texel.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan as one JSON object on stdout.")
def plan_cmd(scene: Path, variants: dict[str, str], all_materials: bool, texel_density: float | None,
             no_coverage: bool, as_json: bool, **_training) -> None:
    """List the training jobs `bcfpipe build SCENE` would run with these options: each job's
    content hash (its cache key), materials, channels, resolution, profile and covered fraction.
    Reads and hashes the textures; trains and writes nothing."""
    from bcfpipe.builder import plan
    from bcfpipe.cli.options import training_record

    training, bench = training_record(click.get_current_context())
    bplan = plan(scene, training, variants=variants, all_materials=all_materials, texel_density=texel_density,
                 coverage=not no_coverage, bench=bench)
    if as_json:
        click.echo(json.dumps(plan_json(bplan), indent=2))
        return
    t = Table(title=f"bcfpipe plan: {bplan.scene}", title_justify="left")
    for col in ("job", "materials", "outputs", "resolution", "profile", "read", "content hash"):
        t.add_column(col, overflow="fold")
    for j in bplan.jobs:
        w, h = j.size
        prof = j.options.profile if j.options.target_psnr is None else (
            f"target {j.options.target_psnr:g} dB ({'bench' if j.anchors else 'probe'})")
        t.add_row(j.name, str(len(j.materials)), str(len(j.channels)), f"{w}x{h}", prof,
                  f"{100 * j.covered_fraction:.0f}%" if j.covered_fraction is not None else "all",
                  j.content_hash[:16])
    con = Console()
    con.print(t)
    counts = {d: sum(1 for m in bplan.materials if m.decision == d) for d in Decision}
    con.print(f"{len(bplan.jobs)} job(s) for {counts['model']} modelled material(s); {counts['constant']} "
              f"constant, {counts['skip']} skipped", highlight=False)
