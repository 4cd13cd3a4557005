"""Issue 58: the default layout's wall time against `--layout neural`'s, before and after, interleaved.

For each set, in turn: the default layout with the code BEFORE (a source tree, e.g. a `git worktree`
of the commit before the change), `--layout neural` with this tree, the default layout with this
tree; each run alone, into a fresh folder, with no cache. The teapot, brick, wood and water bottle
sets are trained with `bcfpipe train` (default profile), the sample scene built with `bcfpipe build
--no-cache`. Prints per run the wall seconds, what shipped and its per-mip PSNR, and per set the
ratios auto / neural before and after, and whether the decision held: the same layout, or one
within 0.1 dB at every mip, or better; never below BC@R - 0.5 dB (BC@R as BEFORE measured it,
encoded in full) at any mip.

  python benchmarks/bench_default_cost.py BEFORE_TREE [--sets teapot,brick,wood,bottle,sample]
      [--quality draft] [--profile P] [--reps 1] [--neural-before] [--json out.json] [--before-json earlier.json]

``--neural-before``: `--layout neural` with BEFORE too, right after BEFORE's default, for a change
that moves both (the final measure): the ratio before is then BEFORE's own, auto / neural.

``--before-json``: BEFORE's runs from an earlier ``--json`` of this script (the same quality and
profile) instead of running BEFORE again: its code does not change, and its figures decide only
the ratio "before" and whether the decisions held; the ratio now is always this run's, interleaved.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import MX, REPO, SET_ARGS, add_options, machine, write_json  # noqa: E402

SETS = {
    "teapot": SET_ARGS["teapot"],
    # the grey base as an rgb albedo (SET_ARGS' brick has it as one generic channel)
    "brick": [f"albedo={MX / 'brick' / 'brick_base_gray.jpg'}:rgb", f"normal={MX / 'brick' / 'brick_normal.jpg'}:xy",
              f"roughness={MX / 'brick' / 'brick_roughness.jpg'}:r"],
    "wood": SET_ARGS["wood"],
    "bottle": SET_ARGS["bottle"],
    "sample": None,  # samples/sample_scene.usda, built
}


def run(tree: Path, name: str, layout: str, quality: str, out: Path, profile: str | None = None) -> dict:
    """One run of ``tree``'s bcfpipe: wall seconds and what shipped (per material)."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(tree))
    py = str(REPO / ".venv" / "bin" / "python")
    common = ["--quality", quality, "--layout", layout, "--json", *(["--profile", profile] if profile else [])]
    if SETS[name] is None:
        cmd = [py, "-m", "bcfpipe", "build", str(tree / "samples" / "sample_scene.usda"), "-o", str(out),
               "--no-cache", *common]
    else:
        cmd = [py, "-m", "bcfpipe", "train", *SETS[name], "-o", str(out), *common]
    t = time.perf_counter()
    p = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"{name} {layout} ({tree}): exit {p.returncode}: {p.stderr[-600:]}")
    folders = [out] if SETS[name] is not None else sorted(d for d in (out / "materials").iterdir() if d.is_dir())
    shipped = {}
    for f in folders:
        key = name if SETS[name] is not None else f.name
        lay = f / "layout.json"
        if lay.exists():
            d = json.loads(lay.read_text())
            shipped[key] = {"layout": d["chosen"]["layout"], "psnr_per_mip": d["chosen"]["psnr_per_mip"],
                               "bc_psnr_per_mip": d["bc"]["psnr_per_mip"], "bc_basis": d["bc"].get("basis"),
                               "size_bytes": d["chosen"]["size_bytes"], "bc_bytes": d["bc"]["size_bytes"],
                               "cost_seconds": d.get("cost_seconds") or _phases(p.stdout)}
    return {"wall_seconds": round(wall, 1), "shipped": shipped}


