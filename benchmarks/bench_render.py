"""Frame time of the reference renderer: neural materials against their original textures.

    .venv/bin/python benchmarks/bench_render.py BUILT.usda [--size 1920x1080] [--zoom 4]
                                                [--camera PATH] [--repeat 7] [--json]

Both renderers hold the same scene in one OpenGL context: the neural one decodes the bcf render
context's materials (glsl/bcf_decode.glsl, one sample per pixel, derivative lod), the original
one samples their UsdPreviewSurface textures (RGBA8 / RGBA16F, trilinear, GL mipmaps). After one
warm-up frame each, frames alternate (neural, original, original, neural, ...), each timed from
the first draw call to glFinish on the CPU, and with a GL timer query (GL_TIME_ELAPSED) when the
driver has one. Prints the medians, the ratio neural / original, and the frame's difference.
The default view is the close-up of the benchmark in docs/benchmarks.md (zoom 4 on the
framing camera: every pixel of the frame is material).
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene")
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--zoom", type=float, default=4.0)
    ap.add_argument("--camera", default=None)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()

    from bcfpipe.cli.decode import parse_size
    from bcfpipe.render import compare as C
    from bcfpipe.render.frames import NEURAL, ORIGINAL, load_scene, renderer_for
    from bcfpipe.verify.glsl import open_runtime

    w, h = parse_size(a.size)
    scene = load_scene(a.scene, w, h, camera=a.camera, zoom=a.zoom, kinds=(NEURAL, ORIGINAL))
    rt = open_runtime()
    renderers = {k: renderer_for(rt, scene, k, w, h) for k in (NEURAL, ORIGINAL)}
    images = {k: r.render(scene.view) for k, r in renderers.items()}  # warm-up, and the frames compared
    diff, _ = C.difference(images[NEURAL], images[ORIGINAL])
    coverage = float((images[NEURAL][..., 3] > 0).mean())
    wall = {k: [] for k in renderers}
    gpu = {k: [] for k in renderers}
    for i in range(a.repeat):
        order = (NEURAL, ORIGINAL) if i % 2 == 0 else (ORIGINAL, NEURAL)
        for k in order:
            t_wall, t_gpu = renderers[k].frame_time(scene.view)
            wall[k].append(t_wall)
            if t_gpu is not None:
                gpu[k].append(t_gpu)
            if not a.json:
                print(f"  rep {i + 1}/{a.repeat} {k:8s} wall {t_wall * 1e3:9.1f} ms"
                      + (f"  gpu {t_gpu * 1e3:9.1f} ms" if t_gpu is not None else ""), flush=True)
    info, software = rt.info, rt.is_software
    for r in renderers.values():
        r.release()
    rt.release()

    def med(xs):
        return statistics.median(xs) if xs else None

    res = {
        "scene": a.scene, "size": [w, h], "camera": scene.view.source, "zoom": a.zoom, "repeat": a.repeat,
        "coverage": round(coverage, 4), "neural_materials": scene.neural_materials(),
        "gl_renderer": info["renderer"], "gl_version": info["version"], "software": software, "machine": machine(),
        "wall_ms": {k: round(med(v) * 1e3, 2) for k, v in wall.items()},
        "wall_ms_min": {k: round(min(v) * 1e3, 2) for k, v in wall.items()},
        "gpu_ms": {k: (round(med(v) * 1e3, 2) if v else None) for k, v in gpu.items()},
        "ratio_wall": round(med(wall[NEURAL]) / med(wall[ORIGINAL]), 3),
        "ratio_gpu": round(med(gpu[NEURAL]) / med(gpu[ORIGINAL]), 3) if gpu[NEURAL] and gpu[ORIGINAL] else None,
        "difference": diff.to_dict(),
    }
    if a.json:
        print(json.dumps(res, indent=2))
        return
    print(f"machine: {res['machine']}; GL: {res['gl_renderer']} ({res['gl_version']})")
    print(f"{a.scene}: {w}x{h}, camera {res['camera']} (zoom {a.zoom}), {coverage:.0%} of the pixels covered")
    print("| frame | median wall ms | min wall ms | median GL timer ms |")
    print("|---|---|---|---|")
    for k in (NEURAL, ORIGINAL):
        g = res["gpu_ms"][k]
        print(f"| {k} | {res['wall_ms'][k]:.1f} | {res['wall_ms_min'][k]:.1f} | {'-' if g is None else f'{g:.1f}'} |")
    print(f"ratio neural / original: wall {res['ratio_wall']:.2f}x"
          + (f", GL timer {res['ratio_gpu']:.2f}x" if res["ratio_gpu"] else ""))
    if res["software"]:
        print("(a software renderer: its GL timer measures command submission, not the rasterisation that "
              "runs at glFinish; the wall time is the frame time)")
    d = res["difference"]
    print(f"neural vs original in this frame: PSNR {d['psnr_db']} dB, mean |diff| {d['mean_abs_8bit']} levels")


if __name__ == "__main__":
    main()
