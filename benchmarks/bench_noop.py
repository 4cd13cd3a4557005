"""Cold build and no-op rebuild of the teapot (Fancy variant) with the cache, as a build system
sees them: the wall time of the `bcfpipe build` process, start to exit.

    .venv/bin/python benchmarks/bench_noop.py [--repeat 5] [--preset draft] [--profile auto]

The scene is copied to a temporary folder with a fresh cache. One cold build (trains), then
``--repeat`` no-op rebuilds (every job a cache hit, nothing written; the script checks both).
Prints the machine, every run, and a Markdown row for docs/benchmarks.md. Issue #10 asks for a
no-op median of at most 2 s on the 2-core reference machine.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, machine, needs, run_bcfpipe  # noqa: E402


def run(args: list[str], cwd: Path) -> tuple[float, dict]:
    wall, p = run_bcfpipe("-q", *args, "--json", cwd=cwd)
    if p.returncode != 0:
        raise SystemExit(f"build failed ({p.returncode}): {p.stderr.strip()}")
    return wall, json.loads(p.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--preset", default="draft", help="preset of the cold build (the no-op does not depend on it)")
    ap.add_argument("--profile", default="auto")
    a = ap.parse_args()
    src = needs(SHARED / "usdwg_teapot")
    print(f"machine: {machine()}; load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="bcf-noop-") as tmp:
        work = Path(tmp) / "teapot"
        shutil.copytree(src, work)
        args = ["build", "Teapot.usd", "--variant", "modelVariant=Fancy", "-o", "out", "--cache", "cache",
                "--profile", a.profile, "--quality", a.preset]
        cold, rep = run(args, work)
        assert rep["totals"]["trained"] == rep["totals"]["jobs"] >= 1, rep["totals"]
        print(f"cold build: {cold:.2f} s wall ({rep['totals']['trained']} texture set(s) trained, "
              f"preset {a.preset}, profile {a.profile})")
        noop = []
        for i in range(a.repeat):
            wall, rep = run(args, work)
            assert rep["totals"]["trained"] == 0 and rep["written"] == [], rep
            noop.append(wall)
            print(f"no-op {i + 1}: {wall:.3f} s wall (in-process {rep['totals']['wall_seconds']:.3f} s)")
    med = statistics.median(noop)
    print(f"no-op median of {len(noop)}: {med:.3f} s (min {min(noop):.3f}, max {max(noop):.3f}); "
          f"load average {os.getloadavg()[0]:.2f}")
    print(f"| teapot Fancy | {a.preset} | {cold:.1f} s | {med:.2f} s | {min(noop):.2f}-{max(noop):.2f} s |")


if __name__ == "__main__":
    main()
