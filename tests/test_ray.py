"""The Ray executor on a real Ray cluster: two nodes on loopback (`ray start --head` plus a second
`ray start --address`), byte-identical outputs to a local build, a worker killed mid-job, and
Ctrl-C cancelling the running tasks."""
from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_shard import files, scene  # noqa: E402

from bcfpipe.builder.ray_executor import in_flight_limit, resolve_executor  # noqa: E402

RAY = Path(sys.executable).with_name("ray")
# Ray 2.60 listens on every interface even when told 127.0.0.1, so the test cluster takes a token
# (and so does not depend on what ~/.ray/auth_token holds)
AUTH = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}


def test_executor_choice(monkeypatch) -> None:
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert resolve_executor("auto", None) == "local"
    assert resolve_executor("auto", "127.0.0.1:6379") == "ray"
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:6379")
    assert resolve_executor("auto", None) == "ray" and resolve_executor("local", None) == "local"


def test_in_flight_limit_follows_the_cluster_not_the_scene() -> None:
    assert in_flight_limit({"CPU": 2.0}, 1, 0, 10_000) == 4  # 2 slots + 2 queued
    assert in_flight_limit({"CPU": 64.0}, 2, 0, 10_000) == 64  # 32 slots of 2 threads + 32 queued
    assert in_flight_limit({"CPU": 4096.0}, 1, 0, 10_000) == 4096 + 32
    assert in_flight_limit({"CPU": 64.0, "GPU": 8.0}, 1, 1, 10_000) == 16  # GPUs are the slots
    assert in_flight_limit({"CPU": 64.0}, 1, 0, 3) == 3 and in_flight_limit({}, 1, 0, 5) == 2


def test_without_the_ray_package_one_line(tmp_path: Path) -> None:
    code = ("import sys; sys.modules['ray'] = None; from bcfpipe.cli import main; "
            f"sys.argv = ['bcfpipe', 'build', {str(tmp_path / 'x.usda')!r}, '--executor', 'ray']; main()")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 2 and "pip install 'bcfpipe[ray]'" in p.stderr and "Traceback" not in p.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster():
    """A head node and a second node on 127.0.0.1, one CPU each; torn down whatever happens. One
    cluster at a time on the machine (a file lock across pytest-xdist workers): `ray stop --force`
    stops every Ray process, so two clusters would tear each other down."""
    if not RAY.exists():
        pytest.skip("needs ray (pip install 'bcfpipe[ray]')")
    from filelock import FileLock

    lock = FileLock(os.path.join(tempfile.gettempdir(), "bcfpipe-test-ray-cluster.lock"))
    lock.acquire(timeout=1800)
    port = _free_port()
    tmp = tempfile.mkdtemp(prefix="r", dir="/tmp")  # Ray's socket paths must stay short
    saved = {k: os.environ.get(k) for k in AUTH}
    os.environ.update(AUTH)  # the cluster and every driver of this module (build subprocesses too)
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    try:
        subprocess.run([str(RAY), "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=1",
                        "--include-dashboard=false", f"--temp-dir={tmp}", "--disable-usage-stats"],
                       check=True, capture_output=True, text=True, timeout=180, env=env)
        subprocess.run([str(RAY), "start", f"--address=127.0.0.1:{port}", "--node-ip-address=127.0.0.1",
                        "--num-cpus=1", "--disable-usage-stats"],
                       check=True, capture_output=True, text=True, timeout=180, env=env)
        yield f"127.0.0.1:{port}"
    finally:
        subprocess.run([str(RAY), "stop", "--force"], capture_output=True, timeout=180, env=env)
        shutil.rmtree(tmp, ignore_errors=True)
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)
        lock.release()


def _train_task_pids() -> list[int]:
    return [int(x) for x in subprocess.run(["pgrep", "-f", "ray::train_task"], capture_output=True,
                                           text=True).stdout.split()]


def _free_cpus(address: str) -> tuple[float, float]:
    """(available, total) CPUs of the cluster, asked by a fresh driver."""
    code = ("import ray, json; ray.init(address=%r, log_to_driver=False); "
            "print(json.dumps([ray.available_resources().get('CPU', 0), ray.cluster_resources().get('CPU', 0)]))"
            % address)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=180,
                       env=dict(os.environ, RAY_USAGE_STATS_ENABLED="0"))
    return tuple(json.loads(p.stdout.strip().splitlines()[-1]))


def build(s: Path, cache: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "bcfpipe", "build", str(s), "--cache", str(cache), "--quality",
                             "draft", "--threads", "1", "--json", *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=dict(os.environ, RAY_USAGE_STATS_ENABLED="0"))


