"""`bcfpipe verify`: run the GLSL decoder through OpenGL and check it against decoder.onnx.

Exit codes: 0 every check passed; 1 a check failed; 2 bad input (no material.json/manifest.json,
unreadable or malformed files) or no OpenGL 4.5 context through EGL.
"""
from __future__ import annotations

import json

import click

from bcfpipe.cli.errors import Command
from bcfpipe.errors import EXIT_FAILED, EXIT_OK, EXIT_USAGE

__all__ = ["verify", "run_verify", "print_report"]


def print_report(report, console=None) -> None:
    """The human-readable form: per material its checks, then the error table (per channel and per
    group of sample points)."""
    from rich.console import Console
    from rich.table import Table

    con = console or Console()
    if report.renderer:
        con.print(f"OpenGL: {report.renderer['renderer']} | {report.renderer['version']}")
    tol = report.tolerance
    tol_text = (f"derived per point (filtering precision 2^-{tol['filter_bits']}, fp16 weights)"
                if tol["mode"] == "derived" else f"fixed {tol['value']:g}")
    con.print(f"Tolerance: {tol_text}")
    if report.gl_error:
        con.print(f"[red]no OpenGL:[/red] {report.gl_error}")
    for m in report.materials:
        status = "[green]PASS[/green]" if m.passed else "[red]FAIL[/red]"
        con.print(f"\n{status} {m.name}  ({m.folder})")
        if m.input_error:
            con.print(f"  [red]bad input:[/red] {m.input_error}")
        for c in m.checks:
            mark = {True: "[green]ok[/green]  ", False: "[red]FAIL[/red]", None: "[dim]--[/dim]  "}[c.passed]
            con.print(f"  {mark} {c.name:<12} {c.detail}")
        if m.channels:
            t = Table(title=f"|GLSL - ONNX| over {m.n_points} (u, v, s) points", title_justify="left")
            for col in ("channel", "max abs", "mean abs", "max tol", "mean tol", "over"):
                t.add_column(col, justify="right" if col != "channel" else "left")
            for ch in m.channels:
                t.add_row(ch["name"], f"{ch['max_abs']:.3g}", f"{ch['mean_abs']:.3g}", f"{ch['max_tolerance']:.3g}",
                          f"{ch['mean_tolerance']:.3g}",
                          str(ch["over_tolerance"]) if ch["passed"] else f"[red]{ch['over_tolerance']}[/red]")
            con.print(t)
            t = Table(title="by sample group (all channels)", title_justify="left")
            for col in ("group", "points", "max abs", "mean abs", "over"):
                t.add_column(col, justify="right" if col != "group" else "left")
            for c in m.categories:
                t.add_row(c["category"], str(c["n"]), f"{c['max_abs']:.3g}", f"{c['mean_abs']:.3g}",
                          str(c["over_tolerance"]))
            con.print(t)
    n_ok = sum(m.passed for m in report.materials)
    con.print(f"\n{n_ok}/{len(report.materials)} material(s) passed")


def run_verify(path: str, tolerance: float | None = None, as_json: bool = False, glsl: bool = True,
               filter_bits: int | None = None, seed: int = 0, echo=click.echo, to_stderr: bool = False) -> int:
    """Verify ``path`` and print the report; returns the exit code (what `bcfpipe build --verify` calls)."""
    from bcfpipe.verify import checks as V

    try:
        report = V.verify(path, tolerance=tolerance, glsl=glsl, seed=seed,
                          filter_bits=V.FILTER_BITS if filter_bits is None else filter_bits)
    except V.VerifyInputError as e:
        if as_json:
            echo(json.dumps({"path": str(path), "passed": False, "exit_code": EXIT_USAGE, "input_error": str(e)}))
        else:
            click.echo(f"Error: {e}", err=True)
        return EXIT_USAGE
    if as_json:
        echo(json.dumps(report.to_dict(), indent=2))
    else:
        from rich.console import Console

        print_report(report, Console(stderr=True) if to_stderr else None)
    return report.exit_code


@click.command("verify", cls=Command)
@click.argument("out", type=click.Path(exists=True, file_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON report instead of tables.")
@click.option("--tolerance", type=float, default=None, metavar="X",
              help="Fixed absolute tolerance per output value instead of the derived per-point bound.")
@click.option("--filter-bits", type=click.IntRange(1, 24), default=8, show_default=True,
              help="Fractional precision assumed for the texture unit's bilinear and mip weights.")
@click.option("--no-glsl", is_flag=True, help="Skip the OpenGL comparison (file, weight and OpenImageIO checks only).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the random part of the (u, v, s) grid.")
@click.pass_context
def verify(ctx: click.Context, out: str, as_json: bool, tolerance: float | None, filter_bits: int, no_glsl: bool,
           seed: int) -> None:
    """Check the exported material(s) in OUT through the real GLSL decoder.

    OUT is a material folder (material.json) or a build folder (manifest.json, or subfolders with
    material.json). Per material: the files agree with material.json, recorded SHA-256s match,
    weights.bin equals decoder.onnx, OpenImageIO decodes every DDS identically, and
    glsl/bcf_decode.comp run through OpenGL (EGL: GPU driver or Mesa llvmpipe) matches decoder.onnx
    fed features sampled in numpy from the DDS, over a (u, v, s) grid with texel centres and edges,
    wrapping, magnification, fractional lods and lods past the last mip.

    \b
    Exit codes: 0 passed, 1 a check failed, 2 bad input or no OpenGL.
    """
    code = run_verify(out, tolerance=tolerance, as_json=as_json, glsl=not no_glsl, filter_bits=filter_bits, seed=seed)
    ctx.exit(code if code in (EXIT_OK, EXIT_FAILED, EXIT_USAGE) else EXIT_FAILED)
