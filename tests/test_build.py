"""Tests for `bcfpipe build` (bcfpipe.builder, cli/build.py, usd_layer, formats/weights, schemas/, samples/).

Training runs use the tiny profile and the smoke preset. The sample scene is built once per module
(two workers); a second small stage checks failure isolation, de-duplication and ``--json``.
Checks that depend on process-wide USD plug-in state (schema registered or not) run in
subprocesses, as a user's tool would.
"""
from __future__ import annotations
from bcfpipe.builder import Execution, Selection

import io
import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cli_run import run_cli

from bcfpipe.errors import InputError
from pxr import Sdf, Usd, UsdGeom, UsdShade

from bcfpipe.builder.events import ProgressEvent
from bcfpipe.config import TrainingOptions
from bcfpipe.formats import weights as weightsbuf
from bcfpipe.builder import (MANIFEST, BuildError, MaterialJob, build, plan, root_layer_name)
from bcfpipe.cli.build_display import BuildDisplay
from bcfpipe.resources import SCHEMA_DIR

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO / "samples"
SCHEMAS = SCHEMA_DIR  # bcfpipe/schemas: the package ships them
SCENES = REPO.parent / "shared" / "scenes"
FAST = {"training": TrainingOptions(profile="tiny", preset="smoke", seed=0, layout="neural")}  # the neural path


