"""`bcfpipe verify` and `bcfpipe decode`: the GLSL runtime against decoder.onnx, tamper detection,
the derived tolerance, build folders, exit codes.

Materials are made without training: random mode-11110 BC6H blocks and a random fp16 decoder, written
by the real exporter (bcfpipe.export.export), so every file is exactly what a trained material has.
GL tests skip when no OpenGL 4.5 context can be created through EGL.
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from click.testing import CliRunner

from bcfpipe.export import writer as E
from bcfpipe.verify import checks as V
from bcfpipe.model.decoder import HEADER_BYTES, MlpWeights, decode_numpy
from bcfpipe.formats.vocabulary import FeatureFormat

SIZES = (32, 16, 8, 4)
REF = 64


def make_material(folder: Path, signed: bool = False, wrap: str = "repeat", normal: bool = False,
                  resolutions=SIZES, ref: int = REF, hidden: int = 16, seed: int = 0, mlp_transform=None) -> Path:
    """Export a synthetic material: random smooth-ish BC6H features, a random fp16 decoder
    (``mlp_transform`` maps its MlpWeights to the ones exported)."""
    from bcfpipe.config import ModelConfig, TrainConfig, mip_count
    from bcfpipe.model.features import Layers
    from bcfpipe.model.neural import lod_biases
    from bcfpipe.texset.texture_set import Channel, TextureSet
    from bcfpipe.train.trainer import BlockLevel

    rng = np.random.default_rng(seed)
    src = str(folder / "src.png")
    chans = [Channel("albedo", c, "color", src, i) for i, c in enumerate("rgb")]
    if normal:
        chans += [Channel("normal", c, "normal", src, i) for i, c in enumerate("xy")]
    chans.append(Channel("roughness", "r", "scalar", src, 0))
    ts = TextureSet(np.zeros((ref, ref, len(chans)), np.float32), tuple(chans), ref, ref)
    lo, hi = (-12, 12) if signed else (22, 30)
    layers = []
    for r in resolutions:
        mips = []
        for k in range(mip_count(r)):
            size = max(4, r >> k)
            n = (size // 4) ** 2
            mips.append(BlockLevel(rng.integers(lo, hi + 1, (n, 4, 3)), rng.integers(0, 8, (n, 16)),
                                   rng.integers(0, 32, n), size))
        layers.append(mips)
    n_out = len(chans)
    w = MlpWeights(
        (rng.uniform(-1, 1, (hidden, 12)) * 0.8).astype(np.float32),
        rng.uniform(-0.5, 0.5, hidden).astype(np.float32),
        (rng.uniform(-1, 1, (n_out, hidden)) * 0.15).astype(np.float32),
        np.zeros(n_out, np.float32), np.ones(n_out, np.float32),
        np.array([0.0 if c.kind == "normal" else 0.5 for c in chans], np.float32)).to_fp16()
    if mlp_transform is not None:
        w = mlp_transform(w)
    cfg = TrainConfig(model=ModelConfig(features=FeatureFormat.BC6H, resolutions=tuple(resolutions), hidden=hidden, signed=signed, wrap=wrap),
                      preset_name="synthetic")
    tm = SimpleNamespace(config=cfg, texture_set=ts, layers=Layers.of(layers), mlp=w,
                         lod_biases=lod_biases(resolutions, ref, ref), phase_seconds={},
                         kinds=tuple(c.kind for c in chans))
    out = folder / "mat"
    E.export(tm, out)
    return out


@pytest.fixture(scope="module")
def gl_runtime():
    from bcfpipe.verify.glsl import GLRuntime, GLUnavailable

    try:
        rt = GLRuntime()
    except GLUnavailable as e:
        pytest.skip(str(e))
    yield rt
    rt.release()


@pytest.fixture(scope="module")
def materials(tmp_path_factory):
    base = tmp_path_factory.mktemp("mats")
    out = {}
    for name, kw in {"unsigned_repeat": {}, "signed_clamp_normal": dict(signed=True, wrap="clamp", normal=True),
                     "unsigned_normal_h32": dict(normal=True, hidden=32, seed=3)}.items():
        (base / name).mkdir()
        out[name] = make_material(base / name, **kw)
    return out


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def _print_table(name: str, rep: V.MaterialReport) -> None:
    print(f"\n[{name}] {rep.n_points} points")
    for ch in rep.channels:
        print(f"  {ch['name']:<12} max {ch['max_abs']:.3g}  mean {ch['mean_abs']:.3g}  "
              f"tol max {ch['max_tolerance']:.3g} mean {ch['mean_tolerance']:.3g}")


# ---------------------------------------------------------------------------------------- passes

@pytest.mark.gl
@pytest.mark.parametrize("name", ["unsigned_repeat", "signed_clamp_normal", "unsigned_normal_h32"])
def test_verify_passes_on_exported_materials(materials, gl_runtime, name):
    rep = V.verify(materials[name], runtime=gl_runtime)
    m = rep.materials[0]
    _print_table(name, m)
    assert rep.exit_code == 0, [c.to_dict() for c in m.checks]
    assert {c.name: c.passed for c in m.checks} == {"files": True, "integrity": True, "weights": True,
                                                     "openimageio": True, "glsl": True}
    cats = {c["category"]: c for c in m.categories}
    assert set(cats) == set(V.CATEGORIES)
    assert all(c["n"] >= 100 for c in cats.values())
    if gl_runtime.is_software:  # llvmpipe filters in fp32: the two paths agree to fp32 rounding
        assert max(ch["max_abs"] for ch in m.channels) < 2e-5


def test_grid_covers_the_extremes(materials):
    from bcfpipe.verify.glsl import read_material

    m = read_material(materials["unsigned_repeat"])
    sizes = [[(max(4, r >> k),) * 2 for k in range(n)] for r, n in zip(SIZES, m.mip_counts)]
    uv, s, cat = V.verification_points(m, sizes)
    s_last = max(n - 1 - b for n, b in zip(m.mip_counts, m.lod_biases))
    assert (s < 0).sum() > 1000 and (s > s_last).sum() > 500
    assert ((s[np.isfinite(s)] % 1) != 0).sum() > 1000
    assert (uv < 0).any() and (uv > 1).any() and (uv == 0).any() and (uv == 1).any()
    # the runtime extremes (issue #11): uv +-1e4 in both axes, s at +-inf and +-1e30
    assert (uv <= -1e4 + 1).any() and (uv >= 1e4).any()
    assert np.isinf(s).sum() >= 128 and (np.abs(s) == np.float32(1e30)).sum() >= 128
    # every level of every layer is hit at exact texel centres with that layer exactly at the level
    centres = cat == V.CATEGORIES.index("texel centres")
    for i, b in enumerate(m.lod_biases):
        assert set(range(m.mip_counts[i])) <= set(np.round(s[centres] + b, 6).tolist())


# ---------------------------------------------------------------------------------------- tamper

def _flip_weight(folder: Path, index: int, new_value: float | None = None, ulps: int = 0) -> float:
    path = folder / "weights.bin"
    data = bytearray(path.read_bytes())
    off = HEADER_BYTES + 2 * index
    old = np.frombuffer(bytes(data[off:off + 2]), "<f2")[0]
    if new_value is not None:
        new = np.float16(new_value)
    else:
        new = (np.array([old], "<f2").view("<u2") + np.uint16(ulps)).view("<f2")[0]
    data[off:off + 2] = np.array([new], "<f2").tobytes()
    path.write_bytes(bytes(data))
    return float(new) - float(old)


@pytest.mark.gl
def test_changed_fp16_weight_fails(materials, gl_runtime, tmp_path):
    d = _copy(materials["unsigned_repeat"], tmp_path / "m")
    hidden = 16
    _flip_weight(d, 12 * hidden + 3, new_value=2.5)  # b1[3]: a hidden unit's bias
    rep = V.verify(d, runtime=gl_runtime)
    checks = {c.name: c for c in rep.materials[0].checks}
    print("\n" + checks["weights"].detail + "\n" + checks["glsl"].detail)
    assert rep.exit_code == 1
    assert checks["weights"].passed is False and checks["glsl"].passed is False


@pytest.mark.gl
def test_one_ulp_weight_change_fails_the_weights_check(materials, gl_runtime, tmp_path):
    d = _copy(materials["unsigned_repeat"], tmp_path / "m")
    _flip_weight(d, 5, ulps=1)  # W1[0][5] + 1 ulp: below any filtering tolerance, still caught
    rep = V.verify(d, runtime=gl_runtime)
    checks = {c.name: c for c in rep.materials[0].checks}
    assert rep.exit_code == 1 and checks["weights"].passed is False
    assert "W1: 1 value(s) differ" in checks["weights"].detail


@pytest.mark.gl
def test_flipped_dds_byte_fails(materials, gl_runtime, tmp_path):
    """A flipped byte is decoded identically by Mesa and bcfpipe, so it is caught by the file
    checks: the mode bits by the declared block mode, any byte by the recorded SHA-256."""
    from bcfpipe.formats import dds

    d = _copy(materials["unsigned_repeat"], tmp_path / "m")
    assert "sha256" in json.loads((d / "material.json").read_text())  # recorded by the exporter
    assert V.verify(d, runtime=gl_runtime).exit_code == 0
    path = d / "T1.dds"
    data = bytearray(path.read_bytes())
    block = len(dds.encode_header(16, 16, 3, False)) + 16 * 5  # 6th block of mip 0
    data[block + 11] ^= 0x40  # an index bit
    path.write_bytes(bytes(data))
    rep = V.verify(d, runtime=gl_runtime)
    checks = {c.name: c for c in rep.materials[0].checks}
    assert rep.exit_code == 1 and checks["integrity"].passed is False
    assert "T1.dds differs" in checks["integrity"].detail
    assert checks["glsl"].passed and checks["openimageio"].passed  # both decoders agree on the new block

    d2 = _copy(materials["unsigned_repeat"], tmp_path / "m2")
    desc = json.loads((d2 / "material.json").read_text())
    del desc["sha256"]  # a folder from before digests were recorded
    (d2 / "material.json").write_text(json.dumps(desc))
    path = d2 / "T0.dds"
    data = bytearray(path.read_bytes())
    data[len(dds.encode_header(32, 32, 4, False)) + 16 * 7] ^= 0x01  # mode bits of a block
    path.write_bytes(bytes(data))
    rep = V.verify(d2, runtime=gl_runtime)
    checks = {c.name: c for c in rep.materials[0].checks}
    assert rep.exit_code == 1 and checks["files"].passed is False and "mode 11110" in checks["files"].detail


# ---------------------------------------------------------------------------------------- tolerance

def _quantized_features(em, uv, s, bits, mode):
    """Features as a texture unit with ``bits`` fractional bits (rounding or truncating) filters them."""
    import torch

    from bcfpipe.model.sampling import sample_bilinear

    q = 2.0 ** bits
    quant = (lambda x: np.round(x * q) / q) if mode == "round" else (lambda x: np.floor(x * q) / q)
    out = []
    for layer, b in zip(em.levels, em.lod_biases):
        n = len(layer)
        lam = np.clip(s.astype(np.float64) + b, 0, n - 1)
        lo = np.floor(lam)
        t = quant(lam - lo)
        acc = 0.0
        for k, tex in enumerate(layer):
            h, w, _ = tex.shape
            x = quant(uv[:, 0].astype(np.float64) * w - 0.5)
            y = quant(uv[:, 1].astype(np.float64) * h - 0.5)
            uvq = torch.from_numpy(np.stack([(x + 0.5) / w, (y + 0.5) / h], 1))
            val = sample_bilinear(torch.from_numpy(np.moveaxis(tex, -1, 0).astype(np.float64)), uvq, em.wrap).numpy()
            wk = np.where(lo == k, 1 - t, 0) + np.where((lo + 1 == k) & (lo + 1 <= n - 1), t, 0)
            acc = acc + val * wk[:, None]
        out.append(acc)
    return np.concatenate(out, 1).astype(np.float32)


@pytest.mark.parametrize("name", ["unsigned_repeat", "signed_clamp_normal", "unsigned_normal_h32"])
def test_derived_tolerance_bounds_8bit_hardware_filtering(materials, name):
    """Simulate a texture unit with 8-bit sub-texel and mip fractions (rounded or truncated): its
    outputs stay within the derived per-point tolerance, which is nearly reached (tight)."""
    from bcfpipe.verify.glsl import read_material

    m = read_material(materials[name])
    em = E.load(materials[name])
    sizes = [[(lv.shape[1], lv.shape[0]) for lv in layer] for layer in em.levels]
    uv, s, _ = V.verification_points(m, sizes)
    feats = E.sample_exported_features(em, uv, s)
    ref = decode_numpy(em.weights, feats, em.kinds)
    tol = V.output_tolerance(em.weights, em.kinds, feats, V.filter_error(em.levels, em.lod_biases, uv, s, em.wrap), ref)
    worst = 0.0
    for mode in ("round", "floor"):
        sim = decode_numpy(em.weights, _quantized_features(em, uv, s, 8, mode), em.kinds)
        err = np.abs(sim.astype(np.float64) - ref)
        ratio = float((err / tol).max())
        worst = max(worst, ratio)
        print(f"\n[{name}, 8-bit {mode}] simulated max {err.max(0).round(5).tolist()} "
              f"mean {err.mean(0).round(6).tolist()}; tol max {tol.max(0).round(5).tolist()} "
              f"mean {tol.mean(0).round(6).tolist()}; max err/tol {ratio:.3f}")
        assert (err <= tol).all()
    assert worst > 0.3  # the bound is not vacuous


def test_tolerance_has_fp32_floor_at_texel_centres(materials):
    from bcfpipe.verify.glsl import read_material

    em = E.load(materials["unsigned_repeat"])
    m = read_material(materials["unsigned_repeat"])
    # T0 level 0 centres at s = -b_0 (T0 exactly on level 0): fraction error only from other layers
    uv = np.array([[0.5 / 32, 0.5 / 32], [10.5 / 32, 3.5 / 32]], np.float32)
    s = np.full(2, -m.lod_biases[0], np.float32)
    fe = V.filter_error(em.levels, em.lod_biases, uv, s, em.wrap)
    assert (fe.total[:, :3] < 1e-4).all()  # T0 contributes only fp32 arithmetic
    assert (fe.total[:, 3:] >= 0).all()


# ---------------------------------------------------------------------------------------- CLI / inputs

@pytest.mark.gl
def test_cli_json_and_exit_codes(materials, tmp_path):
    from bcfpipe.cli import main

    r = CliRunner().invoke(main, ["verify", str(materials["signed_clamp_normal"]), "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["passed"] and rep["materials"][0]["channels"][5]["name"] == "normal.z"
    r = CliRunner().invoke(main, ["verify", str(materials["unsigned_repeat"]), "-v"])
    assert r.exit_code == 0 and "1/1 material(s) passed" in r.output and "texel edges" in r.output
    r = CliRunner().invoke(main, ["verify", str(materials["unsigned_repeat"]), "--tolerance", "0"])
    assert r.exit_code in (0, 1)  # fixed tolerance 0: passes only if GL is bit-exact
    (tmp_path / "empty").mkdir()
    r = CliRunner().invoke(main, ["verify", str(tmp_path / "empty")])
    assert r.exit_code == 2
    bad = _copy(materials["unsigned_repeat"], tmp_path / "bad")
    (bad / "T2.dds").write_bytes((bad / "T2.dds").read_bytes()[:-7])
    r = CliRunner().invoke(main, ["verify", str(bad), "--json"])
    assert r.exit_code == 2 and "truncated" in json.loads(r.output)["materials"][0]["input_error"]


@pytest.mark.gl
def test_cli_one_line_per_material_unless_verbose(materials, tmp_path):
    """Default: the header (renderer, tolerance), one line per material with its figures, the
    count; a failure says on its line what failed. -v: every check and the error tables. --json
    keeps its keys."""
    from bcfpipe.cli import main

    root = tmp_path / "two"
    _copy(materials["unsigned_repeat"], root / "a")
    _copy(materials["signed_clamp_normal"], root / "b")
    r = CliRunner().invoke(main, ["verify", str(root)])
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert len(lines) == 2 + 2 + 1, r.stdout
    assert lines[0].startswith("OpenGL: ") and lines[1].startswith("Tolerance: ")
    assert [ln.split()[:2] for ln in lines[2:4]] == [["PASS", "a"], ["PASS", "b"]]
    assert all("glsl: max |GLSL - ONNX| " in ln and "tolerance up to" in ln and " points x " in ln
               and ln.endswith("ok: files, integrity, weights, openimageio") for ln in lines[2:4])
    assert lines[4] == "2/2 material(s) passed"

    r = CliRunner().invoke(main, ["verify", str(root), "--verbose"])
    assert r.exit_code == 0
    detail = r.stdout.splitlines()
    assert len(detail) > 2 * 20 and "texel edges" in r.stdout and "by sample group" in r.stdout
    assert sum(ln.lstrip().startswith("ok   files") for ln in detail) == 2

    _flip_weight(root / "b", 5, ulps=1)
    r = CliRunner().invoke(main, ["verify", str(root)])
    assert r.exit_code == 1
    lines = r.stdout.splitlines()
    assert len(lines) == 5 and lines[4] == "1/2 material(s) passed"
    assert lines[3].startswith("FAIL b  integrity: weights.bin differs from its recorded SHA-256; "
                               "weights: W1: 1 value(s) differ; glsl: max |GLSL - ONNX| "), lines[3]

    r = CliRunner().invoke(main, ["verify", str(root), "--json"])
    rep = json.loads(r.stdout)
    assert set(rep) == {"path", "passed", "exit_code", "renderer", "vulkan", "gl_error", "tolerance", "materials"}
    assert set(rep["materials"][0]) == {"name", "folder", "passed", "input_error", "checks", "n_points", "channels",
                                        "categories", "shares"}


def _report(checks, channels=(), n_points=0, input_error=None) -> V.MaterialReport:
    return V.MaterialReport("/W/M", "/out/m", [V.Check(*c) for c in checks], list(channels), [], n_points,
                            input_error)


def _channel(name, max_abs, max_tol, over=0, category="random") -> dict:
    return {"name": name, "max_abs": max_abs, "mean_abs": max_abs / 10, "max_tolerance": max_tol,
            "mean_tolerance": max_tol / 10, "over_tolerance": over,
            "worst": {"u": 0.5, "v": 0.5, "s": 1.0, "category": category}, "passed": over == 0}


def test_material_line_says_what_failed():
    """The one-line form: failures first with their finding, the GLSL figures of the worst
    channel (a failing one when any fails), then the checks that passed and were skipped."""
    from bcfpipe.cli.verify import material_line

    ok = [("files", True, "4 layers"), ("integrity", None, "no SHA-256 recorded"), ("weights", True, "equal"),
          ("openimageio", True, "14 levels")]
    line = material_line(_report(ok + [("glsl", True, "fine")],
                                 [_channel("albedo.r", 1e-7, 2e-3), _channel("normal.x", 3e-7, 5e-4)], 100))
    assert line == ("glsl: max |GLSL - ONNX| 3e-07 (normal.x; tolerance up to 0.0005), 100 points x 2 channels; "
                    "ok: files, weights, openimageio; skipped: integrity")
    line = material_line(_report(ok + [("glsl", False, "over")],
                                 [_channel("albedo.r", 0.5, 2e-3, over=7, category="texel edges"),
                                  _channel("normal.x", 0.9, 5e-1)], 100))
    assert line.startswith("glsl: 7 of 200 values over tolerance, max |GLSL - ONNX| 0.5 (albedo.r; tolerance up "
                           "to 0.002), worst at texel edges; ok: files, weights")
    line = material_line(_report([("files", True, "ok"), ("weights", False, "W1: 1 value(s) differ"),
                                  ("glsl", None, "skipped (--no-glsl)")]))
    assert line == "weights: W1: 1 value(s) differ; ok: files; skipped: glsl"
    assert material_line(_report([], input_error="T2.dds: truncated")) == "bad input: T2.dds: truncated"


def test_verify_heartbeat_on_a_fake_clock():
    """While a check runs, stderr gets a line once nothing was printed for LINE_SECONDS, and not
    sooner; a material's line counts as output."""
    import io

    from rich.console import Console

    from bcfpipe.cli.verify import VerifyOutput
    from bcfpipe.train.pace import LINE_SECONDS

    now = [100.0]
    report, beat = io.StringIO(), io.StringIO()
    out = VerifyOutput(Console(file=report, width=300), heartbeat=Console(file=beat, width=300),
                       clock=lambda: now[0])
    out(V.VerifyEvent("start", renderer={"renderer": "r", "version": "v"},
                      tolerance={"mode": "fixed", "value": 0.1, "filter_bits": 8}, total=2))
    out(V.VerifyEvent("check", "/W/A", "glsl"))
    for t in (1.0, 4.0, LINE_SECONDS - 0.1):
        now[0] = 100.0 + t
        out.tick()
    assert beat.getvalue() == ""
    now[0] = 100.0 + LINE_SECONDS
    out.tick()
    assert beat.getvalue() == f"verify: 0/2 material(s) checked; /W/A: glsl, {LINE_SECONDS:.0f}s in\n"
    now[0] += LINE_SECONDS - 0.5
    out(V.VerifyEvent("done", "/W/A", report=_report([("files", True, "")])))
    now[0] += 1.0
    out.tick()
    assert beat.getvalue().count("\n") == 1 and report.getvalue().splitlines()[-1] == "PASS /W/M  ok: files"