def _phases(stdout: str) -> dict | None:
    """A train run's layout_* phase seconds from its --json output (a build's: None)."""
    try:
        d = json.loads(stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return None
    return {k[7:]: v for k, v in (d.get("phase_seconds") or {}).items() if k.startswith("layout_")} or None


def held(before: dict, after: dict) -> list[str]:
    """Per material: the same layout; or one within 0.1 dB at every mip; or better; and never below
    BC@R - 0.5 dB (BEFORE's BC@R, encoded in full) at any mip, nor bigger."""
    out = []
    for m, b in before["shipped"].items():
        a = after["shipped"].get(m)
        if a is None:
            out.append(f"{m}: missing after")
            continue
        diff = [x - y for x, y in zip(a["psnr_per_mip"], b["psnr_per_mip"])]
        floor = [x - y for x, y in zip(a["psnr_per_mip"], b["bc_psnr_per_mip"])]
        same = "same layout" if a["layout"] == b["layout"] else f"{b['layout']} -> {a['layout']}"
        worst = min(diff[:-2] or diff)
        kind = ("same figures" if max(abs(d) for d in diff) < 1e-3 else
                "within 0.1 dB" if worst >= -0.1 else "WORSE by %.2f dB at a mip" % -worst)
        ok = min(floor[:-2] or floor) >= -0.5 and a["size_bytes"] <= b["bc_bytes"]
        out.append(f"{m}: {same}, {kind} (worst mip {worst:+.2f} dB), "
                   f"{'within' if ok else 'NOT within'} BC@R - 0.5 dB and its bytes")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before", type=Path, nargs="?", help="BEFORE's source tree (not with --before-json)")
    add_options(ap, sets="teapot,brick,wood,bottle,sample", quality="draft", reps=1)
    ap.add_argument("--profile", help="passed to every run (default: the default profile)")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--before-json", type=Path, help="BEFORE's runs from an earlier --json of this script")
    ap.add_argument("--neural-before", action="store_true", help="run --layout neural with BEFORE too")
    a = ap.parse_args()
    if (a.before is None) == (a.before_json is None):
        ap.error("give BEFORE_TREE or --before-json, not both")
    if a.neural_before and a.before is None:
        ap.error("--neural-before runs BEFORE_TREE: give it")
    earlier = {}
    if a.before_json:
        d = json.loads(a.before_json.read_text())
        if d["quality"] != a.quality or d.get("profile") != a.profile:
            ap.error(f"{a.before_json} ran at {d['quality']}, profile {d.get('profile')}")
        earlier = {(r["set"], r["rep"]): r["auto_before"] for r in d["runs"]}
    before, after = (a.before.resolve() if a.before else None), REPO
    print(f"machine: {machine()}; quality {a.quality}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in a.sets.split(","):
            for rep in range(a.reps):
                r = {"set": name, "rep": rep}
                plan = [("auto_before", before, "auto"), ("neural", after, "neural"), ("auto_after", after, "auto")]
                if a.neural_before:
                    plan.insert(1, ("neural_before", before, "neural"))
                for key, tree, layout in plan:
                    if tree is None:
                        if (name, rep) not in earlier:
                            raise SystemExit(f"{a.before_json} has no run of {name} (rep {rep})")
                        r[key] = dict(earlier[name, rep], reused=str(a.before_json))
                    else:
                        r[key] = run(tree, name, layout, a.quality, Path(tmp) / key, a.profile)
                    print(f"  {name} {key}: {r[key]['wall_seconds']} s "
                          f"{[(k, v['layout']) for k, v in r[key]['shipped'].items()]}", flush=True)
                nb, na = r["auto_before"]["wall_seconds"], r["auto_after"]["wall_seconds"]
                n = r["neural"]["wall_seconds"]
                n_before = r["neural_before"]["wall_seconds"] if "neural_before" in r else n
                r["ratio_before"], r["ratio_after"] = round(nb / n_before, 2), round(na / n, 2)
                r["decisions"] = held(r["auto_before"], r["auto_after"])
                print(f"{name}: auto before {nb} s, neural before {n_before} s, neural {n} s, auto after {na} s: "
                      f"{r['ratio_before']}x -> {r['ratio_after']}x", flush=True)
                for line in r["decisions"]:
                    print("    " + line, flush=True)
                rows.append(r)
    write_json(a.json, quality=a.quality, profile=a.profile, runs=rows)


if __name__ == "__main__":
    main()
