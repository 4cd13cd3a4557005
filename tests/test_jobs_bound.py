"""Issue 58: ``--jobs N`` bounds every process and thread a build starts, encoders included.

Real ``bcfpipe build`` runs (subprocesses, as a user's shell starts them) of a small scene with
``--jobs 1``, with the default layout (BC@R's quicktex and ISPC encodes, weighed) and with
``--layout neural`` (a training, the evaluation through onnxruntime), ``BCFPIPE_TRACE_POOLS`` set: every place that opens a
pool or sets a thread count appends what it opened (bcfpipe/pooltrace.py). Every record must say
one worker, and no encoder process pool or thread beside a training may start. Before issue 58 a
lone job on a 2-core machine encoded on 2 cores: quicktex in a pool of 2 processes, beside the
probe's training.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bcfpipe.builder.executor import core_shares
from bcfpipe.pooltrace import TRACE_ENV, trace_pool
from bcfpipe.texset import parallel
from test_build import add_material, new_stage, pattern, write_png


def _scene(tmp: Path) -> Path:
    """One material: colour (BC1), roughness (BC4) and a normal map (BC5) at 64²."""
    write_png(tmp / "tex" / "a.png", pattern(64))
    write_png(tmp / "tex" / "r.png", pattern(64, c=1, seed=2)[..., 0])
    write_png(tmp / "tex" / "n.png", pattern(64, seed=4))
    stage = new_stage(tmp / "s.usda")
    add_material(stage, "/World/Looks/M", {"diffuseColor": ("./tex/a.png", "rgb", {}),
                                           "roughness": ("./tex/r.png", "r", {}),
                                           "normal": ("./tex/n.png", "rgb", {"sourceColorSpace": "raw"})},
                 mesh="/World/A")
    stage.Save()
    return tmp / "s.usda"


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def _build(tmp_path: Path, name: str, *extra: str) -> tuple[dict, list[dict]]:
    """A ``--jobs 1`` build of the scene with pool tracing: its report and what it opened."""
    trace = tmp_path / f"{name}.jsonl"
    env = dict(os.environ, **{TRACE_ENV: str(trace)})
    proc = subprocess.run([sys.executable, "-m", "bcfpipe", "build", str(_scene(tmp_path / name)), "-o",
                           str(tmp_path / name / "out"), "--profile", "tiny", "--quality", "smoke", "--jobs", "1",
                           "--json", *extra], capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout), _records(trace)


def test_jobs_1_opens_every_pool_and_thread_group_with_one_worker(tmp_path: Path) -> None:
    """The default layout (BC@R weighed; here nothing neural fits its bytes, so no model trains)
    and ``--layout neural`` (a model trained and measured through onnxruntime)."""
    report, auto = _build(tmp_path, "auto")
    (m,) = report["materials"]
    assert m["status"] == "built" and m["layout"]["bc_size_bytes"] > 0  # BC@R was encoded and weighed
    report, neural = _build(tmp_path, "neural", "--layout", "neural")
    assert report["materials"][0]["status"] == "built"
    records = auto + neural
    kinds = {r["kind"] for r in records}
    # what builds open: the job pool, and in its worker torch, OpenImageIO, the encode share, onnxruntime
    assert {"job-pool", "encode-share", "oiio"} <= {r["kind"] for r in auto}, auto
    assert {"job-pool", "torch-intra-op", "torch-inter-op", "oiio", "oiio-exr", "encode-share",
            "onnxruntime"} <= kinds, kinds
    assert [r for r in records if r["workers"] != 1] == [], "every pool and thread group has one worker"
    assert "quicktex-openmp" in {r["kind"] for r in auto}, "quicktex's own OpenMP threads are bounded"
    assert not kinds & {"encode-process-pool", "encode-thread-pool", "encode-beside-training"}, \
        "with one core the encodes run inline: no encoder process or thread"
    for run in (auto, neural):
        (pool,) = [r for r in run if r["kind"] == "job-pool"]
        workers = {r["pid"] for r in run if r["kind"] == "torch-intra-op"}
        assert pool["pid"] not in workers, "training ran in the job pool's worker"


def test_core_shares() -> None:
    def t(*a):
        s = core_shares(*a)
        return s.workers, s.threads, s.encode

    assert t(5, 1, 1) == (1, 1, 1)  # --jobs 1: one core everywhere
    assert t(5, 1, 4) == (1, 1, 1)  # a --threads above --jobs is cut to it
    assert t(5, 4, 2) == (2, 2, 2)  # 4 cores, 2 threads a job: 2 jobs side by side
    assert t(5, 3, 2) == (1, 2, 3)  # 3 cores: 1 job of 2 threads, its encodes on all 3
    assert t(1, 8, 1) == (1, 1, 8)  # a lone job gets every core of the budget for its encodes
    assert t(3, 8, 1) == (3, 1, 2)  # never more workers than jobs; the cores shared among them
    for n_jobs in (1, 2, 7):
        for jobs in (1, 2, 3, 8):
            for threads in (1, 2, 5):
                w, th, enc = t(n_jobs, jobs, threads)
                assert w * max(th, enc) <= jobs and 1 <= w <= n_jobs and th <= threads


def test_core_shares_without_jobs_use_the_machine(monkeypatch) -> None:
    """No --jobs: as fast as before issue 58, one job per core, a lone job encoding on every core."""
    import bcfpipe.builder.executor as ex

    monkeypatch.setattr(ex, "cpu_count", lambda: 4)
    monkeypatch.setattr(parallel, "_cores", lambda: 4)
    s = core_shares(1, None, 1)
    assert (s.workers, s.threads, s.encode) == (1, 1, 4)
    s = core_shares(8, None, 1)
    assert (s.workers, s.threads, s.encode) == (4, 1, 1)
    s = core_shares(2, None, 3)
    assert (s.workers, s.threads, s.encode) == (2, 3, 3)  # never fewer than --threads


def test_job_encode_workers(monkeypatch) -> None:
    monkeypatch.setattr(parallel, "_cores", lambda: 2)
    # with --jobs (cores): the budget's share, whatever the machine has
    assert parallel.job_encode_workers(1, 1, cores=1) == 1  # issue 58: --jobs 1 on 2 cores encodes on 1
    assert parallel.job_encode_workers(1, 1, cores=8) == 8
    assert parallel.job_encode_workers(1, 3, cores=8) == 2
    assert parallel.job_encode_workers(1, 9, cores=8) == 1  # never fewer than one
    # without: the machine's cores shared, never fewer than the job's threads
    assert parallel.job_encode_workers(1, 1) == 2
    assert parallel.job_encode_workers(1, 2) == 1
    assert parallel.job_encode_workers(3, 2) == 3


def test_one_worker_encodes_inline_off_the_main_thread(tmp_path: Path, monkeypatch) -> None:
    """quicktex in a thread beside a training, with one worker: inline, no process pool (before
    issue 58 any encode off the main thread started one)."""
    import threading

    import numpy as np

    monkeypatch.setenv(TRACE_ENV, str(tmp_path / "t.jsonl"))
    parallel.release_workers()  # a pool an earlier test of this process kept
    px = np.zeros((64, 64, 4), np.uint8)
    out: list = []

    def enc() -> None:
        with parallel.workers(1):
            out.append(parallel.quicktex_level("bc4 channel 0", px, 8))

    th = threading.Thread(target=enc)
    th.start()
    th.join()
    assert out and out[0].shape == (256, 8) and parallel._pool is None
    assert {r["kind"] for r in _records(tmp_path / "t.jsonl")} <= {"encode-beside-training", "quicktex-openmp"}
    assert [r["workers"] for r in _records(tmp_path / "t.jsonl")] in ([1], [1, 1])


_THREADS_AFTER = """
import os, sys, threading, time, numpy as np
from bcfpipe.texset import parallel


