"""The throughput model of docs/scale.md: wall time, traffic and storage of a build of N materials
on S CPU slots or GPUs, from measured per-job and per-material costs.

    .venv/bin/python benchmarks/scale_model.py [--materials 1000 10000] [--json]

Every input is a measurement of this repository's benchmarks on the reference machine (Intel
Xeon, 2 cores), named where it is defined below; the GPU job time is the paper's figure (no GPU
was lent to measure ours). The model:

    wall = plan(N) + max(ceil(J / S) * t_job, J * driver_per_job) + assemble(N)

with J = N jobs (no two materials share a texture set), a cold plan (every source decoded once
for its texel facts), plan and assembly linear in N (benchmarks/bench_scale.py), and the driver's
serial work per job: ray.put of the sources, receiving the outputs, and storing them into the
staging folder and the cache.
"""
from __future__ import annotations

import argparse
import json
import math

MIB = 2**20

# benchmarks/bench_scale.py (docs/benchmarks.md "Scale"): 10,000 materials from the cache, 19 s:
# the plan 10.8 s (compose, scan every network, areas, coverage), the assembly 7.8 s (USD layer,
# manifest.json, records); texel facts warm. A cold plan also decodes every distinct source once:
# the teapot's two 2K JPEGs cost 0.0-0.16 s more cold than warm (`bcfpipe plan`, run twice).
PLAN_FIXED_S, PLAN_PER_MATERIAL_S = 0.4, 0.00108
ASSEMBLE_FIXED_S, ASSEMBLE_PER_MATERIAL_S = 0.3, 0.00078
COLD_FACTS_S_PER_SOURCE = 0.05  # decoding one 2K JPEG for its texel facts, once per distinct file
SOURCES_PER_MATERIAL = 2
# benchmarks/bench_ray.py: ray.put + a task reading it, 64 MiB in 0.12-0.14 s
OBJECT_STORE_S_PER_MIB = 0.0020
# benchmarks/bench_scale.py: the driver's store of a job (staging + cache, fsynced): 0.5k 5.3 ms,
# 1k 8.6 ms
STORE_S = {"0.5k": 0.0053, "1k": 0.0086, "2k": 0.0086 * 4}
# per-job driver work besides the bytes: a task's submission and result (bench_ray's empty task
# round trip, 1.6-1.9 ms)
DRIVER_FIXED_PER_JOB_S = 0.002

# a job's sizes: the teapot's texture set (two 2K JPEGs) and the exported files per profile
# (4 BC6H feature textures with mips, weights, decoder.onnx, material.json)
SOURCE_MIB = 3.4
OUT_MIB = {"0.5k": 0.45, "1k": 1.78, "2k": 7.1}
WEIGHTS_BYTES_PER_MATERIAL = 708  # weights.bin share (hidden 16, fp16)
MANIFEST_BYTES_PER_MATERIAL = 3900  # manifest.json (samples/sample_scene.bcf: 23.6 KB for 6 materials)
OVERRIDES_BYTES_PER_MATERIAL = 1300  # overrides.usda

# seconds per job on one CPU slot (1 torch thread), 2K sources: `bcfpipe bench` on the teapot and
# the brick (docs/benchmarks.md, issue 12), mean of the two sets
CPU_JOB_S = {("0.5k", "fast"): 107, ("1k", "standard"): 444}
# the paper (§7): about 140 minutes for its 1K model's 205k steps on an RTX 2070 with PyTorch,
# and "decent results after 10k steps, in approximately 15 minutes"
GPU_JOB_S = {("1k", "paper"): 140 * 60, ("1k", "10k steps"): 15 * 60}


def wall(n: int, slots: int, t_job: float, profile: str, source_mib: float = SOURCE_MIB) -> dict:
    out_mib = OUT_MIB[profile]
    driver = DRIVER_FIXED_PER_JOB_S + (source_mib + out_mib) * OBJECT_STORE_S_PER_MIB + STORE_S[profile]
    train = math.ceil(n / slots) * t_job
    serial = n * driver
    plan = PLAN_FIXED_S + n * (PLAN_PER_MATERIAL_S + SOURCES_PER_MATERIAL * COLD_FACTS_S_PER_SOURCE)
    asm = ASSEMBLE_FIXED_S + n * ASSEMBLE_PER_MATERIAL_S
    total = plan + max(train, serial) + asm
    bound = "training" if train >= max(serial, plan + asm) else "driver" if serial >= plan + asm else "plan + assembly"
    return {"materials": n, "slots": slots, "hours": total / 3600, "train_s": train, "driver_s": serial,
            "plan_s": plan, "assemble_s": asm, "bound": bound,
            "saturating_slots": math.ceil(t_job / driver)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--materials", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--cpu-slots", type=int, nargs="+", default=[32, 256, 2048],
                    help="CPU slots (nodes x cores / threads), e.g. 1, 8, 64 nodes of 32 cores")
    ap.add_argument("--gpus", type=int, nargs="+", default=[8, 64, 512])
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    rows = []
    for n in args.materials:
        for (profile, preset), t in CPU_JOB_S.items():
            for s in args.cpu_slots:
                rows.append({"kind": "cpu", "profile": profile, "preset": preset, **wall(n, s, t, profile)})
        for (profile, preset), t in GPU_JOB_S.items():
            for s in args.gpus:
                rows.append({"kind": "gpu", "profile": profile, "preset": preset, **wall(n, s, t, profile)})
    sizes = {n: {"sources_gib": n * SOURCE_MIB / 1024,
                 **{f"outputs_{p}_gib": n * m / 1024 for p, m in OUT_MIB.items()},
                 "weights_bin_mib": n * WEIGHTS_BYTES_PER_MATERIAL / MIB,
                 "manifest_mib": n * MANIFEST_BYTES_PER_MATERIAL / MIB,
                 "overrides_mib": n * OVERRIDES_BYTES_PER_MATERIAL / MIB} for n in args.materials}
    if args.json:
        print(json.dumps({"rows": rows, "sizes": sizes}, indent=2))
        return
    print("| materials | job | slots | wall | training | driver (serial) | plan (cold) | assembly | bound by |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---|")
    for r in rows:
        job = f"{r['profile']} {r['preset']} ({'GPU' if r['kind'] == 'gpu' else 'CPU'})"
        slots = f"{r['slots']} GPUs" if r["kind"] == "gpu" else f"{r['slots']} CPUs"
        print(f"| {r['materials']:,} | {job} | {slots} | {_t(r['hours'] * 3600)} | {_t(r['train_s'])} | "
              f"{_t(r['driver_s'])} | {_t(r['plan_s'])} | {_t(r['assemble_s'])} | {r['bound']} |")
    print()
    print("| materials | sources through the object store | outputs back (0.5k / 1k / 2k) | weights.bin | "
          "manifest.json | overrides.usda |")
    print("|---:|---:|---:|---:|---:|---:|")
    for n, z in sizes.items():
        print(f"| {n:,} | {z['sources_gib']:.1f} GiB | {z['outputs_0.5k_gib']:.1f} / {z['outputs_1k_gib']:.1f} / "
              f"{z['outputs_2k_gib']:.1f} GiB | {z['weights_bin_mib']:.1f} MiB | {z['manifest_mib']:.0f} MiB | "
              f"{z['overrides_mib']:.0f} MiB |")


def _t(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.0f} h"


if __name__ == "__main__":
    main()