@pytest.mark.slow
def test_two_node_cluster_matches_a_local_build_and_survives_a_killed_worker(cluster, tmp_path: Path) -> None:
    import ray

    # the cluster has two nodes
    ray.init(address=cluster, log_to_driver=False)
    try:
        assert len([n for n in ray.nodes() if n["Alive"]]) == 2
    finally:
        ray.shutdown()
    a = scene(tmp_path / "a", n=3)
    p = build(a, tmp_path / "cache-ray", "--executor", "ray", "--ray-address", cluster)
    out, err = p.communicate(timeout=900)
    assert p.returncode == 0, err
    assert out.lstrip().startswith("{"), out[:2000]
    report = json.loads(out)
    assert report["executor"] == "ray" and report["totals"]["trained"] == 3
    b = scene(tmp_path / "b", n=3)
    p = build(b, tmp_path / "cache-local", "--executor", "local", "--jobs", "1")
    assert p.wait(timeout=900) == 0
    assert files(tmp_path / "a" / "scene.bcf") == files(tmp_path / "b" / "scene.bcf")

    # kill the worker process of a running job: Ray retries it and the build reports the retry
    c = scene(tmp_path / "c", n=1)
    p = build(c, tmp_path / "cache-kill", "--executor", "ray", "--ray-address", cluster)
    victim = None
    deadline = time.monotonic() + 300
    while victim is None and time.monotonic() < deadline and p.poll() is None:
        found = subprocess.run(["pgrep", "-f", "ray::train_task"], capture_output=True, text=True).stdout.split()
        if found:
            time.sleep(2.0)  # let it start training
            victim = int(found[0])
            os.kill(victim, signal.SIGKILL)
        else:
            time.sleep(0.2)
    out, err = p.communicate(timeout=900)
    assert victim is not None, "no Ray worker ran the job"
    assert p.returncode == 0 and out.lstrip().startswith("{"), (out[:500], err[-3000:])
    (m,) = [m for m in json.loads(out)["materials"] if m["status"] == "built"]
    assert m["attempts"] == 2


@pytest.mark.slow
def test_ctrl_c_cancels_the_running_tasks(cluster, tmp_path: Path) -> None:
    """SIGINT while both nodes train: exit 130 with one line, OUT not created, nothing half-stored in
    the cache, and the cluster's CPUs free again (the tasks were cancelled, not left running)."""
    s = scene(tmp_path / "i", n=2)
    p = build(s, tmp_path / "cache-int", "--executor", "ray", "--ray-address", cluster)
    deadline = time.monotonic() + 300
    while len(_train_task_pids()) < 2 and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.2)
    assert len(_train_task_pids()) == 2, "the two jobs never ran at once"
    time.sleep(2.0)
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=180)
    assert p.returncode == 130, err[-3000:]
    assert "Error: interrupted" in err and "Traceback" not in err, err[-3000:]
    assert out == "" and not (tmp_path / "i" / "scene.bcf").exists()
    assert not any((tmp_path / "cache-int").rglob("entry.json"))
    deadline = time.monotonic() + 60
    while (free := _free_cpus(cluster))[0] < free[1] and time.monotonic() < deadline:
        time.sleep(1.0)
    assert free == (2.0, 2.0) and not _train_task_pids()


@pytest.mark.slow
def test_a_ray_of_its_own_leaves_nothing_behind(tmp_path: Path) -> None:
    """`--executor ray` with no cluster starts a Ray for the build and ends it: the build succeeds,
    and nothing is left in HOME (Ray alone would write ~/.ray/auth_token) or in the temporary folder
    (Ray's session files)."""
    if not RAY.exists():
        pytest.skip("needs ray (pip install 'bcfpipe[ray]')")
    home, tmp = tmp_path / "home", Path(tempfile.mkdtemp(prefix="t", dir="/tmp"))  # short: Ray's socket paths
    home.mkdir()
    try:
        env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_AUTH_TOKEN", "RAY_AUTH_MODE")}
        env.update(HOME=str(home), TMPDIR=str(tmp), RAY_USAGE_STATS_ENABLED="0")
        s = scene(tmp_path / "s", n=1)
        p = subprocess.run([sys.executable, "-m", "bcfpipe", "build", str(s), "--no-cache", "--quality", "draft",
                            "--executor", "ray", "--json"], capture_output=True, text=True, env=env, timeout=900)
        assert p.returncode == 0, p.stderr[-3000:]
        assert json.loads(p.stdout)["executor"] == "ray"
        time.sleep(2.0)  # Ray's processes end after the build
        assert not any(home.iterdir()), sorted(p.name for p in home.iterdir())
        assert not any(tmp.iterdir()), sorted(p.name for p in tmp.iterdir())
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@pytest.mark.slow
def test_a_job_that_fails_fails_alone(cluster, tmp_path: Path) -> None:
    """Five jobs on two CPUs: four are submitted at once (slots + queue), the fifth when one ends.
    Its texture is saved again once training has started, so the driver finds bytes its cache
    key does not name: that job fails with one line, the other four build, exit 1."""
    from test_build import pattern, write_png

    s = scene(tmp_path / "f", n=5)
    order = json.loads(subprocess.run([sys.executable, "-m", "bcfpipe", "plan", str(s), "--json", "--quality",
                                       "draft"], capture_output=True, text=True, timeout=300).stdout)["jobs"]
    last = order[-1]["materials"][0].rsplit("/", 1)[-1]  # M<k>: its texture is c<k>.png
    p = build(s, tmp_path / "cache-f", "--executor", "ray", "--ray-address", cluster)
    deadline = time.monotonic() + 300
    while not _train_task_pids() and time.monotonic() < deadline and p.poll() is None:
        time.sleep(0.2)
    write_png(tmp_path / "f" / "tex" / f"c{last[1:]}.png", pattern(32, 3, seed=99))
    out, err = p.communicate(timeout=900)
    assert p.returncode == 1, err[-3000:]
    status = {m["path"].rsplit("/", 1)[-1]: m for m in json.loads(out)["materials"]}
    assert status[last]["status"] == "failed" and "changed during the build" in status[last]["reason"]
    assert sorted(k for k, m in status.items() if m["status"] == "built") == sorted(set(status) - {last})
