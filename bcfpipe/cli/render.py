"""`bcfpipe render`: draw a (built) USD stage with the reference renderer (docs/render.md)."""
from __future__ import annotations

import json
import os

import click

from bcfpipe.cli.decode import parse_size
from bcfpipe.cli.errors import Command
from bcfpipe.errors import InputError
from bcfpipe.render import compare as C
from bcfpipe.render.frames import NEURAL, ORIGINAL, load_scene, render_frames
from bcfpipe.verify.sources import check_sources

HEAT_LEGEND = "heat map of |difference| in 8-bit sRGB levels: black 0, blue 4, red 12, yellow 32, white 64+"


def _stage_file(path: str) -> str:
    """A build folder stands for its root layer (the one *.bcf.usda in it)."""
    if not os.path.isdir(path):
        return path
    roots = sorted(f for f in os.listdir(path) if f.endswith(".bcf.usda"))
    if len(roots) != 1:
        raise InputError(f"{path}: a folder with {len(roots)} *.bcf.usda files, not one build; pass the stage file")
    return os.path.join(path, roots[0])


@click.command("render", cls=Command)
@click.argument("scene", type=click.Path())
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False), metavar="PNG",
              help="The image to write (8-bit sRGB PNG).")
@click.option("--camera", default=None, metavar="PATH", help="A UsdGeom.Camera prim; default: a camera that frames "
              "every visible mesh from the front-right, above.")
@click.option("--size", default="960x540", show_default=True, metavar="WxH", help="Frame size in pixels.")
@click.option("--zoom", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Without --camera: narrow the default camera's field of view by this factor "
                   "(4 = a 4x close-up of the scene's centre, 0.25 = far away).")
@click.option("--compare", is_flag=True, help="Also draw the source scene a build was made from (its original "
              "textures) and write [original | built | difference heat map] side by side, with the numbers; "
              "any layout (neural, classic, mixed, untouched).")
@click.option("--original", is_flag=True, help="Draw the source scene a build was made from only (the input "
              "stage with the build's variant selections).")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON report (stable keys) instead of text.")
@click.option("--force", is_flag=True, help="Overwrite an existing output image.")
def render(scene: str, output: str, camera: str | None, size: str, zoom: float, compare: bool, original: bool,
           as_json: bool, force: bool) -> None:
    """Render SCENE (OUT/<scene>.bcf.usda, or a build folder OUT) headless with OpenGL, one
    sample per pixel.

    A reference and a test tool: it reads only the USD stage and the files it names. Materials
    with a bcf render context are decoded by glsl/bcf_decode.glsl at the lod from the uv
    derivatives; the others use their UsdPreviewSurface textures (a layout's classic DDS textures
    included); --compare and --original draw the source scene the build was made from. Shading:
    Lambert + GGX under one directional light and an ambient term (docs/render.md).

    \b
    Exit codes: 0 written; 2 bad input, no OpenGL, or the output exists (use --force).
    """
    width, height = parse_size(size)
    scene = _stage_file(scene)
    if scene.endswith(".bcf.usda") and os.path.isfile(scene):
        check_sources(scene)  # a moved OUT: say so, not "no visible mesh"
    if compare and original:
        raise InputError("--compare and --original exclude each other")
    if camera and zoom != 1.0:
        raise InputError("--zoom narrows the framing camera; it does not apply with --camera")
    _check_output(output, force)
    kinds = (ORIGINAL,) if original else ((NEURAL, ORIGINAL) if compare else (NEURAL,))
    sc = load_scene(scene, width, height, camera=camera, zoom=zoom, kinds=kinds)
    neural = sc.neural_materials() if NEURAL in kinds else []
    frames = render_frames(sc, width, height)
    others = sorted(m for m in sc.surfaces[kinds[0]] if m and m not in neural)
    classic = [m for m in others if kinds[0] == NEURAL and _reads_shipped(sc.surfaces[NEURAL][m], scene)]
    report = {"output": output, "width": width, "height": height, "camera": sc.view.source,
              "triangles": sc.triangles, "neural_materials": neural, "classic_materials": classic,
              "original_materials": [m for m in others if m not in classic],
              "notes": sc.notes(kinds[0])}
    if compare:
        diff, per_pixel = C.difference(frames[NEURAL].image, frames[ORIGINAL].image)
        C.write_png(output, C.side_by_side(C.to_srgb8(frames[ORIGINAL].image), C.to_srgb8(frames[NEURAL].image),
                                           C.heat_map(per_pixel)))
        report["difference"] = diff.to_dict()
    else:
        C.write_png(output, C.to_srgb8(frames[kinds[0]].image))
    if as_json:
        click.echo(json.dumps(report, indent=2))
    else:
        _echo_report(report)


def _reads_shipped(surface, scene: str) -> bool:
    """Whether a (non-neural) surface of the built stage reads a texture the build shipped beside
    ``scene``: a classic layout's DDS files, not the source scene's own."""
    out = os.path.dirname(os.path.abspath(scene))
    return any(os.path.abspath(t.path).startswith(out + os.sep) and t.path.lower().endswith(".dds")
               for t in surface.textures)


def _check_output(output: str, force: bool) -> None:
    """Refuse an output that is not a *.png, exists (without --force) or has no folder."""
    if not output.lower().endswith(".png"):
        raise InputError(f"{output}: the output is a PNG; name it *.png")
    if os.path.exists(output) and not force:
        raise InputError(f"{output} exists; pass --force to overwrite it")
    if not os.path.isdir(os.path.dirname(os.path.abspath(output))):
        raise InputError(f"{output}: its folder does not exist")


def _echo_report(report: dict) -> None:
    """The text report: the notes on stderr, the frame, and with --compare the difference."""
    for n in report["notes"]:
        click.echo(f"note: {n}", err=True)
    click.echo(f"{report['output']}: {report['width']}x{report['height']}, camera {report['camera']}, "
               f"{report['triangles']:,} triangles; {len(report['neural_materials'])} neural, "
               + (f"{len(report['classic_materials'])} classic (shipped BC textures), "
                  if report["classic_materials"] else "")
               + f"{len(report['original_materials'])} original material(s)")
    if "difference" in report:
        d = report["difference"]
        psnr = "identical" if d["psnr_db"] is None else f"PSNR {d['psnr_db']:.2f} dB"
        click.echo(f"  [original | built | difference]; built vs original over {d['pixels']:,} pixels: {psnr}, "
                   f"mean |diff| {d['mean_abs_8bit']:.2f}, p99 {d['p99_abs_8bit']:.1f}, max {d['max_abs_8bit']:.0f}")
        click.echo(f"  {HEAT_LEGEND}")
