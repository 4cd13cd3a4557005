"""The file contract (bcfpipe.formats): records read and write material.json / manifest.json, the
published schemas are what the records generate, and bad files are refused naming the key."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf
from bcfpipe.formats import schema
from bcfpipe.formats.record import FormatError
from bcfpipe.resources import GLSL_DIR, SCHEMA_DIR



def _material() -> mf.MaterialFile:
    layers = tuple(mf.Layer(mf.layer_file(i), 64 >> i, 5 - i, -float(i)) for i in range(4))
    return mf.MaterialFile(
        layers=layers, bc6h=mf.BC6H(95, False, "11110 (two regions, 6-bit endpoints, 3-bit indices)"),
        sampling=mf.Sampling("repeat"), reference=mf.Reference(64, 32, 7),
        mlp=mf.Mlp("weights.bin", 0, 100, 12, 16, 2, "relu", "fp16", "BCFW v1", tuple(f"T{i}.{c}" for i in range(4)
                                                                                     for c in "rgb"),
                   (1.0, 1.0), (0.0, 0.5)),
        outputs=(mf.Output("roughness.r", "roughness", "r", "scalar", "roughness", (0.0, 1.0), 0, "uint8", False),
                 mf.Output("metallic.r", "metallic", "r", "scalar", "metallic", (0.0, 1.0), 0, "uint16", False)),
        onnx=mf.Onnx("decoder.onnx", "features", "channels", 17),
        training=mf.Training((64, 32, 16, 8), "draft", 0, "cpu"))


@pytest.mark.parametrize("name", sorted(schema.SCHEMAS))
def test_published_schemas_are_generated(name):
    """bcfpipe/schemas/*.schema.json (what the package ships) are exactly what the records generate (regenerate with
    `python -m bcfpipe.formats.schema`), every key has a description, and they are valid schemas."""
    import jsonschema

    text = (SCHEMA_DIR / name).read_text()
    assert text == schema.render(name), f"bcfpipe/schemas/{name} is stale: run python -m bcfpipe.formats.schema"
    s = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(s)
    for obj in [s, *s["$defs"].values()]:
        assert obj["description"] and all(p["description"] for p in obj["properties"].values())


def test_material_round_trip_and_schema(tmp_path):
    import jsonschema

    m = _material()
    mf.write(tmp_path, m)
    data = json.loads((tmp_path / mf.FILE).read_text())
    assert list(data)[:3] == ["format", "format_version", "bcfpipe_version"]
    assert "sha256" not in data  # optional keys are left out, not null
    jsonschema.validate(data, json.loads(schema.render("material.schema.json")))
    back = mf.read(tmp_path)
    assert back == m and back.kinds == ("scalar", "scalar") and back.normal_index == -1


def test_per_axis_addressing_is_version_7_and_one_mode_stays_as_before(tmp_path):
    """sampling: ``addressing`` while both axes repeat or both clamp (the version, and the bytes, as
    before issue 57); ``wrap_s`` / ``wrap_t`` (version 7) where they differ or one mirrors; both read
    back as the (S, T) pair, valid against the schema; a sampling with neither, or with a mode
    nobody knows, is refused in one line."""
    import dataclasses

    import jsonschema

    for wrap, written, version in [("clamp", {"addressing": "clamp"}, mf.NO_SPLIT_VERSION),
                                   (("clamp", "repeat"), {"wrap_s": "clamp", "wrap_t": "repeat"}, 7),
                                   ("mirror", {"wrap_s": "mirror", "wrap_t": "mirror"}, 7)]:
        m = dataclasses.replace(_material(), sampling=mf.Sampling.of(wrap))
        mf.write(tmp_path, m)
        data = json.loads((tmp_path / mf.FILE).read_text())
        assert {k: v for k, v in data["sampling"].items() if k in ("addressing", "wrap_s", "wrap_t")} == written
        assert data["format_version"] == version == mf.read(tmp_path).format_version
        jsonschema.validate(data, json.loads(schema.render("material.schema.json")))
        assert mf.read(tmp_path).wrap == ((wrap, wrap) if isinstance(wrap, str) else wrap)
    for bad, message in [({"wrap_s": "clamp"}, "either 'addressing' or both"),
                         ({"addressing": "black"}, "unknown addressing 'black'")]:
        data["sampling"] = {**{k: v for k, v in data["sampling"].items() if k in ("filter", "uv", "lod")}, **bad}
        (tmp_path / mf.FILE).write_text(json.dumps(data))
        with pytest.raises(FormatError) as e:
            mf.read(tmp_path)
        assert message in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(extra=1), "unknown key 'extra'"),
    (lambda d: d["layers"][2].pop("lod_bias"), "material.json.layers[2]: missing key 'lod_bias'"),
    (lambda d: d["mlp"].update(n_hidden="16"), "material.json.mlp.n_hidden: expected an integer"),
    (lambda d: d["outputs"][0].update(range=[0.0]), "material.json.outputs[0].range: expected 2 items"),
    (lambda d: d.update(format="something-else"), "not a bcfpipe-material file"),
    (lambda d: d.update(format_version=99), f"version 99; this bcfpipe reads version {mf.FORMAT_VERSION}"),
])
def test_malformed_material_is_refused(tmp_path, edit, message):
    data = _material().to_json()
    edit(data)
    (tmp_path / mf.FILE).write_text(json.dumps(data))
    with pytest.raises(FormatError, match=message.replace("[", r"\[").replace("]", r"\]")):
        mf.read(tmp_path)


def test_unreadable_files_are_format_errors(tmp_path):
    with pytest.raises(FormatError, match="No such file"):
        mf.read(tmp_path)
    (tmp_path / mfst.FILE).write_text("{ not json")
    with pytest.raises(FormatError, match="not JSON"):
        mfst.read(tmp_path)
    assert FormatError("x").exit_code == 2


def test_minimal_manifest(tmp_path):
    """A manifest needs only its scene, root layer and materials; the rest has defaults, and what
    is written is complete (it passes the schema)."""
    import jsonschema

    m = mfst.Manifest(scene="s.usda", root_layer="s.bcf.usda",
                      materials=(mfst.Material("/World/M", "skipped", reason="unbound"),))
    mfst.write(tmp_path, m)
    data = json.loads((tmp_path / mfst.FILE).read_text())
    jsonschema.validate(data, json.loads(schema.render("manifest.schema.json")))
    assert mfst.is_manifest(tmp_path) and mfst.read(tmp_path) == m and m.failed() == []
    assert list(data["materials"][0])[:4] == ["path", "aliases", "job", "status"]
    assert "profile" not in data["materials"][0]


def test_version_4_and_5_manifests_are_read(tmp_path):
    """An OUT built by a previous version reads: version 4 (each material listing the others of its
    job), version 5 (options as a hand-picked subset of the job record)."""
    m = mfst.Manifest(scene="s.usda", root_layer="s.bcf.usda",
                      materials=(mfst.Material("/World/A", "built", job="A"), mfst.Material("/World/B", "built", job="A")))
    mfst.write(tmp_path, m)
    data = json.loads((tmp_path / mfst.FILE).read_text())
    data["format_version"] = 4
    data["materials"][0]["shared_with"] = ["/World/B"]
    data["materials"][1]["shared_with"] = ["/World/A"]
    (tmp_path / mfst.FILE).write_text(json.dumps(data))
    assert mfst.read(tmp_path).materials == m.materials
    data["format_version"] = mfst.FORMAT_VERSION
    (tmp_path / mfst.FILE).write_text(json.dumps(data))
    with pytest.raises(FormatError, match="shared_with"):
        mfst.read(tmp_path)
    data = json.loads((tmp_path / mfst.FILE).read_text())
    for mat in data["materials"]:
        del mat["shared_with"]
    data["format_version"], data["options"] = 5, {"profile": "1k", "preset": "standard", "seed": 0}
    (tmp_path / mfst.FILE).write_text(json.dumps(data))
    assert mfst.read(tmp_path).options["profile"] == "1k"


SDR_CHECK = """
import json, sys
from pxr import Sdf, Sdr, Usd, UsdGeom, UsdShade, UsdValidation
from bcfpipe.formats import usd_schema
if sys.argv[1] in ("register", "wrong-type", "both"):
    assert usd_schema.register_shader_defs() == ["BcfNeuralMaterial"]
    assert usd_schema.register_shader_defs() == ["BcfNeuralMaterial"]  # idempotent
stage = Usd.Stage.CreateInMemory()
UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
UsdGeom.SetStageMetersPerUnit(stage, 1.0)
mat = UsdShade.Material.Define(stage, "/M")
stage.SetDefaultPrim(mat.GetPrim())
bcf = UsdShade.Shader.Define(stage, "/M/BcfSurface")
bcf.CreateIdAttr("BcfNeuralMaterial")
bias_type = Sdf.ValueTypeNames.Int if sys.argv[1] == "wrong-type" else Sdf.ValueTypeNames.Float
bcf.CreateInput("lodBias1", bias_type).Set(2)
bcf.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("clamp")
bcf.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("mirror")
mat.CreateSurfaceOutput("bcf").ConnectToSource(bcf.ConnectableAPI(), "surface")
node = Sdr.Registry().GetShaderNodeByIdentifierAndType("BcfNeuralMaterial", "" if sys.argv[1] == "env" else "glsl")
validators = UsdValidation.ValidationRegistry().GetOrLoadAllValidators()
errors = [e for e in UsdValidation.ValidationContext(validators).Validate(stage)
          if e.GetType() == UsdValidation.ValidationErrorType.Error]
print(json.dumps({"node": bool(node and node.IsValid()),
                  "impl": node.GetResolvedImplementationURI() if node else None,
                  "outputs": list(node.GetShaderOutputNames()) if node else [],
                  "errors": [e.GetName() + ": " + e.GetMessage() for e in errors]}))
"""


@pytest.mark.parametrize("case", ["register", "env", "both", "none", "wrong-type"])
def test_shader_definition_in_sdr(case):
    """The BcfNeuralMaterial node of bcfpipe/schemas/shaders/BcfNeuralMaterial.usda: registered in-process
    (register), through the environment alone by Sdr's filesystem discovery (env), or both, it is a
    valid Sdr node whose implementation is the package's glsl/bcf_decode.glsl, and a material's bcf
    render-context output connected to it passes UsdValidation, which checks input types against it
    (an int lod bias is an error); unregistered, UsdValidation reports the unknown shader."""
    import os
    import subprocess
    import sys

    from bcfpipe.formats.usd_schema import shader_discovery_env

    env = {k: v for k, v in os.environ.items() if not k.startswith("PXR_SDR_FS_")}
    if case in ("env", "both"):
        env.update(shader_discovery_env())
    p = subprocess.run([sys.executable, "-c", SDR_CHECK, case], capture_output=True, text=True, timeout=300,
                       env=env, cwd="/")
    register = case in ("register", "env", "both")
    assert p.returncode == 0, p.stderr[-3000:]
    r = json.loads(p.stdout.strip().splitlines()[-1])
    if register:
        assert r["node"] and Path(r["impl"]).resolve() == GLSL_DIR / "bcf_decode.glsl"
        assert {"surface", "diffuseColor", "normal", "roughness", "metallic", "occlusion"} <= set(r["outputs"])
        assert r["errors"] == [], r["errors"]
    elif case == "none":
        assert not r["node"] and any("BcfNeuralMaterial" in e for e in r["errors"]), r["errors"]
    else:
        assert r["node"] and any("lodBias1" in e for e in r["errors"]), r["errors"]


def test_version_2_material_reads_as_every_output_from_the_mlp(tmp_path):
    """material.json format 2 (before layouts) still reads: no classic textures, every output the
    decoder's; it is upgraded to the record of version 3 (4 is for mip splits only)."""
    data = _material().to_json()
    data["format_version"] = 2
    (tmp_path / mf.FILE).write_text(json.dumps(data))
    d = mf.read(tmp_path)
    assert d.format_version == mf.NO_SPLIT_VERSION == 3 and d.neural and not d.mixed and not d.classic
    assert [o.name for o in d.mlp_outputs] == ["roughness.r", "metallic.r"]


def test_outputs_from_classic_textures_must_name_one(tmp_path):
    data = _material().to_json()
    data["outputs"][1].update(source="classic", texture=0, texel_channel=0, texel_scale=1.0, texel_bias=0.0)
    (tmp_path / mf.FILE).write_text(json.dumps(data))
    with pytest.raises(FormatError, match="output metallic.r names no classic texture"):
        mf.read(tmp_path)
