"""`bcfpipe bench`: the report of a small set end to end (real training, quicktex, astcenc, Mesa GL,
matplotlib), its data file against the library's own metric code, and the HTML in headless Chromium."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_build import add_material, new_stage, pattern, write_png  # noqa: E402

from bcfpipe.bench import report as R  # noqa: E402


def run_cli(*args: str, timeout: int = 900) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bcfpipe", *args], capture_output=True, text=True, timeout=timeout)


def textures(root: Path, n: int = 128) -> list[str]:
    rng = np.random.default_rng(0)
    base = pattern(n, 3) + 0.05 * rng.standard_normal((n, n, 3))
    write_png(root / "albedo.png", base)
    write_png(root / "rough.png", pattern(n, 1, seed=4)[..., 0])
    write_png(root / "normal.png", pattern(n, 3, seed=2))
    return [f"albedo={root / 'albedo.png'}:rgb", f"roughness={root / 'rough.png'}:r",
            f"normal={root / 'normal.png'}:xy"]


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """A bench of a 128² set: one BCf cell (tiny/smoke, its material kept), BC, the BC7 quality set
    and ASTC 12x12 at full and half size."""
    if shutil.which("astcenc") is None:
        pytest.skip("needs astcenc (apt-get install astcenc)")
    root = tmp_path_factory.mktemp("bench")
    out = root / "report"
    p = run_cli("bench", *textures(root), "--name", "small set", "--profiles", "tiny", "--presets", "smoke",
                "--astc-blocks", "12x12", "--decode-size", "64x36", "--keep-materials", "-o", str(out))
    assert p.returncode == 0, p.stderr
    assert "| BCf tiny smoke |" in p.stdout  # the markdown summary on stdout
    return out


def test_report_files_and_keys(report: Path) -> None:
    data = json.loads((report / R.JSON_FILE).read_text())
    assert (data["format"], data["format_version"]) == ("bcfpipe-bench", 1)
    (s,) = data["sets"]
    assert s["name"] == "small set" and s["slug"] == "small_set"
    assert s["sources"] == ["albedo=albedo.png:rgb", "roughness=rough.png:r", "normal=normal.png:xy"]  # no paths
    methods = [b["method"] for b in s["baselines"]]
    assert methods == ["BC @128", "BC7 quality @128", "ASTC 12x12 @128", "BC @64", "BC7 quality @64", "ASTC 12x12 @64"]
    (cell,) = s["cells"]
    assert (cell["profile"], cell["preset"], cell["method"]) == ("tiny", "smoke", "BCf tiny smoke")
    n_mips = len(s["mips"])
    for row in [*s["baselines"], cell]:
        assert len(row["psnr_per_mip"]) == n_mips and len(row["lod_sweep"]) == len(s["lod_sweep"]["s"])
        assert set(row["psnr_per_group"]) == {"albedo", "roughness", "normal"}
        assert row["size_bytes"] > 0 and 10 < row["psnr"] < 80 and 0 < row["ssim"] <= 1
        assert 0 < row["disk_bytes"] and row["disk_mib"] == row["disk_bytes"] / 2**20
    # sizes: BC = BC1 albedo + BC4 roughness (8 B/block) + BC5 normal (16 B/block), every mip; the
    # quality set's albedo in BC7 (16 B/block)
    blocks = sum(((w + 3) // 4) * ((h + 3) // 4) for w, h in s["mips"])
    assert s["baselines"][0]["size_bytes"] == blocks * (8 + 8 + 16)
    assert s["baselines"][1]["size_bytes"] == blocks * (16 + 8 + 16)
    assert [b["formats"] for b in s["baselines"][:2]] == [["bc1", "bc5", "bc4"], ["bc7", "bc5", "bc4"]]
    assert data["options"]["disk_zstd_level"] == 19
    assert cell["training_curve"] and cell["train_seconds"] > 0
    d = s["decode_cost"]
    assert d["classic"] == "BC @128" and d["classic_formats"] == ["BC1", "BC5", "BC4"]
    (row,) = d["rows"]
    assert row["method"] == "BCf tiny smoke" and row["ratio"] > 0 and (row["width"], row["height"]) == (64, 36)
    if d["software"]:
        assert "only the neural / classic ratio" in d["note"]
    assert [c["mip"] for c in s["crops"]] == [0, 2] and all((report / c["png"]).is_file() for c in s["crops"])
    for f in ("small_set_rd.png", "small_set_time.png", "small_set_per_mip.png", "small_set_lod.png",
              R.HTML_FILE, R.MD_FILE):
        assert (report / f).is_file(), f
    assert not [p for p in report.iterdir() if p.name.startswith(".bench-work")]


def test_baselines_match_the_library(report: Path, tmp_path: Path) -> None:
    """The report's BC row is what bcfpipe.texset.baselines + texset.metrics give on the same set."""
    from bcfpipe.texset.baselines import encode_texture_set_baseline
    from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set
    from bcfpipe.texset.metrics import compute_metrics

    s = json.loads((report / R.JSON_FILE).read_text())["sets"][0]
    ts = load_texture_set([TextureSpec.parse(t) for t in textures(tmp_path)])
    ref = build_mip_chain(ts.data)
    dec, size = encode_texture_set_baseline(ts, "bc", 64, ref_mips=ref)
    m = compute_metrics(ref, dec, ts.channels)
    row = next(b for b in s["baselines"] if b["method"] == "BC @64")
    assert row["size_bytes"] == size and row["psnr"] == pytest.approx(m.psnr, abs=1e-9)
    dec, size = encode_texture_set_baseline(ts, "bc7", 64, ref_mips=ref)
    row = next(b for b in s["baselines"] if b["method"] == "BC7 quality @64")
    assert row["size_bytes"] == size
    assert row["psnr_per_mip"] == pytest.approx(compute_metrics(ref, dec, ts.channels).psnr_per_mip, abs=1e-9)


