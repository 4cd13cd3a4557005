"""Ray's overhead against the local executor: the same build, the same cores, one run.

    .venv/bin/python benchmarks/bench_ray.py [--scene samples/sample_scene.usda] [--quality draft]
                                             [--repeat 3] [--cpus 2] [--tasks 200] [--json]

1. Start-up: `ray start --head` on 127.0.0.1 (a cluster of --cpus CPUs), a driver connecting to it,
   and a driver starting a Ray of its own (what `--executor ray` does with no address); each
   timed in a fresh process, import included.
2. Per task: the round trip of an empty task (submit, run, get; sequential, warm workers), the
   throughput of --tasks empty tasks at once, the first task of a new driver, and ray.put of the
   scene's largest source and of 1, 16 and 64 MiB with a task reading it (a job's object-store traffic).
3. Builds: `bcfpipe build SCENE --no-cache --threads 1`, local (`--jobs` = --cpus) against Ray on the
   running cluster, interleaved (local, ray, local, ray, ...), each timed as a process from start
   to exit. Both train the same texture sets on the same cores.

Prints one line per measurement and Markdown tables for docs/benchmarks.md (or one JSON object).
"""
from __future__ import annotations

import argparse
import json
import os
import secrets
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import REPO, add_options, machine  # noqa: E402

RAY = Path(sys.executable).with_name("ray")
# a token-authenticated cluster: Ray 2.60 listens on every interface even when told 127.0.0.1
ENV = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))

