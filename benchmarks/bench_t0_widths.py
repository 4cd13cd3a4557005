"""Issue 52: what `--layout auto` ships and what every T_0 width holds, per mip, from the exported files.

For each set: `bcfpipe train SET --profile P --quality Q` with the default layout (auto), then
`--layout neural --t0-layers k` for every width k the set's channels allow (k ≤ ⌈channels/4⌉),
each into its own folder under ``--out`` (a folder that already holds a result is read, not
trained again, so an interrupted run resumes). Prints one markdown table per set: BC@R and the BC7
quality set (measured by auto's layout fit, exact), what auto ships, and each width, with GPU MiB,
MiB on disk (every shipped file zstd-19-compressed), PSNR at mips 0..3 and over all mips, and the
margins at mips 0 and 1 against BC@R and against the BC7 quality set.

  python benchmarks/bench_t0_widths.py --sets teapot,brick,wood,bottle --profile 1k --quality standard --out DIR
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import add_options, machine, mip_columns, psnr_cells, run_bcfpipe, spec_args, specs  # noqa: E402

MIPS = 4


def _train(name: str, out: Path, args: argparse.Namespace, extra: list[str]) -> dict:
    """The --json result of one `bcfpipe train` into ``out`` (read back when it is there already)."""
    result = out.with_suffix(".json")
    if result.is_file():
        return json.loads(result.read_text())
    # BENCH_LOCK: a file to flock(1) each training on, on a machine shared with other jobs
    wall, p = run_bcfpipe("train", *spec_args(name), "--profile", args.profile, "--quality", args.quality,
                          "--threads", args.threads, "-o", out, "--force", "--json", *extra,
                          lock=os.environ.get("BENCH_LOCK"))
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(p.args)}: exit {p.returncode}: {p.stderr.strip().splitlines()[-1:]}")
    d = json.loads(p.stdout)
    d["wall_seconds"] = wall
    d["disk_bytes"] = _disk(out)
    result.write_text(json.dumps(d))
    return d


def _disk(folder: Path) -> int:
    from bcfpipe.export.material import shipped_disk_bytes

    return shipped_disk_bytes(folder)


def _row(label: str, size: int, disk: int | None, mips, allm: float, bc, q) -> str:
    def margin(ref):
        return " / ".join(f"{mips[k] - ref[k]:+.1f}" for k in (0, 1))

    d = f"{disk / 2**20:.2f}" if disk else "—"
    return f"| {label} | {size / 2**20:.2f} | {d} | {psnr_cells(mips[:MIPS], allm)} | {margin(bc)} | {margin(q)} |"


def table(name: str, auto: dict, widths: dict[int, dict]) -> str:
    """The markdown table of one set (module docstring)."""
    lay = auto["layout"]
    use = len(lay["bc"]["psnr_per_mip"])
    bc, q = lay["bc"], lay["bc7_quality"] or lay["bc"]
    b, qq = bc["psnr_per_mip"], q["psnr_per_mip"]
    ch = lay["chosen"]
    lines = ["| layout | GPU MiB | disk MiB | " + mip_columns(MIPS) + " | all mips | vs BC@R mip 0 / 1 | vs BC7 set mip 0 / 1 |",
             "|---|---:|---:|" + "---:|" * (MIPS + 1) + "---|---|",
             _row("BC@R", bc["size_bytes"], bc["disk_bytes"], b, bc["psnr"], b, qq),
             _row("BC7 quality set", q["size_bytes"], q["disk_bytes"], qq, q["psnr"], b, qq),
             _row(f"**auto ships: {ch['layout']}**", auto["size_bytes"], auto["disk_bytes"],
                  auto["metrics"]["psnr_per_mip"][:use], auto["psnr"], b, qq)]
    for k, d in sorted(widths.items()):
        lines.append(_row(f"neural {d['profile']}, T_0 of {k} layer{'s' if k > 1 else ''}", d["size_bytes"],
                          d["disk_bytes"], d["metrics"]["psnr_per_mip"][:use], d["psnr"], b, qq))
    return f"{name}: {auto['layout']['reason']}\n\n" + "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_options(ap, sets="teapot,brick,wood,bottle", profile="1k", quality="standard", threads=1)
    ap.add_argument("--widths-only", action="store_true", help="train the widths, not auto (no table)")
    ap.add_argument("--out", type=Path, required=True, help="one folder per training; results are reused")
    args = ap.parse_args()
    from bcfpipe.config import max_t0_layers

    args.out.mkdir(parents=True, exist_ok=True)
    print(f"machine: {machine()}; --profile {args.profile} --quality {args.quality}, {args.threads} thread(s)")
    for name in args.sets.split(","):
        n = sum(len(s.channels) for s in specs(name))
        widths = {k: _train(name, args.out / f"{name}_{args.profile}_w{k}", args,
                            ["--layout", "neural", "--t0-layers", str(k)])
                  for k in range(1, max_t0_layers(n) + 1)}
        if args.widths_only:
            for k, d in widths.items():
                print(f"{name} width {k}: {d['size_bytes'] / 2**20:.2f} MiB, "
                      + " ".join(f"{v:.2f}" for v in d["metrics"]["psnr_per_mip"][:MIPS])
                      + f", all {d['psnr']:.2f} (trained in {d['train_seconds']:.0f} s)", flush=True)
            continue
        auto = _train(name, args.out / f"{name}_{args.profile}_auto", args, [])
        print("\n" + table(name, auto, widths) + "\n", flush=True)
        print(f"training: auto {auto['train_seconds']:.0f} s; " + ", ".join(
            f"width {k} {d['train_seconds']:.0f} s" for k, d in widths.items()), flush=True)


if __name__ == "__main__":
    main()
