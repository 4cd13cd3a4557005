"""The driver's side of a big build, measured on scenes of N materials: the inputs of docs/scale.md.

    .venv/bin/python benchmarks/bench_scale.py [--plan 100,1000,10000] [--train 64]
                                               [--assemble 8,16,32,64] [--size 16] [--json]

Each generated scene has N materials, each bound to its own quad and reading its own N-distinct
SIZE² PNG (so N texture sets: nothing is merged). Measured, each as a `bcfpipe` process from start
to exit:

- `plan`: `bcfpipe plan SCENE --json` with an empty cache, for each N in --plan: composing the stage, hashing
  and reading every texture, the coverage of every mesh; the work the driver does before any job.
- training: one cold `build` of the --train scene (`--profile tiny --quality draft --jobs 2
  --threads 1`): the per-job time on this machine, from the report.
- assembly: with every job in the cache, `build` of the first N materials into a fresh OUT, for
  each N in --assemble (USD layer, weights.bin, manifest, every file installed), then a no-op rebuild.
- shared: the same for N materials in --shared that share the --train texture sets (material k
  reads texture k mod --train): the per-material cost (plan, USD layer, manifest) at large N,
  where training 10,000 sets on this machine would take a day.

- store: the driver's write of one job's exported files into the staging folder and the cache
  (`ray_executor._store`: two copies, fsynced, SHA-256 of each file), at the sizes of a 0.5k and a
  1k job, median of 30.

Prints per-N lines, a least-squares fixed + per-material cost of each step, and Markdown tables.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import machine, run_bcfpipe  # noqa: E402


MATERIAL = """
        def Material "M{k:05d}"
        {{
            token outputs:surface.connect = </World/Looks/M{k:05d}/Surface.outputs:surface>
            def Shader "Surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor.connect = </World/Looks/M{k:05d}/Tex.outputs:rgb>
                token outputs:surface
            }}
            def Shader "St"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "st"
                float2 outputs:result
            }}
            def Shader "Tex"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @./tex/{tex}@
                float2 inputs:st.connect = </World/Looks/M{k:05d}/St.outputs:result>
                float3 outputs:rgb
            }}
        }}
"""
QUAD = """
        def Mesh "Q{k:05d}" (prepend apiSchemas = ["MaterialBindingAPI"])
        {{
            int[] faceVertexCounts = [4]
            int[] faceVertexIndices = [0, 1, 2, 3]
            point3f[] points = [({x0}, {y0}, 0), ({x1}, {y0}, 0), ({x1}, {y1}, 0), ({x0}, {y1}, 0)]
            texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "faceVarying")
            rel material:binding = </World/Looks/M{k:05d}>
        }}
