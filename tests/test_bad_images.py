"""Issue 33: damaged source images are refused by name, never trained, scanned or drawn as if whole.

The oracle is OpenImageIO itself, read directly here: a file is damaged when opening it fails, or
``read_image`` returns nothing, or the ImageInput holds an error afterwards. Every mutant (files
cut short, bytes flipped) goes through `bcfpipe plan` (the reading a build refuses with, exit
code 2 before anything trains) and through each reader of texels (training, scan facts, the
renderer's original textures).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_run import run_cli
from click.testing import CliRunner

from bcfpipe.formats import images
from bcfpipe.texset.texture_set import TextureError, load_texture_set

from test_build import add_material, new_stage

FORMATS = ("jpg", "png", "exr")
MUTANTS = 300  # per format: half cut short at a random length, half with 1-4 bytes flipped
N = 48


def source_bytes(ext: str, tmp: Path) -> bytes:
    """A small textured image in ``ext`` (8-bit, or half for EXR)."""
    import OpenImageIO as oiio

    y, x = np.mgrid[0:N, 0:N] / N
    a = np.stack([0.5 + 0.4 * np.sin(7 * x + k * y) for k in (3, 5, 9)], -1).astype(np.float32)
    path = tmp / f"source.{ext}"
    spec = oiio.ImageSpec(N, N, 3, "half" if ext == "exr" else "uint8")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(a)
    out.close()
    return path.read_bytes()


def mutants(data: bytes, seed: int):
    rng = np.random.default_rng(seed)
    for i in range(MUTANTS):
        if i % 2 == 0:
            yield f"cut at {(n := int(rng.integers(0, len(data))))}", data[:n]
        else:
            b = bytearray(data)
            where = rng.integers(0, len(b), int(rng.integers(1, 5)))
            for w in where:
                b[w] ^= int(rng.integers(1, 256))
            yield f"flipped at {sorted(int(w) for w in where)}", bytes(b)


def oracle_error(path: Path) -> str | None:
    """OpenImageIO's own verdict, read without bcfpipe: its error message, or None if whole."""
    import OpenImageIO as oiio

    if path.stat().st_size == 0:
        return "empty"
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        return oiio.geterror() or "cannot open"
    try:
        spec = inp.spec()
        if spec.width * spec.height > images.MAX_TEXELS or spec.nchannels > images.MAX_CHANNELS:
            return "implausible size"  # not read: bcfpipe refuses such a header before allocating it
        data = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        err = inp.geterror() if inp.has_error else ""
        return err or ("no pixels" if data is None else None)
    finally:
        inp.close()
        oiio.geterror()


@pytest.fixture
def cache_env(tmp_path, monkeypatch):
    monkeypatch.setenv("BCFPIPE_CACHE", str(tmp_path / "cache"))