def zstd_cli(data: bytes, tmp: Path) -> int:
    """``zstd -19 --no-check -c FILE | wc -c``."""
    f = tmp / "blob.bin"
    f.write_bytes(data)
    return len(subprocess.run(["zstd", "-19", "--no-check", "-q", "-c", str(f)], capture_output=True,
                              check=True).stdout)


@pytest.mark.skipif(shutil.which("zstd") is None, reason="needs the zstd command line")
def test_disk_bytes_against_the_zstd_command_line(report: Path, tmp_path: Path) -> None:
    """Every row's disk bytes are its files compressed by the zstd CLI at level 19, within a few
    bytes of frame header per file: the BCf cell's shipped files (its GPU bytes count the same
    files), BC@R's and the quality set's textures as `formats.dds.write` writes them."""
    from bcfpipe.export.material import shipped_files
    from bcfpipe.formats import dds
    from bcfpipe.formats.bcn import DXGI, ClassicFormat
    from bcfpipe.texset.baselines import BC7_QUALITY, encode_texture_set_baseline
    from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set

    s = json.loads((report / R.JSON_FILE).read_text())["sets"][0]
    (cell,) = s["cells"]
    files = shipped_files(report / cell["folder"])
    assert cell["size_bytes"] == sum(f.stat().st_size for f in files)
    assert abs(cell["disk_bytes"] - sum(zstd_cli(f.read_bytes(), tmp_path) for f in files)) <= 8 * len(files)
    ts = load_texture_set([TextureSpec.parse(t) for t in textures(tmp_path)])
    ref = build_mip_chain(ts.data)
    for codec, method in (("bc", "BC @128"), (BC7_QUALITY, "BC7 quality @128")):
        tex: list = []
        encode_texture_set_baseline(ts, codec, 128, ref_mips=ref, textures=tex)
        cli = 0
        for fmt, _, levels in tex:
            dds.write(tmp_path / "t.dds", levels, dxgi_format=DXGI[ClassicFormat(fmt)])
            cli += zstd_cli((tmp_path / "t.dds").read_bytes(), tmp_path)
        row = next(b for b in s["baselines"] if b["method"] == method)
        assert abs(row["disk_bytes"] - cli) <= 8 * len(tex), (method, row["disk_bytes"], cli)


def test_margins_against_bc_and_the_quality_set(report: Path) -> None:
    """Each row's per-mip margins against BC@R and the BC7 quality set at R (a BCf cell's R is its
    T_0 side, tiny's 64; a baseline's its resolution), and the summary's table of the cell's."""
    s = json.loads((report / R.JSON_FILE).read_text())["sets"][0]
    rows = {r["method"]: r for r in [*s["baselines"], *s["cells"]]}

    def margins(a: dict, b: dict) -> list:
        return [x - y if x is not None and y is not None else None for x, y in zip(a["psnr_per_mip"], b["psnr_per_mip"])]

    cell = rows["BCf tiny smoke"]
    assert cell["resolutions"][0] == 64
    for method, bc, q in (("BCf tiny smoke", "BC @64", "BC7 quality @64"), ("ASTC 12x12 @128", "BC @128", "BC7 quality @128"),
                          ("BC7 quality @128", "BC @128", None), ("BC @64", None, "BC7 quality @64")):
        r = rows[method]
        assert (r.get("against_bc"), r.get("against_bc7")) == (bc, q)
        assert r.get("margin_per_mip_db") == (None if bc is None else pytest.approx(margins(r, rows[bc]), abs=1e-9))
        assert r.get("margin_vs_bc7_per_mip_db") == (None if q is None else pytest.approx(margins(r, rows[q]), abs=1e-9))
    md = (report / R.MD_FILE).read_text()
    assert "| method | GPU MiB | disk MiB |" in md
    q = rows["BC7 quality @64"]
    line = next(x for x in md.splitlines() if x.startswith("| BCf tiny smoke | BC7 quality @64 |")).split(" | ")
    assert line[2:5] == [f"{cell['size_bytes'] / q['size_bytes']:.2f}", f"{cell['disk_bytes'] / q['disk_bytes']:.2f}",
                         f"{margins(cell, q)[0]:+.1f}"]
    assert any(x.startswith("| BCf tiny smoke | BC @64 |") for x in md.splitlines())


