"""Issue 50, item 3: the default layout's wall time against `--layout neural`, side by side.

Builds (a) the teapot scene (../shared/scenes/usdwg_teapot/Teapot.usd, --variant modelVariant=Fancy) and (b) a 2048² set with
normals (../shared/scenes/gltf_water_bottle/water_bottle.usda: base colour, normal, ORM, emissive)
at ``--quality draft``, with the default layout (auto) and with ``--layout neural``, repetitions
interleaved (auto, neural, auto, neural, ...), each into a fresh OUT with an empty cache in /tmp.
Prints each build's wall time, the train and encode seconds its report gives, the bytes it wrote
against what `bcfpipe plan --json` predicted, and the ratio auto / neural per scene.

  python benchmarks/bench_layout_time.py [--scenes teapot,bottle] [--reps 1] [--json out.json]
"""
from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, machine  # noqa: E402

SCENES = {"teapot": (SHARED / "usdwg_teapot" / "Teapot.usd", ("--variant", "modelVariant=Fancy")),
          "bottle": (SHARED / "gltf_water_bottle" / "water_bottle.usda", ())}
LAYOUTS = ("auto", "neural")


def _bcfpipe(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bcfpipe", *args], capture_output=True, text=True)


def build(scene: Path, extra: tuple[str, ...], layout: str, root: Path, quality: str) -> dict:
    """One build into a fresh OUT with an empty cache: wall seconds, the report's figures, and the
    plan's predicted range."""
    out, cache = root / "out", root / "cache"
    for p in (out, cache):
        shutil.rmtree(p, ignore_errors=True)
    opts = ["--quality", quality, "--layout", layout, *extra]
    plan = json.loads(_bcfpipe("plan", str(scene), "--json", *opts).stdout)
    t = time.perf_counter()
    p = _bcfpipe("build", str(scene), "-o", str(out), "--cache", str(cache), "--json", *opts)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"{scene.name} {layout}: build exited {p.returncode}: {p.stderr[-400:]}")
    rep = json.loads(p.stdout)
    tot = rep["totals"]
    return {"wall_seconds": round(wall, 1), "train_seconds": tot["train_seconds"],
            "encode_seconds": tot.get("encode_seconds"), "total_bytes": tot["total_bytes"],
            "predicted_bytes": plan["predicted_bytes"],
            "layouts": {m["path"]: (m.get("layout") or {}).get("chosen", "neural") for m in rep["materials"]
                        if m["status"] == "built"},
            "predictions": [{"job": j["name"], **{k: j["prediction"][k] for k in ("resolution", "probe", "bc_bytes",
                                                                                   "min_bytes", "max_bytes")}}
                            for j in plan["jobs"]]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="teapot,bottle")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--quality", default="draft")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    print(f"machine: {machine()}", flush=True)
    runs: dict[str, dict[str, list[dict]]] = {}
    with tempfile.TemporaryDirectory(prefix="bench-layout-time-", dir="/tmp") as tmp:
        for name in args.scenes.split(","):
            scene, extra = SCENES[name]
            if not scene.is_file():
                raise SystemExit(f"needs {scene}")
            runs[name] = {lay: [] for lay in LAYOUTS}
            for rep in range(args.reps):
                for lay in LAYOUTS:
                    r = build(scene, extra, lay, Path(tmp) / f"{name}-{lay}", args.quality)
                    runs[name][lay].append(r)
                    inside = r["predicted_bytes"]["min"] <= r["total_bytes"] <= r["predicted_bytes"]["max"]
                    print(f"{name} {lay} rep {rep + 1}: {r['wall_seconds']:.1f} s wall, train {r['train_seconds']:.1f} s, "
                          f"encode {r['encode_seconds'] or 0:.1f} s; {r['total_bytes'] / 2**20:.2f} MiB, plan said "
                          f"{r['predicted_bytes']['min'] / 2**20:.2f}-{r['predicted_bytes']['max'] / 2**20:.2f} MiB "
                          f"({'inside' if inside else 'OUTSIDE'}); {r['layouts']}", flush=True)
            a = statistics.median(r["wall_seconds"] for r in runs[name]["auto"])
            n = statistics.median(r["wall_seconds"] for r in runs[name]["neural"])
            print(f"{name}: auto {a:.1f} s, neural {n:.1f} s, ratio {a / n:.2f}", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"machine": machine(), "quality": args.quality, "runs": runs}, indent=2))


if __name__ == "__main__":
    main()
