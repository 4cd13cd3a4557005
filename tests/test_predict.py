"""`scan` and `plan` say what the default layout will weigh (R, the probe, BC@R's bytes) and a size
that contains what the build ships (bcfpipe.layout.predict, issue 50 item 4)."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from cli_run import run_cli

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "samples" / "sample_scene.usda"


def _bcfpipe(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return run_cli(*args, cwd=cwd)  # the real CLI, in this process (`cli_run`)


def _plan(scene: Path, *options: str) -> dict:
    p = _bcfpipe("plan", str(scene), "--json", *options)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def _build(scene: Path, out: Path, *options: str) -> dict:
    p = _bcfpipe("build", str(scene), "-o", str(out), "--cache", str(out.parent / "cache"), "--json", *options)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout)


def check_prediction_holds(plan: dict, report: dict, out: Path) -> None:
    """Every job: its built bytes within the predicted range; BC@R's bytes, R and the probe profile
    what the build's layout.json says it weighed."""
    size_of = {m["job"]: m["total_bytes"] for m in report["materials"] if m["job"]}
    assert plan["jobs"]
    for job in plan["jobs"]:
        p = job["prediction"]
        built = size_of[job["name"]]
        assert p["min_bytes"] <= built <= p["max_bytes"], (job["name"], p, built)
        lay = out / "materials" / job["name"] / "layout.json"
        if p["layout"] == "auto":
            d = json.loads(lay.read_text())
            assert d["bc"]["size_bytes"] == p["bc_bytes"]
            # the probe never ships (issue 58): its all-channel candidate is weighed on its prediction
            probes = [c["profile"] for c in d.get("weighed", ()) if c["basis"] == "predicted" and c["profile"]
                      and not c["classic"] and not c.get("split")]
            neural = [c for c in d["candidates"] if c["profile"]]
            # or none is weighed: the oracle ruled every neural candidate out, and the probe was not trained
            assert p["probe"] in probes or not neural, (p["probe"], probes)
            measured = d["candidates"]  # sizes are exact whether a candidate is estimated or measured
            assert {c["profile"] for c in d["candidates"] if c["profile"] and not c.get("split")} <= set(p["profiles"])
            repacks = sorted(c["size_bytes"] for c in measured if c.get("repack"))
            assert repacks == sorted(p["repack_bytes"])
        else:
            assert p["exact"] and built == p["min_bytes"]
    lo, hi = plan["predicted_bytes"]["min"], plan["predicted_bytes"]["max"]
    assert lo <= report["totals"]["total_bytes"] <= hi


def test_plan_names_resolution_and_profiles():
    d = _plan(SAMPLE, "--quality", "smoke")
    jobs = {j["name"]: j["prediction"] for j in d["jobs"]}
    assert jobs["Bricks"]["resolution"] == 512 and jobs["Bricks"]["profile"] == "0.5k"
    assert jobs["Bricks"]["probe"] == "0.5k" and jobs["Leaves"]["resolution"] == 256
    for p in jobs.values():
        assert p["layout"] == "auto" and not p["exact"]
        assert p["min_bytes"] < p["max_bytes"] == p["bc_bytes"]  # the default objective: at most BC@R
        assert all(b <= p["bc_bytes"] for b in p["repack_bytes"])
    neural = {j["name"]: j["prediction"] for j in _plan(SAMPLE, "--quality", "smoke", "--layout", "neural")["jobs"]}
    assert all(p["exact"] and p["probe"] is None for p in neural.values())
    s = _bcfpipe("scan", str(SAMPLE), "--json")
    assert s.returncode == 0
    req = {m["path"]: m["requirements"] for m in json.loads(s.stdout)["materials"]}["/World/Looks/Bricks"]
    assert req["layout"]["bc_bytes"] == jobs["Bricks"]["bc_bytes"] and req["layout"]["probe"] == "0.5k"
    assert (req["estimated_min_bytes"], req["estimated_bytes"]) == (jobs["Bricks"]["min_bytes"],
                                                                     jobs["Bricks"]["max_bytes"])


@pytest.mark.parametrize("layout", ["auto", "neural"])
def test_sample_build_ships_within_the_plan(tmp_path, layout):
    options = ("--quality", "smoke", "--layout", layout)
    plan = _plan(SAMPLE, *options)
    out = tmp_path / "out"
    check_prediction_holds(plan, _build(SAMPLE, out, *options), out)


@pytest.mark.slow
@pytest.mark.parametrize("scene,extra", [("usdwg_teapot/Teapot.usd", ("--variant", "modelVariant=Fancy")),
                                         ("gltf_water_bottle/water_bottle.usda", ())])
def test_shared_2k_builds_ship_within_the_plan(shared_scenes, tmp_path, scene, extra):
    """The teapot scene and a 2048² set with normals (the water bottle), at draft."""
    path = shared_scenes / scene
    options = ("--quality", "draft", *extra)
    plan = _plan(path, *options)
    assert all(j["prediction"]["resolution"] == 2048 for j in plan["jobs"])
    out = tmp_path / "out"
    check_prediction_holds(plan, _build(path, out, *options), out)