def settled():  # threads a join let go of take a moment to leave /proc: the count once it holds still
    seen, t0 = [], time.monotonic()
    while time.monotonic() - t0 < 3.0:
        seen.append(len(os.listdir('/proc/self/task')))
        if len(seen) >= 10 and len(set(seen[-10:])) == 1:
            break
        time.sleep(0.02)
    return seen[-1]


parallel.set_encode_workers(int(sys.argv[1]))
px = np.random.default_rng(0).integers(0, 256, (512, 512, 4), dtype=np.uint8)  # distinct blocks: a whole level's encode (`distinct_blocks`)
if sys.argv[2] == 'beside':  # the main thread encodes first, then a thread of its own with one worker
    parallel.quicktex_level('bc1 level 13', px, 8)
    idle = threading.Thread(target=lambda: None)  # a first thread leaves one behind: counted before
    idle.start()
    idle.join()
before = settled()
if sys.argv[2] == 'beside':
    def enc():
        with parallel.workers(1):
            parallel.quicktex_level('bc1 level 13', px, 8)
    th = threading.Thread(target=enc)
    th.start()
    th.join()
else:
    parallel.quicktex_level('bc1 level 13', px, 8)
print(settled() - before)
"""


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc (Linux)")
def test_quicktex_runs_on_the_workers_it_is_given() -> None:
    """quicktex encodes on its own OpenMP runtime (not torch's), on every core unless told: with one
    worker no thread starts, with two one more does, and none in a thread beside a training with one
    worker (`parallel.openmp_threads`)."""
    started = [int(subprocess.run([sys.executable, "-c", _THREADS_AFTER, str(n), where], capture_output=True,
                                  text=True, check=True).stdout) for n, where in ((1, "main"), (2, "main"), (1, "beside"))]
    assert started == [0, 1, 0], started  # OpenMP's count is per thread: a new thread is told again


def test_trace_is_silent_without_the_variable(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv(TRACE_ENV, raising=False)
    trace_pool("x", 3)  # nothing to write to, nothing raised
    monkeypatch.setenv(TRACE_ENV, str(tmp_path / "t.jsonl"))
    trace_pool("x", 3, where="here")
    assert _records(tmp_path / "t.jsonl") == [{"kind": "x", "workers": 3, "pid": os.getpid(), "where": "here"}]


@pytest.mark.parametrize("n", [1, 2])
def test_driver_threads_are_restored(n: int) -> None:
    import OpenImageIO as oiio

    from bcfpipe.builder.run import driver_threads

    before = oiio.get_int_attribute("threads"), oiio.get_int_attribute("exr_threads")
    with driver_threads(n):
        assert 1 <= oiio.get_int_attribute("threads") <= n
    assert (oiio.get_int_attribute("threads"), oiio.get_int_attribute("exr_threads")) == before