@pytest.mark.parametrize("ext", FORMATS)
def test_fuzzed_sources_are_refused_exactly_when_openimageio_reports_an_error(tmp_path, ext, cache_env):
    from bcfpipe.cli import main as cli
    from bcfpipe.scan.content import read_stored

    data = source_bytes(ext, tmp_path)
    tex = tmp_path / "tex" / f"a.{ext}"
    tex.parent.mkdir()
    stage = new_stage(tmp_path / "scene.usda")
    add_material(stage, "/World/Looks/M", {"diffuseColor": (f"./tex/a.{ext}", "rgb", {})}, mesh="/World/A")
    stage.Save()
    runner = CliRunner()
    damaged = whole = 0
    wrong: list[str] = []
    for what, mutant in mutants(data, seed=FORMATS.index(ext)):
        tex.write_bytes(mutant)
        bad = oracle_error(tex)
        res = runner.invoke(cli, ["plan", str(tmp_path / "scene.usda"), "--json"])
        if not isinstance(res.exception, (SystemExit, type(None))):
            wrong.append(f"{what}: plan raised {type(res.exception).__name__}: {res.exception}")
            continue
        readers = []
        for name, read in (("train", lambda: load_texture_set([f"albedo={tex}:rgb"])),
                           ("scan", lambda: read_stored(str(tex))),
                           ("render", lambda: images.read(tex, as_float=True))):
            try:
                read()
                readers.append((name, None))
            except (TextureError, images.ImageReadError) as exc:
                readers.append((name, str(exc)))
            except Exception as exc:  # noqa: BLE001 - the finding this test looks for
                wrong.append(f"{what}: {name} raised {type(exc).__name__}: {exc}")
        if bad:
            damaged += 1
            if res.exit_code != 2 or str(tex) not in res.stderr or len(res.stderr.strip().splitlines()) != 1:
                wrong.append(f"{what}: OpenImageIO says {bad!r}; plan exited {res.exit_code}: {res.stderr.strip()!r}")
            wrong += [f"{what}: {name} read it without error ({bad!r})" for name, err in readers if err is None]
        else:
            whole += 1
            if res.exit_code != 0:
                wrong.append(f"{what}: whole for OpenImageIO, plan exited {res.exit_code}: {res.stderr.strip()!r}")
            wrong += [f"{what}: {name} refused a whole file: {err}" for name, err in readers if err is not None]
    assert not wrong, f"{len(wrong)} finding(s) of {MUTANTS}:\n" + "\n".join(wrong[:20])
    assert damaged >= MUTANTS // 3, (damaged, whole)  # the fuzz reaches the error paths


@pytest.mark.parametrize("ext", FORMATS)
def test_file_cut_in_half_is_one_line_naming_it_exit_2_and_nothing_written(tmp_path, ext):
    """The issue's first row, through the command a user runs: `bcfpipe build`."""
    data = source_bytes(ext, tmp_path)
    tex = tmp_path / "tex" / f"a.{ext}"
    tex.parent.mkdir()
    tex.write_bytes(data[: len(data) // 2])
    stage = new_stage(tmp_path / "scene.usda")
    add_material(stage, "/World/Looks/M", {"diffuseColor": (f"./tex/a.{ext}", "rgb", {})}, mesh="/World/A")
    stage.Save()
    out = tmp_path / "out"
    p = run_cli("build", tmp_path / "scene.usda", "-o", out, "--profile", "tiny", "--quality", "smoke",
                "--cache", tmp_path / "cache")
    assert p.returncode == 2, p.stderr
    (line,) = p.stderr.strip().splitlines()
    assert line.startswith("Error: ") and str(tex) in line and "Traceback" not in p.stderr
    assert not out.exists()
    t = run_cli("train", f"albedo={tex}:rgb", "-o", out)
    assert t.returncode == 2 and str(tex) in t.stderr and len(t.stderr.strip().splitlines()) == 1, t.stderr
    assert not out.exists()


def test_every_format_in_the_shared_scenes_is_checked(tmp_path):
    """JPEG, PNG, EXR, TGA, BMP, HDR and TIFF: whole files read, each cut in half is refused by name."""
    import OpenImageIO as oiio

    a = (np.random.default_rng(0).random((32, 32, 3))).astype(np.float32)
    for ext in ("jpg", "png", "exr", "tga", "bmp", "hdr", "tif"):
        path = tmp_path / f"f.{ext}"
        out = oiio.ImageOutput.create(str(path))
        assert out.open(str(path), oiio.ImageSpec(32, 32, 3, "half" if ext in ("exr", "hdr") else "uint8"))
        assert out.write_image(a)
        out.close()
        assert images.read(path).pixels.shape == (32, 32, 3)
        cut = tmp_path / f"cut.{ext}"
        cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
        with pytest.raises(images.ImageReadError, match=f"^{cut}: "):
            images.read(cut)
        with pytest.raises(images.ImageReadError, match="^user/cut"):
            images.read(cut, name=f"user/cut.{ext}")