def run_py(code: str, plugin: bool, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run python code in a fresh interpreter, with or without schemas/ registered."""
    env = dict(os.environ)
    env.pop("PXR_PLUGINPATH_NAME", None)
    if plugin:
        env["PXR_PLUGINPATH_NAME"] = str(SCHEMAS)
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=300)


def copy_samples(dst: Path) -> Path:
    shutil.copytree(SAMPLES / "textures", dst / "textures")
    shutil.copy2(SAMPLES / "sample_scene.usda", dst / "sample_scene.usda")
    return dst / "sample_scene.usda"


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    """The sample scene (copied) built with the default OUT next to it."""
    root = tmp_path_factory.mktemp("sample")
    scene = copy_samples(root)
    result = build(scene, execution=Execution(jobs=2), **FAST)
    return scene, result


# ---------------------------------------------------------------------------------------------
# small authored stages


def write_png(path: Path, data: np.ndarray) -> Path:
    import OpenImageIO as oiio

    path.parent.mkdir(parents=True, exist_ok=True)
    a = np.round(np.clip(data, 0, 1) * 255).astype(np.uint8)
    assert oiio.ImageBuf(np.ascontiguousarray(a)).write(str(path))
    return path


def pattern(n: int = 64, c: int = 3, seed: int = 0) -> np.ndarray:
    y, x = np.mgrid[0:n, 0:n] / n
    k = np.arange(c)[None, None, :] + 1 + seed
    return 0.5 + 0.4 * np.sin((x[..., None] * 3 + y[..., None] * 2) * np.pi * k)


def new_stage(path: Path) -> Usd.Stage:
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetDefaultPrim(stage.DefinePrim("/World", "Xform"))
    return stage


def add_material(stage: Usd.Stage, path: str, textures: dict[str, tuple[str, str, dict]] | None = None,
                 mesh: str | None = None) -> UsdShade.Material:
    """A UsdPreviewSurface material reading {input: (file, output, extra texture inputs)}."""
    T = Sdf.ValueTypeNames
    mat = UsdShade.Material.Define(stage, path)
    surf = UsdShade.Shader.Define(stage, f"{path}/Surface")
    surf.CreateIdAttr("UsdPreviewSurface")
    mat.CreateSurfaceOutput().ConnectToSource(surf.ConnectableAPI(), "surface")
    reader = UsdShade.Shader.Define(stage, f"{path}/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", T.String).Set("st")
    st = reader.CreateOutput("result", T.Float2)
    for name, (file, output, extra) in (textures or {}).items():
        tex = UsdShade.Shader.Define(stage, f"{path}/Tex_{name}")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", T.Asset).Set(file)
        tex.CreateInput("st", T.Float2).ConnectToSource(st)
        for k, v in extra.items():
            tex.CreateInput(k, T.Float4 if k in ("scale", "bias") else T.Token).Set(v)
        out = tex.CreateOutput(output, T.Float3 if output == "rgb" else T.Float)
        in_type = {"diffuseColor": T.Color3f, "emissiveColor": T.Color3f, "normal": T.Normal3f}.get(name, T.Float)
        surf.CreateInput(name, in_type).ConnectToSource(out)
    if mesh:
        m = UsdGeom.Mesh.Define(stage, mesh)
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(mat)
    return mat


def constant_stage(path: Path) -> Path:
    """A stage whose only material is untextured: builds instantly (nothing to train)."""
    stage = new_stage(path)
    mat = add_material(stage, "/World/Looks/Plain", mesh="/World/Mesh")
    UsdShade.Shader(stage.GetPrimAtPath("/World/Looks/Plain/Surface")).CreateInput(
        "roughness", Sdf.ValueTypeNames.Float).Set(0.3)
    assert mat
    stage.Save()
    return path


# ---------------------------------------------------------------------------------------------
# the sample scene


def test_sample_outputs(sample) -> None:
    scene, result = sample
    out = scene.parent / "sample_scene.bcf"
    assert result.out == out and result.exit_code == 0 and result.ok
    for name in ("sample_scene.bcf.usda", "overrides.usda", "weights.bin", MANIFEST):
        assert (out / name).is_file(), name
    manifest = json.loads((out / MANIFEST).read_text())
    status = {m["path"].rsplit("/", 1)[-1]: (m["status"], m["reason"]) for m in manifest["materials"]}
    assert status == {"Bricks": ("built", None), "Tiles": ("built", None), "TilesWorn": ("built", None),
                      "Leaves": ("built", None), "Plastic": ("skipped", "no-textures"),
                      "Unused": ("skipped", "unbound")}
    # identical texture sets train once and share their outputs
    assert [j["name"] for j in manifest["jobs"]] == ["Bricks", "Tiles", "Leaves"]
    mats = {m["path"].rsplit("/", 1)[-1]: m for m in manifest["materials"]}
    assert mats["Tiles"]["job"] == mats["TilesWorn"]["job"] == "Tiles"
    assert mats["Tiles"]["outputs"] == mats["TilesWorn"]["outputs"]
    for job in manifest["jobs"]:
        folder = out / "materials" / job["name"]
        for f in ("T0.dds", "T1.dds", "T2.dds", "T3.dds", "weights.bin", "decoder.onnx", "material.json"):
            assert (folder / f).is_file(), folder / f
    b = mats["Bricks"]
    assert [t["target"] for t in b["targets"]] == ["diffuseColor.r", "diffuseColor.g", "diffuseColor.b",
                                                   "roughness", "normal.x", "normal.y", "normal.z", "displacement"]
    assert [t["color_space"] for t in b["targets"][:4]] == ["sRGB", "sRGB", "sRGB", "raw"]
    normal = [t for t in b["targets"] if t["target"].startswith("normal")]
    assert [(t["scale"], t["bias"]) for t in normal] == [(1.0, 0.0)] * 3  # scale 2 / bias -1 in the input
    leaves = {t["target"]: t for t in mats["Leaves"]["targets"]}
    assert leaves["opacity"]["source_channel"] == "a" and leaves["opacity"]["color_space"] == "raw"
    for m in (b, mats["Leaves"]):
        assert m["metrics"]["psnr"] > 15 and m["sizes"]["total_bytes"] > 0
        assert m["device"] == "cpu" and all(len(s["xxh3_128"]) == 32 for s in m["sources"])
    assert manifest["totals"]["built"] == 4 and manifest["totals"]["trained"] == 3
    # every model channel is read once: Tiles has 3 (albedo) + 2 (normal) + 3 (ORM) outputs
    desc = json.loads((out / "materials" / "Tiles" / "material.json").read_text())
    assert desc["mlp"]["n_out"] == 8



def test_outputs_pass_their_schemas(sample) -> None:
    """manifest.json and every material.json of a real build validate against the published
    schemas (jsonschema, draft 2020-12), and read back through bcfpipe.formats unchanged."""
    import jsonschema

    from bcfpipe.formats import manifest as mfst
    from bcfpipe.formats import material as mf

    scene, result = sample
    schemas = {n: json.loads((SCHEMAS / n).read_text()) for n in ("manifest.schema.json", "material.schema.json")}
    for s in schemas.values():
        jsonschema.Draft202012Validator.check_schema(s)
    manifest = json.loads((result.out / MANIFEST).read_text())
    jsonschema.Draft202012Validator(schemas["manifest.schema.json"]).validate(manifest)
    assert mfst.read(result.out).to_json() == manifest
    folders = sorted((result.out / "materials").iterdir())
    assert [f.name for f in folders] == sorted(j["name"] for j in manifest["jobs"])
    for folder in folders:
        desc = json.loads((folder / "material.json").read_text())
        jsonschema.Draft202012Validator(schemas["material.schema.json"]).validate(desc)
        assert mf.read(folder).to_json() == desc
        assert "/" not in json.dumps(desc["outputs"])  # no paths: a cached entry serves any scene
    # a broken file fails validation (the check can fail)
    del manifest["totals"]["built"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.Draft202012Validator(schemas["manifest.schema.json"]).validate(manifest)


def test_weights_buffer(sample) -> None:
    scene, result = sample
    out = result.out
    data, entries = weightsbuf.read(out / "weights.bin")
    assert len(entries) == 3
    for e, job in zip(entries, result.manifest.to_json()["jobs"]):
        assert e.offset % 16 == 0
        assert data[e.offset:e.offset + e.size] == (out / "materials" / job["name"] / "weights.bin").read_bytes()
        assert job["weights_index"] == e.index
    stage = Usd.Stage.Open(str(result.root_layer))
    for m in result.manifest.to_json()["materials"]:
        if m["status"] != "built":
            continue
        prim = stage.GetPrimAtPath(m["path"])
        e = entries[prim.GetAttribute("bcf:weightsIndex").Get()]
        assert prim.GetAttribute("bcf:weightsOffset").Get() == e.offset
        assert prim.GetAttribute("bcf:weightsSize").Get() == e.size
        assert weightsbuf.record(data, e.index).n_out == prim.GetAttribute("bcf:mlp:outputs").Get()


def test_root_layer(sample) -> None:
    scene, result = sample
    layer = Sdf.Layer.FindOrOpen(str(result.root_layer))
    assert list(layer.subLayerPaths) == ["./overrides.usda", "../sample_scene.usda"]
    assert layer.defaultPrim == "World"
    assert layer.pseudoRoot.GetInfo("upAxis") == "Y" and layer.pseudoRoot.GetInfo("metersPerUnit") == 1.0


CHECK_ATTRS = """
    import json, sys
    from pxr import Usd
    stage = Usd.Stage.Open(sys.argv[1] if len(sys.argv) > 1 else {root!r})
    manifest = json.load(open({manifest!r}))
    report = {{}}
    for m in manifest["materials"]:
        prim = stage.GetPrimAtPath(m["path"])
        props = {{p.GetName(): p for p in prim.GetAuthoredProperties() if p.GetName().startswith("bcf:")}}
        values = {{}}
        for name, p in props.items():
            v = p.GetTargets() if isinstance(p, Usd.Relationship) else p.Get()
            values[name] = None if v is None else str(v)
        report[m["path"]] = {{"n": len(props), "none": [k for k, v in values.items() if v is None],
                             "has_api": prim.HasAPI("BcfNeuralMaterialAPI"),
                             "targets": values.get("bcf:outputs:targets")}}
    print(json.dumps(report))
"""


@pytest.mark.parametrize("plugin", [False, True], ids=["no-plugin", "plugin"])
def test_attributes_readable(sample, plugin: bool) -> None:
    scene, result = sample
    code = CHECK_ATTRS.format(root=str(result.root_layer), manifest=str(result.out / MANIFEST))
    proc = run_py(code, plugin)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    for m in result.manifest.to_json()["materials"]:
        r = report[m["path"]]
        if m["status"] == "built":
            assert r["n"] == 29 and r["none"] == [] and r["has_api"] is plugin
            assert "normal.z" in r["targets"] or m["path"].endswith("Leaves")
        else:
            assert r["n"] == 0


VALIDATE = """
    import sys
    from pxr import Usd, UsdValidation
    if sys.argv[2] == "register":
        from bcfpipe.formats.usd_schema import register_shader_defs
        register_shader_defs()
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    errors = context.Validate(Usd.Stage.Open(sys.argv[1]))
    for e in errors:
        print(e.GetType(), e.GetName(), e.GetMessage())
    print("ERRORS", sum(1 for e in errors if e.GetType() == UsdValidation.ValidationErrorType.Error))
"""


def validate(root: Path, plugin: bool = True, route: str = "register") -> tuple[int, str]:
    """UsdValidation errors of a stage in a fresh process: with the schema plug-in and the Sdr node
    registered in-process (route "register") or by the environment alone ("env"), or with neither."""
    from bcfpipe.formats.usd_schema import shader_discovery_env

    env = {k: v for k, v in os.environ.items() if not k.startswith("PXR_SDR_FS_")}
    if plugin:
        env["PXR_PLUGINPATH_NAME"] = str(SCHEMAS)
        if route == "env":
            env.update(shader_discovery_env())
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(VALIDATE), str(root), route if plugin else "none"],
                          capture_output=True, text=True, env=env, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return int(proc.stdout.rsplit("ERRORS", 1)[1]), proc.stdout


@pytest.mark.parametrize("route", ["register", "env"])
def test_validation(sample, route) -> None:
    """0 UsdValidation errors with the schema and the Sdr node registered, in-process or by the
    environment alone (every built material has a bcf render-context surface on a
    BcfNeuralMaterial shader)."""
    scene, result = sample
    n, text = validate(result.root_layer, route=route)
    assert n == 0, text


BINDINGS = """
    import json, sys
    from pxr import Usd, UsdGeom, UsdShade
    out = {}
    for path in sys.argv[1:]:
        stage = Usd.Stage.Open(path)
        meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
        bound = {str(p.GetPath()): str(UsdShade.MaterialBindingAPI(p).ComputeBoundMaterial()[0].GetPath())
                 for p in meshes}
        surfaces = {}
        for m in {v for v in bound.values() if v != "."}:
            mat = UsdShade.Material(stage.GetPrimAtPath(m))
            default, bcf = mat.ComputeSurfaceSource(), mat.ComputeSurfaceSource("bcf")
            surfaces[m] = [str(default[0].GetPath()) if default[0] else None,
                           str(bcf[0].GetPath()) if bcf[0] else None]
        out[path] = {"bound": bound, "surfaces": surfaces}
    print(json.dumps(out))
"""


def test_without_the_plugins_bindings_and_surfaces_are_the_inputs(sample) -> None:
    """With neither the schema nor the Sdr node registered the built stage opens, every mesh is
    bound to the same material as in the input, and every renderer's default surface is the
    original UsdPreviewSurface; only the bcf render context sees the BcfNeuralMaterial shader."""
    scene, result = sample
    proc = subprocess.run([sys.executable, "-c", textwrap.dedent(BINDINGS), str(scene), str(result.root_layer)],
                          capture_output=True, text=True, env=dict(os.environ), timeout=600)
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    src, built = r[str(scene)], r[str(result.root_layer)]
    assert built["bound"] == src["bound"] and len(src["bound"]) >= 4
    built_paths = {m.path for m in result.manifest.materials if m.status == "built"}
    for mat, (default, bcf) in built["surfaces"].items():
        assert default == src["surfaces"][mat][0]  # the original network, untouched
        assert bcf == (f"{mat}/BcfSurface" if mat in built_paths else default)


def dependencies(root: Path) -> tuple[list[str], list[str], list[str]]:
    from pxr import UsdUtils

    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(str(root))
    return [lyr.realPath for lyr in layers], [str(a) for a in assets], [str(u) for u in unresolved]


def test_dependencies(sample) -> None:
    scene, result = sample
    layers, assets, unresolved = dependencies(result.root_layer)
    assert unresolved == []
    out = result.out.resolve()
    want = {str(out / "weights.bin")} | {str(p.resolve()) for p in out.glob("materials/*/T?.dds")}
    assert len(want) == 1 + 4 * 3
    assert want <= {str(Path(a).resolve()) for a in assets}
    assert str(scene.resolve()) in {str(Path(p).resolve()) for p in layers}


def test_relocation(sample, tmp_path: Path) -> None:
    scene, result = sample
    moved = tmp_path / "elsewhere" / "deeper"
    shutil.copytree(scene.parent, moved)
    root = moved / "sample_scene.bcf" / root_layer_name(scene)
    layers, assets, unresolved = dependencies(root)
    assert unresolved == []
    assert all(Path(p).is_relative_to(moved) for p in layers + assets), (layers, assets)
    assert all(Path(a).exists() for a in assets)
    stage = Usd.Stage.Open(str(root))
    attr = stage.GetPrimAtPath("/World/Looks/Bricks").GetAttribute("bcf:featureTextures")
    resolved = [a.resolvedPath for a in attr.Get()]
    assert all(r and Path(r).is_relative_to(moved) and Path(r).exists() for r in resolved), resolved


def test_deterministic(sample, tmp_path: Path) -> None:
    """The same job and seed (and thread count) give byte-identical exported files. In the default
    suite (about 20 s): as a slow test it went stale unseen."""
    from bcfpipe.builder import run_job
    from bcfpipe.config import DEFAULT_THREADS

    scene, result = sample
    job = result.plan.job("Leaves")
    r = run_job(job.to_dict(), str(tmp_path / "Leaves"), DEFAULT_THREADS, "cpu")  # the build's default
    assert r["status"] == "built", r
    for f in ("T0.dds", "T1.dds", "T2.dds", "T3.dds", "weights.bin", "decoder.onnx"):
        assert (tmp_path / "Leaves" / f).read_bytes() == (result.out / "materials" / "Leaves" / f).read_bytes(), f


# ---------------------------------------------------------------------------------------------
# planning (no training)


def test_plan_jobs_are_json_and_content_hashed(tmp_path: Path) -> None:
    a = copy_samples(tmp_path / "a")
    b = copy_samples(tmp_path / "b")
    pa, pb = plan(a, **FAST), plan(b, **FAST)
    assert [j.content_hash for j in pa.jobs] == [j.content_hash for j in pb.jobs]  # paths do not matter
    for job in pa.jobs:
        assert MaterialJob.from_dict(json.loads(json.dumps(job.to_dict()))) == job
    json.dumps(pa.to_dict())
    assert plan(a, TrainingOptions(profile="tiny", preset="draft", seed=1)).jobs[0].content_hash != \
        pa.jobs[0].content_hash
    # --all-materials adds the unbound material
    names = [m.path for m in plan(a, selection=Selection(all_materials=True), **FAST).materials if m.decision == "model"]
    assert "/World/Looks/Unused" in names


@pytest.mark.parametrize("name,default,other,refused,why", [
    ("t0", None, "trained", {"t0": "pca", "features": "bc6h"}, "use it with --features bc7"),
    ("kernel", "auto", "torch", {"kernel": "fused", "device": "cuda"}, "runs on the CPU"),
])
def test_an_option_keys_the_cache_and_reaches_the_job(tmp_path: Path, name, default, other, refused, why) -> None:
    """--t0 trained and --kernel torch change what trains, so every key changes and each job's record
    holds them; naming the default keys the same jobs. A bad value is refused with one line."""
    a = copy_samples(tmp_path / "a")
    opts = TrainingOptions(profile="tiny", preset="smoke", seed=0)
    p0, p0b, p1 = plan(a, opts), plan(a, opts.with_(**{name: default})), plan(a, opts.with_(**{name: other}))
    assert [j.content_hash for j in p0.jobs] == [j.content_hash for j in p0b.jobs]
    assert not {j.content_hash for j in p0.jobs} & {j.content_hash for j in p1.jobs}
    assert getattr(p1.jobs[0].options, name) == other and getattr(p0.jobs[0].options, name) != other
    with pytest.raises(InputError, match=why):
        TrainingOptions(**refused)


def test_the_feature_format_keys_the_job_and_picks_t0(tmp_path: Path) -> None:
    """Every job records its feature format; bc7's T_0 holds principal components, bc6h's is
    trained. A bad value is refused."""
    a = copy_samples(tmp_path / "a")
    opts = TrainingOptions(profile="tiny", preset="smoke", seed=0)
    p7, p6 = plan(a, opts), plan(a, opts.with_(features="bc6h"))
    assert not {j.content_hash for j in p7.jobs} & {j.content_hash for j in p6.jobs}
    assert p7.jobs[0].options.features == "bc7" and p6.jobs[0].options.features == "bc6h"
    assert p7.jobs[0].options.t0_resolved == "pca" and p6.jobs[0].options.t0_resolved == "trained"
    with pytest.raises(InputError, match="unknown feature format"):
        TrainingOptions(features="bc9")


def test_a_kernel_named_keys_what_it_runs(tmp_path: Path) -> None:
    """--kernel auto runs fused on the CPU: naming fused there trains, keys and records the same job
    as the default; auto resolves to torch on CUDA, fused is refused there."""
    from bcfpipe.formats.vocabulary import Kernel

    a = copy_samples(tmp_path / "a")
    opts = TrainingOptions(profile="tiny", preset="smoke", seed=0, device="cpu")
    assert [j.content_hash for j in plan(a, opts).jobs] == [j.content_hash for j in plan(a, opts.with_(kernel="fused")).jobs]
    assert Kernel.AUTO.on("cpu") == Kernel.FUSED and Kernel.AUTO.on("cuda:0") == Kernel.TORCH
    assert opts.train_config(64, "repeat", "cpu")[1].kernel == Kernel.FUSED
    assert opts.train_config(64, "repeat", "cuda")[1].kernel == Kernel.TORCH
    assert opts.with_(kernel="torch").train_config(64, "repeat", "cpu")[1].kernel == Kernel.TORCH


def test_a_fixed_t0_trains_a_longer_draft_except_at_2k_on_a_cpu() -> None:
    """bc7's fixed T_0 trains FIXED_T0_PRESETS' draft (T_1..T_3 only, 3x the steps); bc6h, a 2048² T_0
    on a CPU (30 s for a 2K material) and the other presets train PRESETS."""
    from bcfpipe import config

    draft = TrainingOptions(preset="draft", device="cpu", layout="neural")
    assert draft.train_config(1024, "repeat", "cpu")[1].preset is config.FIXED_T0_PRESETS["draft"]
    assert draft.with_(features="bc6h").train_config(1024, "repeat", "cpu")[1].preset is config.PRESETS["draft"]
    assert draft.with_(t0="trained").train_config(1024, "repeat", "cpu")[1].preset is config.PRESETS["draft"]
    assert draft.with_(profile="2k").train_config(2048, "repeat", "cpu")[1].preset is config.PRESETS["draft"]
    assert draft.with_(profile="2k").train_config(2048, "repeat", "cuda:0")[1].preset is config.FIXED_T0_PRESETS["draft"]
    assert config.preset_for("fast", 1024, "cpu", True) is config.PRESETS["fast"]


def test_cpu_presets_take_fewer_steps_at_2k_and_the_key_follows(tmp_path: Path, monkeypatch) -> None:
    """Issue 30's limits for a 2K material: on a CPU, standard trains CPU_PRESETS_LARGE at a 2048²
    T_0; CUDA, smaller profiles and the other presets (fast fits at full steps) train PRESETS. The
    cache key holds the schedule a job trains."""
    from bcfpipe import config

    assert config.preset_for("standard", 2048, "cpu") is config.CPU_PRESETS_LARGE["standard"]
    assert config.preset_for("fast", 2048, "cpu") is config.PRESETS["fast"]
    assert config.preset_for("standard", 1024, "cpu") is config.PRESETS["standard"]
    assert config.preset_for("standard", 2048, "cuda:0") is config.PRESETS["standard"]
    assert config.preset_for("draft", 2048, "cpu") is config.PRESETS["draft"]
    big = TrainingOptions(profile="2k", device="cpu", layout="neural")
    assert big.train_config(2048, "repeat", "cpu")[1].preset == config.CPU_PRESETS_LARGE["standard"]
    assert big.train_config(2048, "repeat", "cuda:0")[1].preset == config.PRESETS["standard"]
    a = copy_samples(tmp_path / "a")

    def keys(o):
        return [j.content_hash for j in plan(a, o).jobs]

    k2, k1 = keys(big), keys(big.with_(profile="1k"))
    monkeypatch.setitem(config.CPU_PRESETS_LARGE, "standard", config.PRESETS["fast"])
    assert keys(big) != k2 and keys(big.with_(profile="1k")) == k1


def test_plan_channel_mapping(tmp_path: Path) -> None:
    write_png(tmp_path / "tex" / "color.png", pattern())
    write_png(tmp_path / "tex" / "normal.png", pattern(seed=1))
    write_png(tmp_path / "tex" / "grey.png", pattern(c=1, seed=5)[..., 0])  # not a copy of a colour channel
    stage = new_stage(tmp_path / "scene.usda")
    clamp = {"wrapS": "clamp", "wrapT": "clamp"}
    add_material(stage, "/World/Looks/M", {
        "diffuseColor": ("./tex/color.png", "rgb", clamp),
        "emissiveColor": ("./tex/color.png", "rgb", {**clamp, "scale": (2.0, 2.0, 2.0, 1.0)}),
        "opacity": ("./tex/color.png", "r", clamp),
        "normal": ("./tex/normal.png", "rgb", {**clamp, "sourceColorSpace": "raw"}),  # scale 1 / bias 0
        "roughness": ("./tex/grey.png", "r", clamp),
    }, mesh="/World/Mesh")
    stage.Save()
    p = plan(tmp_path / "scene.usda", **FAST)
    (job,) = p.jobs
    assert job.wrap == ("clamp", "clamp")
    # color.png rgb read once for diffuse, emissive and opacity; normal x, y; grey r
    assert [(Path(c.file).name, c.channel, c.kind) for c in job.channels] == [
        ("color.png", "r", "value"), ("color.png", "g", "value"), ("color.png", "b", "value"),
        ("grey.png", "r", "value"), ("normal.png", "r", "normal"), ("normal.png", "g", "normal")]
    (m,) = [m for m in p.materials if m.decision == "model"]
    t = {x.target: x for x in m.targets}
    assert t["diffuseColor.g"].channel == t["emissiveColor.g"].channel == 1
    assert t["emissiveColor.r"].scale == 2.0 and t["diffuseColor.r"].color_space == "sRGB"  # auto, 8-bit RGB
    assert t["opacity"].channel == 0
    assert (t["normal.x"].scale, t["normal.x"].bias, t["normal.x"].channel) == (0.5, 0.5, 4)
    assert (t["normal.z"].channel, t["roughness"].channel) == (6, 3)
    assert t["roughness"].color_space == "raw"  # auto on a 1-channel file


@pytest.mark.shared
def test_plan_packaged_textures(tmp_path: Path) -> None:
    """Textures inside a usdz are hashed through Ar and copied out for the loader."""
    from bcfpipe.scan.sources import local_file
    from bcfpipe.texset.texture_set import TextureSpec, load_texture_set

    scene = SCENES / "usdwg_roughness_test" / "RoughnessTest.usdz"
    if not scene.exists():
        pytest.skip(f"needs {scene}")
    p = plan(scene, **FAST)
    assert p.jobs and all(m.reason != "failed" for m in p.materials)
    job = p.jobs[0]
    assert all("[" in s.path and s.width > 0 and len(s.xxh3_128) == 32 for s in job.sources)
    ts = load_texture_set([TextureSpec(sem, local_file(path, tmp_path), ch) for sem, path, ch in job.specs])
    assert ts.num_channels == len(job.channels)


# ---------------------------------------------------------------------------------------------
# failures, dedup, --json, OUT handling


def test_damaged_source_is_refused_before_training_then_dedup_and_json(tmp_path: Path) -> None:
    """A damaged texture is the user's to fix: the build refuses it by name (exit 2, one line),
    writes nothing, and trains nothing. Without it, materials sharing a set train once."""
    import jsonschema

    write_png(tmp_path / "tex" / "a.png", pattern())
    write_png(tmp_path / "tex" / "r.png", pattern(c=1, seed=3)[..., 0])
    (tmp_path / "tex" / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n this is not a png")
    stage = new_stage(tmp_path / "scene.usda")
    good = {"diffuseColor": ("./tex/a.png", "rgb", {}), "roughness": ("./tex/r.png", "r", {})}
    add_material(stage, "/World/Looks/Good", good, mesh="/World/A")
    add_material(stage, "/World/Looks/Twin", good, mesh="/World/B")
    add_material(stage, "/World/Looks/Broken", {"diffuseColor": ("./tex/broken.png", "rgb", {})}, mesh="/World/C")
    stage.Save()
    out = tmp_path / "out"
    args = [sys.executable, "-m", "bcfpipe", "build", str(tmp_path / "scene.usda"), "-o", str(out),
            "--profile", "tiny", "--quality", "smoke", "--layout", "neural", "--jobs", "2", "--threads", "1", "--json"]
    proc = subprocess.run(args, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == "" and "Traceback" not in proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("Error: ") and str(tmp_path / "tex" / "broken.png") in line
    assert not out.exists()

    stage.RemovePrim("/World/Looks/Broken")
    stage.RemovePrim("/World/C")
    stage.Save()
    proc = subprocess.run(args, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)  # stdout is the JSON report and nothing else
    jsonschema.validate(report, json.loads((SCHEMAS / "report.schema.json").read_text()))
    status = {m["path"].rsplit("/", 1)[-1]: m for m in report["materials"]}
    assert status["Good"]["status"] == status["Twin"]["status"] == "built"
    assert status["Good"]["cache"] == status["Twin"]["cache"] == "miss"
    assert status["Good"]["job"] == status["Twin"]["job"] and report["totals"]["jobs"] == 1
    assert report["exit_code"] == 0
    assert "materials/Good/T0.dds" in status["Good"]["files"] and status["Good"]["psnr"] > 10
    n, text = validate(out / "scene.bcf.usda")
    assert n == 0, text
    assert not list(out.glob(".bcfpipe-staging*")) and not list(tmp_path.glob(".out*")), "no staging folders left behind"


def test_refuses_foreign_out(tmp_path: Path) -> None:
    scene = constant_stage(tmp_path / "scene.usda")
    out = tmp_path / "precious"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(BuildError, match="--force"):
        build(scene, out, **FAST)
    assert (out / "notes.txt").read_text() == "mine"
    # not even with --force: only a folder holding bcfpipe's manifest is ever replaced
    (out / "sub").mkdir()
    (out / "sub" / "scene.usd").write_bytes(b"#usda 1.0\n")
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    for force in ([], ["--force"]):
        proc = run_cli("build", scene, "-o", out, *force)
        assert proc.returncode == 2 and "not written by bcfpipe" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
        assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    with pytest.raises(BuildError, match="even with --force"):
        build(scene, out, execution=Execution(force=True), **FAST)
    assert {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    out = tmp_path / "built"
    result = build(scene, out, **FAST)
    assert result.exit_code == 0 and (out / MANIFEST).exists()
    # a bcfpipe output of the same scene is replaced without --force
    again = build(scene, out, **FAST)
    assert again.exit_code == 0 and again.manifest.to_json()["totals"]["skipped"] == 1
    # another scene's build is replaced only with --force, and a line names the scene it replaces
    (tmp_path / "other").mkdir()
    other = constant_stage(tmp_path / "other" / "b.usda")
    with pytest.raises(BuildError, match=r"another scene .*scene\.usda.*--force"):
        build(other, out, **FAST)
    assert json.loads((out / MANIFEST).read_text())["scene"].endswith("scene.usda")
    proc = run_cli("build", other, "-o", out, "--force")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count(f"replacing the build of {scene}") == 1  # said once, not per check
    assert json.loads((out / MANIFEST).read_text())["scene"].endswith("b.usda")
    # an OUT containing the input is refused even with --force
    with pytest.raises(BuildError, match="contains the input"):
        build(scene, tmp_path, execution=Execution(force=True), **FAST)
    assert scene.exists()


def test_default_out_and_constant_only(tmp_path: Path) -> None:
    scene = constant_stage(tmp_path / "scene.usda")
    result = build(scene, **FAST)
    assert result.out == tmp_path / "scene.bcf" and result.root_layer == tmp_path / "scene.bcf" / "scene.bcf.usda"
    (m,) = result.manifest.to_json()["materials"]
    assert (m["status"], m["reason"]) == ("skipped", "no-textures")
    assert result.manifest.to_json()["totals"]["trained"] == 0
    data, entries = weightsbuf.read(result.out / "weights.bin")
    assert entries == [] and len(data) == 16
    n, text = validate(result.root_layer)
    assert n == 0, text


def test_bad_variant_and_missing_scene(tmp_path: Path) -> None:
    with pytest.raises(BuildError, match="no such file"):
        build(tmp_path / "nope.usda", **FAST)
    scene = constant_stage(tmp_path / "scene.usda")
    with pytest.raises(BuildError):
        build(scene, selection=Selection(variants=["novalue"]), **FAST)


def test_plain_progress_lines() -> None:
    from rich.console import Console

    buf = io.StringIO()
    display = BuildDisplay(Console(file=buf, width=200), live=False)
    with display:
        display(ProgressEvent(**{"event": "queued", "job": "A", "materials": ["/W/A"]}))
        display(ProgressEvent(**{"event": "progress", "job": "A", "phase": "warmup", "step": 50, "steps": 200, "psnr": 20.0,
                 "eta": 10.0}))
        display(ProgressEvent(**{"event": "progress", "job": "A", "phase": "warmup", "step": 100, "steps": 200, "psnr": 21.0,
                 "eta": 8.0}))
        display(ProgressEvent(**{"event": "done", "job": "A", "status": "built", "psnr": 30.5, "seconds": 12.0}))
    lines = buf.getvalue().splitlines()
    assert len(lines) == 2 and "A: warmup" in lines[0] and "PSNR 30.50" in lines[1]
    assert "[1/1: 1 trained, 0 cached, 0 failed; 0 running, 0 queued]" in lines[1]


def test_plain_progress_at_least_every_10_seconds() -> None:
    """Plain lines on a fake clock, ticked once a second as the Ticker does, through two texture
    sets: A's phases come with events (some shorter than a second), B sits 40 s in one call
    without any. A line comes at least every LINE_SECONDS + TICK_SECONDS (under 10 s), also
    before the jobs are known and after they end; no texture set prints two lines within a
    second before its end; every phase is named but those of the last second before an end."""
    import re

    from rich.console import Console

    from bcfpipe.train.pace import LINE_SECONDS, TICK_SECONDS

    def ev(job, kind="progress", **kw):
        return ProgressEvent(**{"event": kind, "job": job, **kw})

    events: dict[float, list] = {12.0: [ev("A", "queued"), ev("B", "queued")], 14.0: [ev("A", phase="load")],
                                 14.25: [ev("B", phase="load")], 15.0: [ev("A", phase="warmup", step=1, steps=100)],
                                 15.5: [ev("B", phase="warmup", step=1, steps=100, psnr=20.0, eta=80.0)],
                                 15.75: [ev("A", phase="encode", step=0, steps=8)],
                                 16.0: [ev("A", phase="encode", step=8, steps=8)],
                                 55.0: [ev("B", phase="encode", step=8, steps=8)],
                                 62.0: [ev("B", "done", status="built", psnr=30.0, seconds=48.0)]}
    for k in range(1, 120):  # A's constrained phase: a report every 0.25 s
        events.setdefault(16.0 + 0.25 * k, []).append(ev("A", phase="constrained", step=5 * k, steps=600, psnr=25.0,
                                                         eta=40.0))
    events[46.25] = [ev("A", phase="quantize")]
    events[46.5] = [ev("A", phase="finetune", step=1, steps=50)]
    events[47.0] = [ev("A", phase="evaluate")]
    events[47.25] = [ev("A", "done", status="built", psnr=31.0, seconds=33.0)]
    now = [0.0]
    buf = io.StringIO()
    display = BuildDisplay(Console(file=buf, width=300), live=False, clock=lambda: now[0])
    end = 80.0
    for i in range(int(end / 0.25) + 1):
        now[0] = 0.25 * i
        for e in events.get(now[0], []):
            display(e)
        if now[0] % TICK_SECONDS == 0:
            display.tick()
    lines = [(float(m.group(1)), m.group(2)) for m in (re.match(r"\[\s*([\d.]+)s\] \[[^]]*\] (.*)", ln)
                                                        for ln in buf.getvalue().splitlines())]
    times = [0.0] + [t for t, _ in lines] + [end]
    assert max(np.diff(times)) <= LINE_SECONDS + TICK_SECONDS < 10, lines
    for job in "AB":
        mine = [t for t, text in lines if text.startswith(f"{job}: ") and "built in" not in text]
        assert min(np.diff(mine)) >= TICK_SECONDS, (job, lines)
    texts = [text for _, text in lines]
    assert texts[0] == "planning" and texts[-1] == "writing the results"
    named = {ph for text in texts if text.startswith("A: ") and "in this phase" not in text and "built" not in text
             for ph in text[3:].split(", ")}
    assert named == {"load", "warmup", "encode", "constrained", "quantize"}  # not the last second's
    assert "B: warmup" in texts and "B: encode" in texts
    assert any(t.startswith("B: warmup 1/100, ") and "s in this phase, batch PSNR 20.00 dB, ETA 80s" in t
               for t in texts), "\n".join(texts)


def test_progress_counts_every_state() -> None:
    """queued, running, trained, cached and failed are counted (the live title and the plain lines)."""
    from rich.console import Console

    display = BuildDisplay(Console(file=io.StringIO(), width=200), live=False)
    display(ProgressEvent(**{"event": "done", "job": "C", "status": "built", "cache": "hit", "psnr": 31.0, "seconds": 0.0}))
    for name in "ABDE":
        display(ProgressEvent(**{"event": "queued", "job": name, "materials": [f"/W/{name}"]}))
    display(ProgressEvent(**{"event": "progress", "job": "A", "phase": "warmup", "step": 1, "steps": 9}))
    display(ProgressEvent(**{"event": "progress", "job": "B", "phase": "warmup", "step": 1, "steps": 9}))
    display(ProgressEvent(**{"event": "done", "job": "B", "status": "built", "psnr": 30.0, "seconds": 3.0}))
    display(ProgressEvent(**{"event": "done", "job": "D", "status": "failed", "reason": "worker process died"}))
    display(ProgressEvent(**{"event": "progress", "job": "B", "phase": "finetune", "step": 9, "steps": 9}))  # late: ignored
    assert display.counts() == {"queued": 1, "running": 1, "done": 1, "cached": 1, "failed": 1}
    assert display.table().title.endswith("3/5: 1 trained, 1 cached, 1 failed; 1 running, 1 queued")


def test_schema_helper() -> None:
    from bcfpipe.formats import usd_schema as schema

    d = schema.schema_dir()
    assert {"plugInfo.json", "generatedSchema.usda", "schema.usda"} <= {p.name for p in d.iterdir()}
    assert str(d) in schema.plugin_path_env("")
    proc = run_py("""
        from bcfpipe.formats import usd_schema as schema
        assert schema.register() and schema.is_registered()
        from pxr import Usd, UsdShade
        stage = Usd.Stage.CreateInMemory()
        prim = UsdShade.Material.Define(stage, "/M").GetPrim()
        assert prim.CanApplyAPI(schema.SCHEMA)
        prim.ApplyAPI(schema.SCHEMA)
        assert prim.GetAttribute("bcf:mlp:precision").Get() == "fp16"
        assert not stage.DefinePrim("/X", "Xform").CanApplyAPI(schema.SCHEMA)
        print("ok")
    """, plugin=False)
    assert proc.stdout.strip() == "ok", proc.stderr


# ---------------------------------------------------------------------------------------------
# the teapot


@pytest.mark.slow
@pytest.mark.shared
def test_teapot_fancy(tmp_path: Path) -> None:
    scene = SCENES / "usdwg_teapot" / "Teapot.usd"
    if not scene.exists():
        pytest.skip(f"needs {scene}")
    out = tmp_path / "Teapot.bcf"
    result = build(scene, out, selection=Selection(variants={"modelVariant": "Fancy"}), training=TrainingOptions(preset="draft"))
    assert result.exit_code == 0
    mats = {m["path"]: m for m in result.manifest.to_json()["materials"]}
    fancy = mats["/Teapot/Materials/PorcelainFlowers"]
    assert fancy["status"] == "built" and fancy["profile"] == "2k"
    assert mats["/Teapot/Materials/Ceramic"]["status"] == "skipped"
    n, text = validate(result.root_layer)
    assert n == 0, text
    layers, assets, unresolved = dependencies(result.root_layer)
    assert unresolved == []
    assert {str(p.resolve()) for p in out.glob("materials/*/T?.dds")} | {str(out / "weights.bin")} <= set(assets)
    overrides = (out / "overrides.usda").read_text()
    assert 'string modelVariant = "Fancy"' in overrides


@pytest.mark.gl
def test_verify_passes_on_the_sample_build(sample) -> None:
    """`bcfpipe verify` on a real (tiny) build: GLSL through OpenGL against ONNX, every material."""
    from bcfpipe.verify import checks as V

    scene, result = sample
    try:
        report = V.verify(result.out)
    except V.VerifyInputError as e:  # no EGL/OpenGL on this machine
        pytest.skip(f"no OpenGL: {e}")
    assert report.exit_code == 0, report.to_dict()
    built = [m.path for m in result.manifest.materials if m.status == "built"]
    assert [m.name for m in report.materials] == built and all(m.passed for m in report.materials)


def test_size_estimate_equals_a_real_build(sample) -> None:
    """The one byte estimator (formats/sizes.py: `scan`'s estimate, rate control's and the layout
    rule's sizes) is the bytes a build writes per material: its four DDS files and its weight record."""
    from bcfpipe.formats import material as mf
    from bcfpipe.formats.sizes import neural_bytes

    _, result = sample
    for job in result.manifest.to_json()["jobs"]:
        folder = result.out / "materials" / job["name"]
        desc = mf.read(folder)
        written = sum((folder / layer.file).stat().st_size for layer in desc.layers)
        written += (folder / desc.mlp.weights).stat().st_size
        assert neural_bytes(tuple(layer.resolution for layer in desc.layers), desc.mlp.n_in,
                            desc.mlp.n_hidden, desc.mlp.n_out) == written, job["name"]


@pytest.mark.parametrize("width", [160, 40])
def test_summary_never_breaks_a_path(sample, width: int) -> None:
    """The end-of-run summary is a table when the console holds the longest path and the other
    columns, else one block per material; either way every material path is on one line, whole,
    with its status and PSNR."""
    from rich.console import Console

    from bcfpipe.builder.report import headline_psnr
    from bcfpipe.cli.build import print_summary

    _, result = sample
    buf = io.StringIO()
    print_summary(Console(file=buf, width=width, color_system=None), result.manifest, result.report)
    lines = buf.getvalue().splitlines()
    starts = [i for i, text in enumerate(lines) if re.search(r"(^|│ )/World/", text)]
    for m in result.manifest.materials:
        (line,) = [i for i in starts if re.search(re.escape(m.path) + r"(\s|$)", lines[i])]
        end = min([i for i in starts if i > line] + [len(lines)])
        block = " ".join(lines[line:end])
        assert m.status in block
        if headline_psnr(m) is not None:
            assert f"{headline_psnr(m):.2f}" in block
    assert ("┃ material" in buf.getvalue()) == (width == 160)