PROBE = r"""
import json, statistics, sys, time
t0 = time.perf_counter()
import ray
t_import = time.perf_counter() - t0
address, n_tasks, blob_path = sys.argv[1] or None, int(sys.argv[2]), sys.argv[3]
t0 = time.perf_counter()
ray.init(address=address or "local", log_to_driver=False, include_dashboard=False, configure_logging=False,
         **({} if address else {"num_cpus": int(sys.argv[4]), "_temp_dir": sys.argv[5]}))
t_init = time.perf_counter() - t0

@ray.remote(num_cpus=1)
def empty(x=None):
    return x

t0 = time.perf_counter(); ray.get(empty.remote()); t_first = time.perf_counter() - t0
for _ in range(5):
    ray.get(empty.remote())
rt = []
for _ in range(50):
    t0 = time.perf_counter(); ray.get(empty.remote()); rt.append(time.perf_counter() - t0)
t0 = time.perf_counter(); ray.get([empty.remote() for _ in range(n_tasks)]); t_many = time.perf_counter() - t0
import os
put = {}
for name, data in (("blob", open(blob_path, "rb").read()), ("1 MiB", os.urandom(1 << 20)),
                   ("16 MiB", os.urandom(16 << 20)), ("64 MiB", os.urandom(64 << 20))):
    ts = []
    for _ in range(5):
        t0 = time.perf_counter(); ref = ray.put(data); ray.get(empty.remote(ref)); ts.append(time.perf_counter() - t0)
        del ref
    put[name] = 1e3 * statistics.median(ts)
blob_bytes = os.path.getsize(blob_path)
t0 = time.perf_counter(); ray.shutdown(); t_shutdown = time.perf_counter() - t0
print(json.dumps({"import_s": t_import, "init_s": t_init, "first_task_s": t_first,
                  "roundtrip_ms": 1e3 * statistics.median(rt), "tasks_per_s": n_tasks / t_many,
                  "put_get_ms": put, "blob_bytes": blob_bytes, "shutdown_s": t_shutdown}))
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def probe(address: str | None, tasks: int, blob: Path, cpus: int) -> dict:
    tmp = tempfile.mkdtemp(prefix="bcfray-")
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", PROBE, address or "", str(tasks), str(blob), str(cpus), tmp],
                       capture_output=True, text=True, env=ENV, timeout=600)
    wall = time.perf_counter() - t0
    shutil.rmtree(tmp, ignore_errors=True)
    if p.returncode:
        sys.exit(f"probe failed: {p.stderr[-2000:]}")
    out = json.loads(p.stdout.strip().splitlines()[-1])
    out["process_s"] = wall
    return out


def build(scene: Path, out: Path, quality: str, extra: list[str]) -> dict:
    t0 = time.perf_counter()
    with tempfile.TemporaryFile("w+") as so, tempfile.TemporaryFile("w+") as se:
        p = subprocess.Popen([sys.executable, "-m", "bcfpipe", "build", str(scene), "-o", str(out), "--no-cache",
                              "--quality", quality, "--threads", "1", "--json", *extra],
                             stdout=so, stderr=se, text=True, env=ENV)
        _, status, usage = os.wait4(p.pid, 0)  # the driver's own peak RSS (ru_maxrss, KiB)
        p.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
        so.seek(0), se.seek(0)
        stdout, stderr = so.read(), se.read()
    if p.returncode:
        sys.exit(f"build failed ({' '.join(extra)}): {stderr[-2000:]}")
    rep = json.loads(stdout)
    train = [m["train_seconds"] for m in rep["materials"] if m.get("train_seconds")]
    return {"wall_s": wall, "report_wall_s": rep["totals"]["wall_seconds"], "trained": rep["totals"]["trained"],
            "train_s_sum": sum(train), "driver_max_rss_mib": usage.ru_maxrss / 1024}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", type=Path, default=REPO / "samples" / "sample_scene.usda")
    add_options(ap, quality="draft", repeat=3)
    ap.add_argument("--cpus", type=int, default=2, help="CPUs of the Ray cluster, and local --jobs")
    ap.add_argument("--tasks", type=int, default=200, help="empty tasks submitted at once (throughput)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if not RAY.exists():
        sys.exit("needs ray: pip install 'bcfpipe[ray]'")
    say = (lambda *a: None) if args.json else (lambda *a: print(*a, flush=True))
    say(f"machine: {machine()}; load average {os.getloadavg()}")
    from bcfpipe.builder.plan import plan
    from bcfpipe.config import TrainingOptions

    sources = [Path(s) for s in plan(args.scene, TrainingOptions(preset=args.quality)).sources]
    blob = max(sources, key=lambda p: p.stat().st_size)
    res: dict = {"machine": machine(), "scene": os.path.relpath(args.scene, REPO), "quality": args.quality,
                 "cpus": args.cpus, "blob": blob.name}

    # 1. a Ray of the driver's own (no cluster running yet)
    res["own_ray"] = probe(None, args.tasks, blob, args.cpus)
    say(f"driver starting its own Ray: {json.dumps(res['own_ray'])}")

    tmp = Path(tempfile.mkdtemp(prefix="r", dir="/tmp"))
    port = free_port()
    try:
        t0 = time.perf_counter()
        subprocess.run([str(RAY), "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}",
                        f"--num-cpus={args.cpus}", "--include-dashboard=false", f"--temp-dir={tmp}",
                        "--disable-usage-stats"], check=True, capture_output=True, env=ENV, timeout=300)
        res["cluster_start_s"] = time.perf_counter() - t0
        address = f"127.0.0.1:{port}"
        say(f"ray start --head ({args.cpus} CPUs): {res['cluster_start_s']:.2f} s")
        res["connect"] = probe(address, args.tasks, blob, args.cpus)
        say(f"driver connecting to the cluster: {json.dumps(res['connect'])}")

        runs: dict[str, list[dict]] = {"local": [], "ray": []}
        for r in range(args.repeat):
            for name, extra in (("local", ["--executor", "local", "--jobs", str(args.cpus)]),
                                ("ray", ["--executor", "ray", "--ray-address", address])):
                out = tmp / f"out-{name}-{r}"
                b = build(args.scene, out, args.quality, extra)
                shutil.rmtree(out, ignore_errors=True)
                runs[name].append(b)
                say(f"run {r + 1} {name}: {b['wall_s']:.1f} s wall (report {b['report_wall_s']:.1f} s), "
                    f"{b['trained']} texture sets, {b['train_s_sum']:.1f} s of training summed, "
                    f"driver peak RSS {b['driver_max_rss_mib']:.0f} MiB")
        res["builds"] = runs
    finally:
        subprocess.run([str(RAY), "stop", "--force"], capture_output=True, env=ENV, timeout=300)
        shutil.rmtree(tmp, ignore_errors=True)
    res["loadavg_after"] = os.getloadavg()

    med = {k: statistics.median(b["wall_s"] for b in v) for k, v in runs.items()}
    n = runs["local"][0]["trained"]
    res["median_wall_s"] = med
    res["overhead_per_build_s"] = med["ray"] - med["local"]
    res["overhead_per_task_s"] = (med["ray"] - med["local"]) / max(1, n)
    if args.json:
        print(json.dumps(res, indent=2))
        return
    o, c = res["own_ray"], res["connect"]
    print(f"\nload average after: {res['loadavg_after']}\n")
    print("| start-up | seconds |")
    print("|---|---:|")
    print(f"| `ray start --head` ({args.cpus} CPUs, 127.0.0.1) | {res['cluster_start_s']:.2f} |")
    print(f"| driver: `import ray` | {c['import_s']:.2f} |")
    print(f"| driver: `ray.init(address)` (connect to the cluster) | {c['init_s']:.2f} |")
    print(f"| driver: `ray.init()` (start its own Ray) | {o['init_s']:.2f} |")
    print(f"| first empty task of a new driver (Ray keeps idle workers started) | {c['first_task_s']:.2f} |")
    print(f"| `ray.shutdown()` of a driver that started its own Ray | {o['shutdown_s']:.2f} |")
    print()
    print("| per task | connected | own Ray |")
    print("|---|---:|---:|")
    print(f"| empty task round trip, warm worker (median of 50) | {c['roundtrip_ms']:.1f} ms | {o['roundtrip_ms']:.1f} ms |")
    print(f"| empty tasks per second, {args.tasks} at once | {c['tasks_per_s']:.0f} | {o['tasks_per_s']:.0f} |")
    for k in c["put_get_ms"]:
        what = f"{blob.name} ({c['blob_bytes'] / 2**20:.2f} MiB)" if k == "blob" else f"{k} of bytes"
        print(f"| `ray.put` + a task reading {what} | {c['put_get_ms'][k]:.1f} ms | {o['put_get_ms'][k]:.1f} ms |")
    print()
    print(f"| build ({n} texture sets, `--quality {args.quality} --threads 1 --no-cache`) | runs (s) | median (s) "
          "| training summed (s) | driver peak RSS (MiB) |")
    print("|---|---|---:|---:|---:|")
    for k, label in (("local", f"local, `--jobs {args.cpus}`"), ("ray", f"Ray, {args.cpus}-CPU cluster on loopback")):
        walls = ", ".join(f"{b['wall_s']:.1f}" for b in runs[k])
        tr = statistics.median(b["train_s_sum"] for b in runs[k])
        rss = max(b["driver_max_rss_mib"] for b in runs[k])
        print(f"| {label} | {walls} | {med[k]:.1f} | {tr:.1f} | {rss:.0f} |")
    print(f"\nRay overhead: {res['overhead_per_build_s']:+.1f} s per build, "
          f"{res['overhead_per_task_s']:+.2f} s per texture set")


if __name__ == "__main__":
    main()
