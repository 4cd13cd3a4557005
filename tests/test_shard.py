"""`bcfpipe build --shard I/N`: shards partition the jobs, train into the cache only, and a plain
build then assembles byte-identical outputs without training anything."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import add_material, new_stage, pattern, write_png  # noqa: E402

from bcfpipe.builder.shard import parse_shard, shard_of  # noqa: E402
from bcfpipe.errors import InputError  # noqa: E402


def scene(root: Path, n: int = 4) -> Path:
    stage = new_stage(root / "scene.usda")
    for k in range(n):
        write_png(root / "tex" / f"c{k}.png", pattern(32, 3, seed=k))
        add_material(stage, f"/World/Looks/M{k}", {"diffuseColor": (f"./tex/c{k}.png", "rgb", {})},
                     mesh=f"/World/Mesh{k}")
    stage.Save()
    return root / "scene.usda"


def bcf(*args: str, cache: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bcfpipe", "build", *args, "--cache", str(cache), "--quality", "smoke",
                           "--jobs", "1", "--threads", "1"], capture_output=True, text=True, timeout=900)


def files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_shard_arguments() -> None:
    assert parse_shard("2/3") == (2, 3)
    for bad in ("0/2", "3/2", "a/b", "1", "1/0"):
        with pytest.raises(InputError):
            parse_shard(bad)
    import xxhash

    hashes = [xxhash.xxh3_128_hexdigest(str(k).encode()) for k in range(300)]
    counts = [sum(shard_of(h, 3) == i for h in hashes) for i in (1, 2, 3)]
    assert sum(counts) == 300 and min(counts) > 70  # every shard gets its share


def test_two_shards_then_assembly_match_one_build(tmp_path: Path) -> None:
    s = scene(tmp_path / "a")
    p1 = subprocess.Popen([sys.executable, "-m", "bcfpipe", "build", str(s), "--shard", "1/2", "--json", "--cache",
                           str(tmp_path / "cache"), "--quality", "smoke", "--jobs", "1", "--threads", "1"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    r2 = bcf(str(s), "--shard", "2/2", "--json", cache=tmp_path / "cache")
    out1, err1 = p1.communicate(timeout=900)
    assert p1.returncode == 0 and r2.returncode == 0, err1 + r2.stderr
    a, b = json.loads(out1), json.loads(r2.stdout)
    names_a = {j["name"] for j in a["jobs"]}
    names_b = {j["name"] for j in b["jobs"]}
    assert a["total_jobs"] == 4 and not names_a & names_b and len(names_a | names_b) == 4
    assert all(j["cache"] == "miss" for j in a["jobs"] + b["jobs"])
    assert not (tmp_path / "a" / "scene.bcf").exists()  # a shard writes only the cache
    # the assembly trains nothing
    r = bcf(str(s), "--json", cache=tmp_path / "cache")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["totals"]["trained"] == 0 and report["totals"]["cached"] == 4
    # a shard run again finds its jobs cached
    again = bcf(str(s), "--shard", "1/2", "--json", cache=tmp_path / "cache")
    assert all(j["cache"] == "hit" for j in json.loads(again.stdout)["jobs"])
    # byte-identical to one build of a copy of the scene with its own cache
    s2 = scene(tmp_path / "b")
    assert bcf(str(s2), cache=tmp_path / "cache2").returncode == 0
    assert files(tmp_path / "a" / "scene.bcf") == files(tmp_path / "b" / "scene.bcf")
    bad = bcf(str(s), "--shard", "1/2", "-o", str(tmp_path / "o"), cache=tmp_path / "cache")
    assert bad.returncode == 2 and "drop -o/--out" in bad.stderr
