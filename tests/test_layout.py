"""The package layout's promises (issue 17): a click-free library, one set of training options for
`train` and `build`, and `bcfpipe scan` reporting exactly the texture sets that `bcfpipe build` trains."""
from __future__ import annotations

import json
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner

from bcfpipe.build import BuildError, plan
from bcfpipe.cli import main
from bcfpipe.cli.build import build as build_cmd
from bcfpipe.cli.options import TRAINING_OPTION_NAMES
from bcfpipe.cli.train import train_cmd


def test_library_does_not_import_click():
    code = ("import bcfpipe.build, bcfpipe.scan, bcfpipe.train, bcfpipe.verify, bcfpipe.formats, sys; "
            "import bcfpipe.bench.run, bcfpipe.bench.report, bcfpipe.bench.decode_cost, bcfpipe.train.rate; "
            "import bcfpipe.render.frames, bcfpipe.render.compare; "
            "assert 'click' not in sys.modules, 'click imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def _options(cmd: click.Command) -> dict[str, click.Option]:
    return {p.name: p for p in cmd.params if isinstance(p, click.Option)}


def test_train_and_build_take_the_same_training_options():
    train, build = _options(train_cmd), _options(build_cmd)
    for name in TRAINING_OPTION_NAMES:
        a, b = train[name], build[name]
        assert (a.opts, a.default, a.is_flag, str(a.type), a.help) == (b.opts, b.default, b.is_flag, str(b.type), b.help)
    help_of = {c: CliRunner().invoke(main, [c, "--help"]).output for c in ("train", "build")}
    for name in TRAINING_OPTION_NAMES:
        for opt in train[name].opts:
            assert opt in help_of["train"] and opt in help_of["build"], opt
    # no other option of either command sets something a training depends on
    only_train = set(train) - set(TRAINING_OPTION_NAMES)
    only_build = set(build) - set(TRAINING_OPTION_NAMES)
    assert only_train == {"output", "resolution", "wrap", "force", "as_json"}
    # --texel-density and --no-coverage read the scene's meshes (train's --resolution is the first's counterpart)
    # --shard, --executor and --ray-address choose which jobs run and where, not how they train
    assert only_build == {"out", "variants", "all_materials", "jobs", "as_json", "force", "run_verify_after",
                          "cache_dir", "no_cache", "depfile", "depfile_target", "texel_density", "no_coverage",
                          "shard", "executor_name", "ray_address"}


def _scenes(root):
    return sorted(p for p in root.rglob("*") if p.suffix in (".usd", ".usda", ".usdc", ".usdz"))


def test_scan_reports_the_texture_sets_that_build_trains(shared_scenes):
    """On every USD file in ../shared/scenes: `scan --json` texture sets == the planned jobs, with
    the same materials (no training; plan reads and hashes the textures)."""
    runner = CliRunner()
    compared = 0
    for scene in _scenes(shared_scenes):
        r = runner.invoke(main, ["scan", "--json", str(scene)])
        try:
            bp = plan(scene, device="cpu")
        except BuildError:
            assert r.exit_code == 2, (scene, r.output)
            continue
        assert r.exit_code == 0, (scene, r.output)
        sets = json.loads(r.output)["texture_sets"]
        assert [(s["name"], s["materials"]) for s in sets] == [(j.name, list(j.materials)) for j in bp.jobs], scene
        modelled = {m.path for m in bp.materials if m.job}
        assert modelled == {p for s in sets for p in s["materials"]}, scene
        compared += 1
    assert compared >= 10