def test_no_opengl_is_exit_2(materials, monkeypatch):
    from bcfpipe.verify import glsl as G

    def boom(*a, **k):
        raise G.GLUnavailable("no EGL here (test)")

    monkeypatch.setattr(V, "GLRuntime", boom)
    rep = V.verify(materials["unsigned_repeat"])
    assert rep.exit_code == 2 and "no EGL" in rep.gl_error
    rep = V.verify(materials["unsigned_repeat"], glsl=False)
    assert rep.exit_code == 0


@pytest.mark.gl
def test_build_folder_with_combined_weights(materials, gl_runtime, tmp_path):
    """A build layout: materials/<name>/ + one BCFB weights.bin + manifest.json; each material is
    decoded from the combined buffer at its offset, shared records verified once."""
    import shutil

    from bcfpipe.formats import manifest as mfst
    from bcfpipe.formats import weights as weightsbuf

    root = tmp_path / "build"
    names = ["unsigned_repeat", "signed_clamp_normal"]
    for n in names:
        shutil.copytree(materials[n], root / "materials" / n)
    records = [(root / "materials" / n / "weights.bin").read_bytes() for n in names]
    _, entries = weightsbuf.pack(records)
    weightsbuf.write(root / "weights.bin", records)
    mats = [mfst.Material(f"/World/Looks/{n}", "built",
                          outputs=mfst.Outputs(f"materials/{n}", e.index, e.offset, e.size))
            for n, e in zip(names, entries)]
    mats.append(mfst.Material("/World/Looks/alias", "built", outputs=mats[0].outputs))
    mats.append(mfst.Material("/World/Looks/broken", "failed"))
    mfst.write(root, mfst.Manifest(scene="scene.usda", root_layer="scene.bcf.usda", materials=tuple(mats)))
    rep = V.verify(root, runtime=gl_runtime)
    # one report per built material, in the manifest's order: the alias shares unsigned_repeat's files
    assert [(m.name, m.shares) for m in rep.materials] == [
        ("/World/Looks/unsigned_repeat", None), ("/World/Looks/signed_clamp_normal", None),
        ("/World/Looks/alias", "/World/Looks/unsigned_repeat")]
    assert rep.exit_code == 0
    assert all("weights.bin@" in {c.name: c for c in m.checks}["weights"].detail for m in rep.materials)
    assert entries[1].offset > 0
    # corrupt the second record inside the combined buffer only: its material fails
    data = bytearray((root / "weights.bin").read_bytes())
    data[entries[1].offset + HEADER_BYTES + 40] ^= 0x20
    (root / "weights.bin").write_bytes(bytes(data))
    rep = V.verify(root, runtime=gl_runtime)
    assert [m.passed for m in rep.materials] == [True, False, True] and rep.exit_code == 1
    # without a manifest: a directory scan of */material.json
    (root / "manifest.json").unlink()
    (root / "weights.bin").unlink()
    targets = V.find_targets(root)
    assert sorted(t.desc.name for t in targets) == ["materials/signed_clamp_normal", "materials/unsigned_repeat"]


