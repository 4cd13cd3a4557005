"""One record per job (issue 51): every field of `config.JobOptions` reaches the worker that trains
it, in a local build and in a Ray build, changes the job's cache key unless it is declared
`UNKEYED` (with where its effect goes instead), and reaches manifest.json unless it is declared
`UNRECORDED` (issue 59: the record writes itself there; a new field needs no other change).

The worker side is observed for real: the build runs in a subprocess whose Python processes (its
local workers, or Ray's workers) load `sitecustomize` from a folder of this test, which wraps the
real `bcfpipe.fit.fit` to write down the record and the `TrainConfig` it trains with, then trains.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from dataclasses import fields
from pathlib import Path

import pytest

from bcfpipe.builder import plan
from bcfpipe.builder.plan import content_hash
from bcfpipe.config import UNKEYED, UNRECORDED, JobOptions, TrainingOptions

from test_build import copy_samples

#: a value other than the default for every field of the job record, and what it needs beside it
NON_DEFAULT = {
    "profile": ("0.5k", {}), "preset": ("draft", {}), "hidden": (8, {}), "signed": (True, {"features": "bc6h"}),
    "init": ("pca", {}), "fix_nonfinite": (True, {}), "seed": (3, {}), "device": ("cuda", {"kernel": "torch"}),
    "threads": (2, {}), "target_psnr": (30.0, {}), "bench_data": ("bench.json", {"target_psnr": 30.0}),
    "features": ("bc6h", {}), "kernel": ("torch", {}), "layout": ("auto", {}),
    "match_bc": (True, {"layout": "auto"}), "classic": (("normal",), {}), "t0": ("trained", {}),
    "resolution": (32, {}), "texel_density": (100.0, {}), "coverage": (False, {}), "pca_clip": (0.0, {}),
    "t0_layers": (2, {}),
}
#: the fields that change nothing a job trains: their effect is keyed through another field or input
UNKEYED_FIELDS = {"threads", "bench_data", "texel_density"}
#: the fields manifest.json leaves out: how a build ran, not what it made
UNRECORDED_FIELDS = {"threads", "bench_data"}


def test_every_field_is_covered_and_the_unkeyed_ones_are_declared() -> None:
    """A new field of the record fails here until it has a non-default value above, and the
    fields left out of the key are exactly the declared ones."""
    assert set(NON_DEFAULT) == {f.name for f in fields(JobOptions)}
    assert {f.name for f in fields(JobOptions) if UNKEYED in f.metadata} == UNKEYED_FIELDS
    assert {f.name for f in fields(JobOptions) if UNRECORDED in f.metadata} == UNRECORDED_FIELDS
    for f in fields(JobOptions):
        assert NON_DEFAULT[f.name][0] != f.default, f.name


def test_every_keyed_field_changes_the_cache_key(tmp_path: Path) -> None:
    """From a real job of the sample scene: each field set to another value (with what it needs
    beside it) changes the key, unless it is UNKEYED; the same record keys the same."""
    scene = copy_samples(tmp_path)
    job = plan(scene, TrainingOptions(profile="tiny", preset="smoke", layout="neural")).jobs[0]
    sources = {s.path: s for s in job.sources}

    def key(options: JobOptions) -> str:
        return content_hash(job.specs, sources, job.wrap, options)

    assert key(job.options) == key(JobOptions.from_json(json.loads(json.dumps(job.options.to_json()))))
    for name, (value, needs) in NON_DEFAULT.items():
        base = job.options.with_(**needs)
        changed = base.with_(**{name: value})
        assert getattr(changed, name) != getattr(base, name), name
        assert (key(changed) != key(base)) == (name not in UNKEYED_FIELDS), name


def test_every_field_survives_the_executors_transport(tmp_path: Path) -> None:
    """A job whose every record field is non-default comes out of the local executor's pickle and
    Ray's JSON-able dict whole, and the worker trains that record with only its device and thread
    count set (builder.executor.train_job); the full builds below show it reaching the TrainConfig."""
    import pickle

    from bcfpipe.builder.plan import MaterialJob

    scene = copy_samples(tmp_path)
    job = plan(scene, TrainingOptions(profile="tiny", preset="smoke", layout="neural")).jobs[0]
    auto_only = ("match_bc", "classic", "layout", "t0_layers")  # with --target-psnr the layout is neural;
    # a wider T_0 holds principal components, which the first record's trained bc6h T_0 does not
    record = JobOptions(**{name: v for name, (v, _) in NON_DEFAULT.items() if name not in auto_only})
    for f in fields(JobOptions):
        assert f.name in auto_only or getattr(record, f.name) != f.default, f.name
    for options in (record, JobOptions(profile="tiny", layout="auto", match_bc=True, classic=("normal",),
                                                     t0_layers=2)):
        sent = MaterialJob(**{**job.__dict__, "options": options}).to_dict()
        for arrived in (pickle.loads(pickle.dumps(sent)), json.loads(json.dumps(sent))):
            assert MaterialJob.from_dict(arrived).options == options
            assert MaterialJob.from_dict(arrived).options.with_(device="cpu", threads=1) == \
                options.with_(device="cpu", threads=1)


SITE = '''
import json, os, sys
import importlib.abc, importlib.util

TRACE = os.environ.get("BCFPIPE_TEST_FIT_TRACE")


class _WrapFit(importlib.abc.MetaPathFinder):
    """Once bcfpipe.fit.entry loads, its fit writes down what it was given, then runs."""

    def find_spec(self, name, path, target=None):
        if name != "bcfpipe.fit.entry":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            real = module.fit

            def fit(ts, options, out, **kw):
                from dataclasses import asdict
                from bcfpipe.export.material import make_config

                _, cfg = make_config(ts, options, kw["wrap"])
                mode = module.fit_mode(options, sorted({c.semantic for c in ts.channels}))
                rec = {"out": str(out), "options": options.to_json(), "config": asdict(cfg), "mode": mode.value,
                       "size": [ts.width, ts.height], "coverage": kw.get("coverage") is not None}
                with open(TRACE, "a") as f:
                    f.write(json.dumps(rec, default=str) + "\\n")
                return real(ts, options, out, **kw)

            module.fit = fit

        spec.loader.exec_module = exec_module
        return spec


if TRACE:
    sys.meta_path.insert(0, _WrapFit())
'''

DRIVER = textwrap.dedent('''
    import json, sys
    from bcfpipe.builder import Execution, Selection, build
    from bcfpipe.config import TrainingOptions

    training = TrainingOptions.from_json(json.loads(sys.argv[1]))
    selection = Selection(**{k: tuple(v) if k == "materials" else v for k, v in json.loads(sys.argv[2]).items()})
    r = build(sys.argv[3], sys.argv[4], training=training, selection=selection,
              execution=Execution(executor=sys.argv[5], cache=False, jobs=2))  # --threads 2 fits in 2 cores
    print(json.dumps([j.options.to_json() for j in r.plan.jobs]))
    sys.exit(r.exit_code)
''')

BRICKS = "/World/Looks/Bricks"  # one material of the sample scene, with a normal map
#: two builds give every field a non-default value (some exclude others: --target-psnr with
#: --classic or --match-bc); the first's layout, neural under --target-psnr, is not the default's
BUILDS = [
    ({"profile": "tiny", "preset": "smoke", "hidden": 8, "signed": True, "init": "pca", "fix_nonfinite": True,
      "seed": 3, "device": "cpu", "threads": 2, "target_psnr": 10.0, "bench_data": "bench.json",
      "features": "bc6h", "kernel": "torch", "t0": "trained"},
     {"texel_density": 40.0, "coverage": False, "materials": [BRICKS]}, {"rate"}),
    ({"profile": "tiny", "preset": "smoke", "layout": "auto", "match_bc": True, "classic": ["normal"],
      "pca_clip": 0.0, "t0_layers": 2}, {"materials": [BRICKS], "texel_density": 40.0}, {"layout"}),
]


def _build_traced(tmp_path: Path, executor: str) -> list[tuple[list[dict], list[dict], str]]:
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SITE)
    scene = copy_samples(tmp_path / "scene")
    runs = []
    for i, (training, selection, mode) in enumerate(BUILDS):
        trace = tmp_path / f"trace{i}.jsonl"
        env = dict(os.environ, BCFPIPE_TEST_FIT_TRACE=str(trace), RAY_USAGE_STATS_ENABLED="0",
                   PYTHONPATH=os.pathsep.join([str(site), *filter(None, [os.environ.get("PYTHONPATH")])]))
        p = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(training), json.dumps(selection), str(scene),
                            str(tmp_path / f"out{i}"), executor], capture_output=True, text=True, env=env,
                           timeout=900)
        assert p.returncode == 0, p.stderr[-3000:]
        planned = json.loads(p.stdout.strip().splitlines()[-1])
        traced = [json.loads(line) for line in trace.read_text().splitlines()]
        manifest = json.loads((tmp_path / f"out{i}" / "manifest.json").read_text())
        runs.append((planned, traced, mode, manifest["options"]))
    return runs


def _check(runs) -> None:
    """Each worker trained its job's record, whole, into the TrainConfig its fields ask for; the
    manifest records the build's record whole, through the record's own serialisation."""
    seen: dict[str, set] = {f.name: set() for f in fields(JobOptions)}
    recorded: dict[str, set] = {f.name: set() for f in fields(JobOptions) if UNRECORDED not in f.metadata}
    for planned, traced, modes, manifest in runs:
        assert set(manifest) == set(recorded)  # every field but the UNRECORDED ones, by the record's names
        assert JobOptions.from_json(manifest).recorded() == manifest
        for name, value in manifest.items():
            recorded[name].add(json.dumps(value))
        assert len(traced) == len(planned) and traced
        assert {rec["mode"] for rec in traced} == modes
        for rec in traced:
            assert rec["options"] in planned, [{k: (v, p.get(k)) for k, v in rec["options"].items() if p.get(k) != v}
                                               for p in planned]  # the whole record, every field as the plan made it
            o, cfg = rec["options"], rec["config"]
            assert (cfg["model"]["hidden"], cfg["seed"], cfg["model"]["features"], cfg["kernel"],
                    cfg["feature_init"], cfg["model"]["signed"], cfg["preset_name"], cfg["threads"]) == \
                (o["hidden"], o["seed"], o["features"], o["kernel"], o["init"], o["signed"], o["preset"], o["threads"])
            assert cfg["t0"] == (o["t0"] or ("pca" if o["features"] == "bc7" else "trained"))
            assert cfg["device"] == o["device"] == "cpu"
            assert cfg["model"]["pca_clip"] == o["pca_clip"] / 100
            assert 1 <= cfg["model"]["t0_layers"] <= (o["t0_layers"] or 1 if o["layout"] == "neural" else 3)
            assert o["coverage"] or not rec["coverage"]  # covered: a mask where the meshes leave texels unread
            if o["resolution"] is not None:
                assert max(rec["size"]) == o["resolution"]
            for f in fields(JobOptions):
                seen[f.name].add(json.dumps(o[f.name]))
    for f in fields(JobOptions):  # every field took a value other than its default in some worker
        default = json.dumps(JobOptions().to_json()[f.name])
        assert seen[f.name] - {default}, f.name
        # and in some build's manifest, but a job's own resolution (the build's is None)
        assert f.name in ("resolution",) or UNRECORDED in f.metadata or recorded[f.name] - {default}, f.name


@pytest.mark.slow
def test_every_field_reaches_the_local_workers_trainer(tmp_path: Path) -> None:
    _check(_build_traced(tmp_path, "local"))


@pytest.mark.slow
def test_every_field_reaches_the_ray_workers_trainer(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    _check(_build_traced(tmp_path, "ray"))