def test_redraw_and_refusals(report: Path, tmp_path: Path) -> None:
    before = (report / R.HTML_FILE).read_text()
    p = run_cli("bench", "--redraw", "-o", str(report))
    assert p.returncode == 0, p.stderr
    assert (report / R.HTML_FILE).read_text() == before
    p = run_cli("bench", "albedo=x.png:rgb", "-o", str(report))  # a non-empty folder is not overwritten
    assert p.returncode == 2 and "not empty" in p.stderr and "Traceback" not in p.stderr
    p = run_cli("bench", *textures(tmp_path), "--profiles", "9k", "-o", str(tmp_path / "r"))
    assert p.returncode == 2 and "unknown 9k" in p.stderr
    p = run_cli("bench", *textures(tmp_path), "--profiles", "1k", "-o", str(tmp_path / "r2"))
    assert p.returncode == 2 and "larger than its 128-texel textures" in p.stderr


def chromium() -> str | None:
    return next((p for p in (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")) if p), None)


def test_report_opens_in_headless_chromium(report: Path, tmp_path: Path) -> None:
    """Every <img> of index.html loads (naturalWidth > 0) in a real browser."""
    exe = chromium()
    if exe is None:
        pytest.skip("needs chromium (apt-get install chromium)")
    html = (report / R.HTML_FILE).read_text()
    probe = report / "probe.html"
    script = ("<script>window.addEventListener('load', () => { const imgs = [...document.images];"
              "const bad = imgs.filter(i => !i.complete || i.naturalWidth === 0).map(i => i.src);"
              "const p = document.createElement('pre'); p.id = 'probe';"
              "p.textContent = 'images ' + imgs.length + ' missing ' + JSON.stringify(bad);"
              "document.body.appendChild(p); });</script>")
    probe.write_text(html.replace("</body>", script + "</body>"))
    try:
        p = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
                            f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=10000",
                            "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=180)
    finally:
        probe.unlink()
    found = re.search(r'<pre id="probe">images (\d+) missing (.*?)</pre>', p.stdout)
    assert found is not None, p.stderr[-2000:]
    assert int(found.group(1)) == html.count("<img ") == 6 and found.group(2) == "[]", found.group(0)


def test_bench_a_scene_material(tmp_path: Path) -> None:
    """SCENE form: the set of the named material, named after it; an unknown one is one line, exit 2."""
    root = tmp_path / "tex"
    write_png(root / "c.png", pattern(32, 3))
    write_png(root / "r.png", pattern(32, 1, seed=3)[..., 0])
    stage = new_stage(tmp_path / "scene.usda")
    add_material(stage, "/World/Looks/M", {"diffuseColor": ("./tex/c.png", "rgb", {}),
                                           "roughness": ("./tex/r.png", "r", {})}, mesh="/World/Mesh")
    stage.Save()
    p = run_cli("bench", str(tmp_path / "scene.usda"), "--material", "Nope", "-o", str(tmp_path / "r0"))
    assert p.returncode == 2 and "no modelled material Nope" in p.stderr and "Traceback" not in p.stderr
    out = tmp_path / "r"
    p = run_cli("bench", str(tmp_path / "scene.usda"), "--material", "M", "--profiles", "auto", "--presets",
                "smoke", "--baselines", "bc", "--no-half", "--decode-size", "32x18", "--json", "-o", str(out))
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    (s,) = data["sets"]
    assert s["name"] == "/World/Looks/M" and [b["method"] for b in s["baselines"]] == ["BC @32", "BC7 quality @32"]
    assert [c["method"] for c in s["cells"]] == ["BCf auto-32 smoke"]
    assert data == json.loads((out / R.JSON_FILE).read_text())
