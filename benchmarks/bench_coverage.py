"""Coverage (issue #18, item 4): a real 2K texture set on a mesh whose uvs cover a quarter of the
texture, built with the coverage mask (the default) and with --no-coverage, at the same profile
and preset. Both are measured over the covered texels, per mip, from the exported files.

    .venv/bin/python benchmarks/bench_coverage.py [--set brick|teapot] [--preset draft] [--profile auto]

The scene (a 1 m quad, st over [0, 0.5]², the set's textures on a UsdPreviewSurface) is written
into a temporary folder; ../shared/scenes provides the textures. Prints the machine, both runs and
a Markdown table.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, add_options, machine, mip_columns, run_bcfpipe  # noqa: E402

SETS = {
    "brick": {"diffuseColor": ("materialx_texture_sets/brick/brick_base_gray.jpg", "rgb"),
              "normal": ("materialx_texture_sets/brick/brick_normal.jpg", "rgb"),
              "roughness": ("materialx_texture_sets/brick/brick_roughness.jpg", "r")},
    "teapot": {"diffuseColor": ("usdwg_teapot/textures/tea_set_01_diff_2k.jpg", "rgb"),
               "occlusion": ("usdwg_teapot/textures/tea_set_01_arm_2k.jpg", "r"),
               "roughness": ("usdwg_teapot/textures/tea_set_01_arm_2k.jpg", "g"),
               "metallic": ("usdwg_teapot/textures/tea_set_01_arm_2k.jpg", "b")},
}


def write_scene(root: Path, textures: dict) -> Path:
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    T = Sdf.ValueTypeNames
    stage = Usd.Stage.CreateNew(str(root / "quarter.usda"))
    stage.SetDefaultPrim(stage.DefinePrim("/World", "Xform"))
    mat = UsdShade.Material.Define(stage, "/World/Looks/M")
    surf = UsdShade.Shader.Define(stage, "/World/Looks/M/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/M/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", T.String).Set("st")
    st = reader.CreateOutput("result", T.Float2)
    for name, (file, out) in textures.items():
        tex = UsdShade.Shader.Define(stage, f"/World/Looks/M/Tex_{name}")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", T.Asset).Set(str(SHARED / file))
        tex.CreateInput("st", T.Float2).ConnectToSource(st)
        if name == "normal":
            tex.CreateInput("sourceColorSpace", T.Token).Set("raw")
            tex.CreateInput("scale", T.Float4).Set((2, 2, 2, 1))
            tex.CreateInput("bias", T.Float4).Set((-1, -1, -1, 0))
        o = tex.CreateOutput(out, T.Float3 if out == "rgb" else T.Float)
        kind = {"diffuseColor": T.Color3f, "normal": T.Normal3f}.get(name, T.Float)
        surf.CreateInput(name, kind).ConnectToSource(o)
    mesh = UsdGeom.Mesh.Define(stage, "/World/Quad")
    mesh.GetPointsAttr().Set([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.GetFaceVertexCountsAttr().Set([4])
    mesh.GetFaceVertexIndicesAttr().Set([0, 1, 2, 3])
    UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", T.TexCoord2fArray, UsdGeom.Tokens.vertex).Set(
        [(0, 0), (0.5, 0), (0.5, 0.5), (0, 0.5)])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(mat)
    stage.Save()
    return root / "quarter.usda"


def covered_psnr(scene: Path, out: Path, masks_from) -> tuple[float, list[float], float]:
    """PSNR over covered texels (all mips, per mip) of a build's exported files, and over all texels."""
    from bcfpipe.export import writer as E
    from bcfpipe.formats import manifest as mfst
    from bcfpipe.scan.coverage import mask_mips, unpack
    from bcfpipe.scan.sources import local_file
    from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set
    from bcfpipe.texset.metrics import compute_metrics

    job = masks_from
    with tempfile.TemporaryDirectory() as tmp:
        ts = load_texture_set([TextureSpec(sem, local_file(p, tmp), ch) for sem, p, ch in job.specs])
    ref = build_mip_chain(ts.data)
    masks = mask_mips(unpack(job.coverage, ts.width, ts.height), len(ref), job.wrap)
    (m,) = mfst.read(out).built()
    dec = E.decode_mips(E.load(out / m.outputs.folder), [r.shape[:2] for r in ref])
    q = compute_metrics(ref, dec, ts.channels, masks=masks, ssim=False, flip=False)
    return q.psnr_covered, list(q.psnr_per_mip_covered), q.psnr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--set", choices=list(SETS), default="brick")
    add_options(ap, preset="draft", profile="auto")
    a = ap.parse_args()
    from bcfpipe.builder import plan
    from bcfpipe.config import TrainingOptions

    print(f"machine: {machine()}")
    with tempfile.TemporaryDirectory(prefix="bcfcov-") as tmp:
        root = Path(tmp)
        scene = write_scene(root, SETS[a.set])
        job = plan(scene, TrainingOptions(profile=a.profile, preset=a.preset)).jobs[0]
        print(f"{a.set}: covered fraction {job.covered_fraction:.3f}")
        rows = []
        for flag in ([], ["--no-coverage"]):
            out = root / ("out" + "".join(flag))
            wall, p = run_bcfpipe("-q", "build", scene, "-o", out, "--no-cache", "--quality", a.preset,
                                  "--profile", a.profile, "--json", *flag)
            if p.returncode != 0:
                raise SystemExit(p.stderr[-2000:])
            rep = json.loads(p.stdout)
            cov, per_mip, whole = covered_psnr(scene, out, job)
            rows.append(("mask" if not flag else "no mask", cov, per_mip, whole, wall,
                         rep["totals"]["train_seconds"]))
            print(f"{rows[-1][0]}: covered {cov:.2f} dB (per mip {', '.join(f'{v:.2f}' for v in per_mip)}), "
                  f"all texels {whole:.2f} dB, wall {wall:.0f} s, train {rows[-1][5]:.0f} s")
        n = len(rows[0][2])
        print("| training | PSNR covered, all mips | " + mip_columns(n) + " | PSNR all texels |")
        print("|---|---:|" + "---:|" * n + "---:|")
        for name, cov, per_mip, whole, _, _ in rows:
            print(f"| {name} | {cov:.2f} | " + " | ".join(f"{v:.2f}" for v in per_mip) + f" | {whole:.2f} |")
        d = [x - y for x, y in zip(rows[0][2], rows[1][2])]
        print(f"| gain | {rows[0][1] - rows[1][1]:+.2f} | " + " | ".join(f"{v:+.2f}" for v in d) + " | |")


if __name__ == "__main__":
    main()