"""


def make_scene(root: Path, n: int, size: int, sets: int | None = None) -> Path:
    """N materials, each on its own quad, each reading its own SIZE² texture (seeded by index), or
    with ``sets`` the texture (k mod sets): then N materials share that many texture sets. Written
    as USDA text: authoring 10,000 networks through the USD API would take longer than the plan."""
    import OpenImageIO as oiio

    (root / "tex").mkdir(parents=True, exist_ok=True)
    y, x = np.mgrid[0:size, 0:size] / size
    looks, geo = [], []
    for k in range(n):
        tex = root / "tex" / f"t{k % sets if sets else k:05d}.png"
        if not tex.exists():
            rng = np.random.default_rng(k)
            f = rng.uniform(1, 4, 3)
            img = 0.5 + 0.4 * np.sin((x[..., None] * f + y[..., None] * f[::-1]) * np.pi + rng.uniform(0, 6, 3))
            oiio.ImageBuf(np.round(img * 255).astype(np.uint8)).write(str(tex))
        looks.append(MATERIAL.format(k=k, tex=tex.name))
        x0, y0 = (k % 100) * 1.2, (k // 100) * 1.2
        geo.append(QUAD.format(k=k, x0=x0, y0=y0, x1=x0 + 1, y1=y0 + 1))
    text = ('#usda 1.0\n(\n    defaultPrim = "World"\n    upAxis = "Z"\n)\n\ndef Xform "World"\n{\n'
            '    def Scope "Looks"\n    {' + "".join(looks) + '    }\n    def Scope "Geo"\n    {' + "".join(geo)
            + "    }\n}\n")
    (root / "scene.usda").write_text(text)
    return root / "scene.usda"


# the exported files of one job (BC6H T0..T3 with mips), by profile
JOB_FILES = {"0.5k": {"T0.dds": 349668, "T1.dds": 87524, "T2.dds": 21988, "T3.dds": 5604},
             "1k": {"T0.dds": 1398228, "T1.dds": 349668, "T2.dds": 87524, "T3.dds": 21988}}


def store_cost(folder: Path, reps: int = 30) -> dict[str, dict]:
    """Median seconds of the Ray driver's store of one job's files (staging + cache), by profile."""
    from types import SimpleNamespace

    from bcfpipe.builder.executor import JobResult
    from bcfpipe.builder.ray_executor import _store

    out = {}
    for prof, sizes in JOB_FILES.items():
        files = {**{k: os.urandom(v) for k, v in sizes.items()}, "weights.bin": os.urandom(708),
                 "decoder.onnx": os.urandom(2313), "material.json": os.urandom(5393)}
        ts = []
        for i in range(reps):
            job = SimpleNamespace(name=f"{prof}-{i}", content_hash=f"{len(sizes)}{prof == '1k':d}{i:030x}")
            r = JobResult(job.name, "built", None, 1.0, "cpu", 1, {"psnr": 30.0})
            t0 = time.perf_counter()
            _store(job, r, files, folder / "staging", str(folder / "cache"))
            ts.append(time.perf_counter() - t0)
        out[prof] = {"mib": sum(map(len, files.values())) / 2**20, "store_s": statistics.median(ts)}
    return out


def run(*args: str) -> tuple[float, str]:
    wall, p = run_bcfpipe(*args, timeout=7200)
    if p.returncode:
        sys.exit(f"bcfpipe {' '.join(args[:2])} failed: {p.stderr[-2000:]}")
    return wall, p.stdout


def fit(ns: list[int], ts: list[float]) -> tuple[float, float]:
    """Least squares t = a + b·n: (fixed seconds, seconds per material)."""
    b, a = np.polyfit(np.asarray(ns, float), np.asarray(ts, float), 1)
    return float(a), float(b)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plan", default="100,1000,10000")
    ap.add_argument("--train", type=int, default=64)
    ap.add_argument("--assemble", default="8,16,32,64")
    ap.add_argument("--shared", default="1000,10000")
    ap.add_argument("--size", type=int, default=16, help="texture size of every material")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    say = (lambda *a: None) if args.json else (lambda *a: print(*a, flush=True))
    plan_ns = [int(x) for x in args.plan.split(",") if x]
    asm_ns = [int(x) for x in args.assemble.split(",") if x]
    shared_ns = [int(x) for x in args.shared.split(",") if x]
    if asm_ns and max(asm_ns) > args.train:
        sys.exit("--assemble sizes must not exceed --train (they are assembled from its cache)")
    res: dict = {"machine": machine(), "size": args.size, "plan": {}, "assemble": {}, "noop": {},
                 "shared_assemble": {}, "shared_noop": {}}
    say(f"machine: {res['machine']}; load average {os.getloadavg()}")
    with tempfile.TemporaryDirectory(prefix="bcf-scale-") as tmp:
        tmp = Path(tmp)
        for n in plan_ns:
            scene = make_scene(tmp / f"p{n}", n, args.size)
            os.environ["BCFPIPE_CACHE"] = str(tmp / f"p{n}" / "cache")  # cold: no texel facts kept yet
            wall, out = run("plan", str(scene), "--json", "--profile", "tiny", "--quality", "draft")
            jobs = len(json.loads(out)["jobs"])
            assert jobs == n, (jobs, n)
            res["plan"][n] = wall
            say(f"plan, {n} materials: {wall:.2f} s")
        if args.train:
            cache = tmp / "cache"
            scene = make_scene(tmp / "t", args.train, args.size)
            wall, out = run("build", str(scene), "-o", str(tmp / "t" / "cold"), "--cache", str(cache), "--json",
                            "--profile", "tiny", "--quality", "draft", "--jobs", "2", "--threads", "1")
            rep = json.loads(out)
            per_job = [m["train_seconds"] for m in rep["materials"] if m.get("train_seconds")]
            sizes = json.loads((tmp / "t" / "cold" / "manifest.json").read_text())
            res["train"] = {"n": args.train, "wall_s": wall, "job_s_median": statistics.median(per_job),
                            "job_s": per_job, "out_bytes": sizes["totals"]["total_bytes"]}
            say(f"cold build of {args.train}: {wall:.1f} s, a job {statistics.median(per_job):.2f} s (median)")
            for n in asm_ns:
                s = make_scene(tmp / f"a{n}", n, args.size)  # the same textures: every job is in the cache
                out_dir = tmp / f"a{n}" / "out"
                wall, out = run("build", str(s), "-o", str(out_dir), "--cache", str(cache), "--json",
                                "--profile", "tiny", "--quality", "draft")
                assert json.loads(out)["totals"]["trained"] == 0
                res["assemble"][n] = wall
                wall2, _ = run("build", str(s), "-o", str(out_dir), "--cache", str(cache), "--json",
                               "--profile", "tiny", "--quality", "draft")
                res["noop"][n] = wall2
                say(f"from the cache, {n} materials: fresh OUT {wall:.2f} s, no-op {wall2:.2f} s")
            for n in shared_ns:
                s = make_scene(tmp / f"s{n}", n, args.size, sets=args.train)
                out_dir = tmp / f"s{n}" / "out"
                wall, out = run("build", str(s), "-o", str(out_dir), "--cache", str(cache), "--json", "--profile", "tiny",
                                "--quality", "draft")
                rep = json.loads(out)
                assert rep["totals"]["trained"] == 0, rep["totals"]
                res["shared_assemble"][n] = wall
                wall2, _ = run("build", str(s), "-o", str(out_dir), "--cache", str(cache), "--json", "--profile",
                               "tiny", "--quality", "draft")
                res["shared_noop"][n] = wall2
                sizes = {p.name: p.stat().st_size for p in out_dir.iterdir() if p.is_file()}
                res.setdefault("shared_sizes", {})[n] = sizes
                say(f"{n} materials sharing {args.train} sets, from the cache: fresh OUT {wall:.2f} s, "
                    f"no-op {wall2:.2f} s; {sizes}")
        res["store"] = store_cost(tmp / "store")
        for prof, v in res["store"].items():
            say(f"store of a {prof} job ({v['mib']:.2f} MiB) into staging + cache: {1e3 * v['store_s']:.1f} ms")
    res["loadavg_after"] = os.getloadavg()
    for key in ("plan", "assemble", "noop", "shared_assemble", "shared_noop"):
        if len(res[key]) >= 2:
            a, b = fit(list(res[key]), list(res[key].values()))
            res[f"{key}_fit"] = {"fixed_s": a, "per_material_ms": 1e3 * b}
    if args.json:
        print(json.dumps(res, indent=2))
        return
    print(f"\nload average after: {res['loadavg_after']}\n")
    print("| step | " + " | ".join(f"N={n}" for n in sorted({*res['plan'], *res['assemble'], *res['shared_assemble']}))
          + " | fixed + per material |")
    cols = sorted({*res["plan"], *res["assemble"], *res["shared_assemble"]})
    print("|---|" + "---:|" * (len(cols) + 1))
    for key, label in (("plan", "`plan` (scan, hash, read, coverage)"), ("assemble", "build from the cache, fresh OUT"),
                       ("noop", "no-op rebuild"),
                       ("shared_assemble", f"build from the cache, fresh OUT, materials sharing {args.train} sets"),
                       ("shared_noop", f"no-op rebuild, materials sharing {args.train} sets")):
        row = [f"{res[key][n]:.2f}" if n in res[key] else "" for n in cols]
        f = res.get(f"{key}_fit")
        print(f"| {label} | " + " | ".join(row) + (f" | {f['fixed_s']:.2f} s + {f['per_material_ms']:.1f} ms |"
                                                  if f else " | |"))
    if "train" in res:
        t = res["train"]
        print(f"\ncold build of {t['n']} texture sets ({args.size}², tiny, draft, 2 workers): {t['wall_s']:.1f} s; "
              f"a job: {t['job_s_median']:.2f} s median; outputs {t['out_bytes'] / 2**20:.2f} MiB")


if __name__ == "__main__":
    main()
