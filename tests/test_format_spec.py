"""docs/format.md's reference decoder, run as printed there, against `bcfpipe decode` (issue 60).

Trained materials (64², tiny profile, smoke preset, about 2 s each), each with an albedo, a normal
map, an HDR emissive (record v2) and a roughness, 9 channels: 4, 5 and 6 BC7 layers (a T_0 of 1 to 3 layers of principal
components; the 5-layer one clamps along u and mirrors along v) and 4 BC6H layers. The layers are
read by OpenImageIO through the doc's own snippet, not by bcfpipe. Compared on `bcfpipe decode`'s
grid (the images it writes, in source units) at several lods, and at points far outside [0, 1]
through the same decoder.onnx and feature sampling `bcfpipe decode --backend onnx` runs.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from bcfpipe.texset.texture_set import load_texture_set

pytest.importorskip("OpenImageIO")
pytest.importorskip("onnxruntime")

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "format.md"
SAMPLES = REPO / "samples" / "textures"
# fp16 precision of the values compared (outputs up to the emissive's peak): the two decoders differ
# only in fp32 against float64 arithmetic and in where the HDR curve rounds
REL = 2.0 ** -11
ABS = 2.0 ** -13
MATERIALS = {  # name: (features, T_0 layers, (S, T) addressing)
    "bc7-4": ("bc7", 1, ("repeat", "repeat")),
    "bc7-5": ("bc7", 2, ("clamp", "mirror")),
    "bc7-6": ("bc7", 3, ("mirror", "repeat")),
    "bc6h-4": ("bc6h", 1, ("repeat", "clamp")),
}


def doc_code() -> tuple[str, str]:
    """The decoder and the reading snippet, as docs/format.md prints them."""
    blocks = re.findall(r"```python\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    assert len(blocks) == 2, "docs/format.md: the reference decoder and its reading snippet"
    return blocks[0], blocks[1]


def emissive_exr(path: Path) -> str:
    """A 64² HDR emissive: a smooth ramp from 0 to 24 in each channel, as half floats."""
    import OpenImageIO as oiio

    y, x = (np.mgrid[0:64, 0:64] + 0.5) / 64
    a = np.ascontiguousarray(np.stack([24 * x * y, 6 * (1 - x) ** 2, 0.5 + 0.4 * np.sin(6 * y)], -1), np.float32)
    o = oiio.ImageOutput.create(str(path))
    o.open(str(path), oiio.ImageSpec(64, 64, 3, "half"))
    o.write_image(a)
    o.close()
    return f"emissiveColor={path}:rgb"


@pytest.fixture(scope="module")
def materials(tmp_path_factory) -> dict[str, Path]:
    from bcfpipe.config import PRESETS, PROFILES, ModelConfig, TrainConfig
    from bcfpipe.export.material import FIGURES, train_material
    from bcfpipe.formats.vocabulary import T0, FeatureFormat

    root = tmp_path_factory.mktemp("format-spec")
    specs = [f"albedo={SAMPLES / 'bricks_albedo.png'}:rgb", f"normal={SAMPLES / 'bricks_normal.png'}:rg",
             emissive_exr(root / "emissive.exr"), f"roughness={SAMPLES / 'bricks_roughness.png'}:r"]
    ts = load_texture_set(specs, resolution=64)
    out = {}
    for name, (features, k, wrap) in MATERIALS.items():
        fmt = FeatureFormat(features)
        mc = ModelConfig(resolutions=PROFILES["tiny"], features=fmt, t0_layers=k, wrap=wrap)
        cfg = TrainConfig(model=mc, preset=PRESETS["smoke"], preset_name="smoke",
                          t0=T0.PCA if fmt == FeatureFormat.BC7 else T0.TRAINED)
        train_material(ts, root / name, cfg, measure=FIGURES)
        out[name] = root / name
    return out


def reference(folder: Path, u: np.ndarray, v: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, dict]:
    """The doc's decoder on the doc's reading of ``folder``: (n, outputs) in source units."""
    decoder, reading = doc_code()
    ns: dict = {"folder": folder, "u": u.astype(np.float64), "v": v.astype(np.float64), "s": s.astype(np.float64)}
    exec(decoder, ns)  # noqa: S102 - the documentation's code is what is under test
    exec(reading, ns)  # noqa: S102
    return ns["rgb"], ns["m"]


def assert_close(ours: np.ndarray, theirs: np.ndarray, what: str) -> None:
    err = np.abs(ours - theirs)
    bound = ABS + REL * np.abs(theirs)
    worst = np.unravel_index(np.argmax(err - bound), err.shape)
    assert (err <= bound).all(), f"{what}: |ref - bcfpipe| {err[worst]:.3g} at {worst} (value {theirs[worst]:.4g})"


@pytest.mark.parametrize("name", list(MATERIALS))
def test_reference_decoder_matches_bcfpipe_decode(materials, name):
    """On `bcfpipe decode`'s grid, every output (normal z and the HDR emissive included) in source
    units, at lods that magnify, fall between mips and run past the last one."""
    from bcfpipe.cli.decode import decode_material, select_target

    folder = materials[name]
    features, k, wrap = MATERIALS[name]
    target = select_target(str(folder), None)
    outputs = target.desc.file.outputs
    scale = np.array([o.value_scale for o in outputs], np.float32)
    bias = np.array([o.value_bias for o in outputs], np.float32)
    w, h = 48, 40
    xs, ys = (np.arange(w) + 0.5) / w, (np.arange(h) + 0.5) / h
    v, u = (a.ravel() for a in np.meshgrid(ys, xs, indexing="ij"))
    for lod in (-1.5, 0.0, 1.37, 2.5, 9.0):
        ours, m = reference(folder, u, v, np.full(u.shape, lod))
        img, used = decode_material(target, (w, h), lod, "onnx")
        assert used == "onnx"
        assert_close(ours, (img * scale + bias).reshape(h * w, -1), f"{name} at s = {lod}")
    assert len(m["layers"]) == (3 + k if features == "bc7" else 4)
    assert m["mlp"]["record"] == "BCFW v2", "the emissive is HDR: a record with log_gain"
    assert [o["name"] for o in m["outputs"]][3:6] == ["normal.x", "normal.y", "normal.z"]
    assert ours[:, 6:9].max() > 4.0, "the emissive decodes above 1"


@pytest.mark.parametrize("name", list(MATERIALS))
def test_reference_decoder_addresses_every_axis_as_the_runtime(materials, name):
    """At points far outside [0, 1] (each axis its own addressing) and random lods, the doc's
    decoder gives what bcfpipe's feature sampling and decoder.onnx give, before source units."""
    from bcfpipe.export import writer as E
    from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT

    folder = materials[name]
    rng = np.random.default_rng(7)
    uv = rng.uniform(-2.5, 3.5, (4000, 2)).astype(np.float32)
    s = rng.uniform(-2.0, 8.0, 4000).astype(np.float32)
    em = E.load(folder)
    theirs = E.onnx_session(em).run([ONNX_OUTPUT], {ONNX_INPUT: E.sample_exported_features(em, uv, s)})[0]
    ours, m = reference(folder, uv[:, 0], uv[:, 1], s)
    outputs = [o for o in m["outputs"] if o.get("source") != "classic"]
    ours = (ours - [o["value_bias"] for o in outputs]) / [o["value_scale"] for o in outputs]
    assert_close(ours, theirs, f"{name}, uv in [-2.5, 3.5]")
    assert m["sampling"].get("addressing") or (m["sampling"]["wrap_s"], m["sampling"]["wrap_t"]) == MATERIALS[name][2]