@pytest.mark.gl
def test_decode_cli_writes_images(materials, tmp_path):
    import OpenImageIO as oiio

    from bcfpipe.cli import main

    src = materials["signed_clamp_normal"]
    outs = {}
    for backend in ("glsl", "onnx"):
        r = CliRunner().invoke(main, ["decode", str(src), "--lod", "0.5", "--size", "48x40", "--backend", backend,
                                      "-o", str(tmp_path / backend)])
        assert r.exit_code == 0, r.output
        outs[backend] = {p.name: p for p in (tmp_path / backend).iterdir()}
    # sources are not readable (synthetic): not known to be 8-bit -> EXR
    assert set(outs["glsl"]) == {"albedo.exr", "normal.exr", "roughness.exr"}
    for name in outs["glsl"]:
        a = oiio.ImageBuf(str(outs["glsl"][name])).get_pixels(oiio.FLOAT)
        b = oiio.ImageBuf(str(outs["onnx"][name])).get_pixels(oiio.FLOAT)
        assert a.shape[:2] == (40, 48)
        assert np.abs(a - b).max() < 2e-3
    n = oiio.ImageBuf(str(outs["glsl"]["normal.exr"])).get_pixels(oiio.FLOAT) * 2 - 1
    assert np.abs(np.linalg.norm(n, axis=-1) - 1).max() < 1e-3 or (n[..., 2] >= -1e-6).all()
    # 8-bit sources -> PNG
    d = _copy(src, tmp_path / "png")
    desc = json.loads((d / "material.json").read_text())
    for o in desc["outputs"]:
        if not o["reconstructed"]:
            o["source_format"] = "uint8"
    (d / "material.json").write_text(json.dumps(desc))
    r = CliRunner().invoke(main, ["decode", str(d), "--backend", "onnx", "-o", str(tmp_path / "p")])
    assert r.exit_code == 0, r.output
    assert {p.name for p in (tmp_path / "p").iterdir()} == {"albedo.png", "normal.png", "roughness.png"}
    spec = oiio.ImageInput.open(str(tmp_path / "p" / "albedo.png")).spec()
    assert (spec.width, spec.height, str(spec.format)) == (REF, REF, "uint8")
    r = CliRunner().invoke(main, ["decode", str(d), "--material", "nope", "-o", str(tmp_path / "q")])
    assert r.exit_code == 2
