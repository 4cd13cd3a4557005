"""Teapot (Fancy) built with and without --texel-density (issue #18): size, wall time, PSNR per mip
over the texels the teapot reads (each build against its own reference: 2048² or the capped size).

    .venv/bin/python benchmarks/bench_density.py [--density 512] [--preset draft] [--repeat 1]

Each build is cold (a fresh cache) in a temporary copy of the scene; the runs alternate
(default, capped, default, capped, ...). Prints the machine, every run, and Markdown rows.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, add_options, machine, run_bcfpipe  # noqa: E402


def run(scene: Path, out: Path, cache: Path, preset: str, density: float | None) -> tuple[float, dict, dict]:
    args = ["-q", "build", scene, "--variant", "modelVariant=Fancy", "-o", out, "--cache", cache, "--quality", preset,
            "--json"]
    if density:
        args += ["--texel-density", density]
    wall, p = run_bcfpipe(*args)
    if p.returncode != 0:
        raise SystemExit(f"build failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
    manifest = json.loads((out / "manifest.json").read_text())
    return wall, json.loads(p.stdout), manifest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_options(ap, density=512.0, preset="draft", repeat=1)
    a = ap.parse_args()
    print(f"machine: {machine()}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bcfdensity-") as tmp:
        src = Path(tmp) / "teapot"
        shutil.copytree(SHARED / "usdwg_teapot", src)
        for r in range(a.repeat):
            for density in (None, a.density):
                tag = f"{r}-{density or 'default'}"
                wall, report, manifest = run(src / "Teapot.usd", Path(tmp) / f"out-{tag}", Path(tmp) / f"cache-{tag}",
                                             a.preset, density)
                (m,) = [x for x in manifest["materials"] if x["status"] == "built"]
                q = m["metrics"]["detail"]
                psnr, per_mip = q.get("psnr_covered", q["psnr"]), q.get("psnr_per_mip_covered", q["psnr_per_mip"])
                row = (density, m["profile"], m["resolutions"], manifest["totals"]["total_bytes"], wall,
                       report["totals"]["train_seconds"], psnr, per_mip, q.get("covered_fraction"))
                rows.append(row)
                print(f"run {tag}: profile {row[1]} {row[2]}, {row[3] / 2**20:.2f} MiB, wall {wall:.0f} s, "
                      f"train {row[5]:.0f} s, PSNR over read texels {psnr:.2f} dB "
                      f"(covered fraction {row[8]}), per mip " + ", ".join(f"{v:.1f}" for v in per_mip))
    print("| --texel-density | profile | resolutions | size | wall | train | PSNR over read texels, its own reference |")
    print("|---|---|---|---:|---:|---:|---:|")
    for d, prof, res, size, wall, train, psnr, _, _ in rows:
        print(f"| {d or '—'} | {prof} | {res} | {size / 2**20:.2f} MiB | {wall:.0f} s | {train:.0f} s | {psnr:.2f} dB |")


if __name__ == "__main__":
    main()
