"""The normal map as a UsdPreviewSurface reads it from a layout's classic normal (issue 57, item 3):
mean and p99 angle against the source, beside BC5 with z rebuilt as engines read it.

For each set's normal map, at R (the source's side: the default `--profile auto`, or
``--resolution``):

* **BC5 slopes (shipped)**: the layout's BC@R normal (`bcfpipe.layout.classic.encode`: BC5 of
  clip(s / m) / 2 + 1 / 2, s = (x / z, y / z), m the 0.999 quantile of |s| at level 0), written as
  the export writes it (a DX10 DDS), read back with OpenImageIO, the USD layer's scale and bias
  (r, g: 2m / M, -m / M; b: 0, 1 / M; M = max(m, 1)) applied, normalised;
* **BC7 x, y, z**: x, y and the rebuilt z in BC7 (ISPC at the project's BC7 preset), read with scale 2
  and bias -1 on r, g, b, normalised (what the layout shipped before the slopes);
* **BC5, z rebuilt**: the same x, y in BC5 (quicktex, as `bench`'s BC@R has it),
  z = sqrt(1 - x² - y²), as engines read it;
* **BC5, z = 1**: what the USD layer gave a UsdPreviewSurface before issue 57 (scale 0, bias 1 on z);
* **source x, y, z rebuilt**: no compression: how far the source's own z is from its x, y's.

The reference is the source file's r, g, b as 2v - 1, normalised, at its own resolution (R below
it: its mip at R, box-filtered as bcfpipe builds mips). Bytes: every mip's blocks plus the header.

    .venv/bin/python benchmarks/bench_normal_usd.py [--resolution 1024] [NORMAL_MAP ...]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import SHARED, machine  # noqa: E402

SETS = {"brick": SHARED / "materialx_texture_sets" / "brick" / "brick_normal.jpg",
        "water bottle": SHARED / "gltf_water_bottle" / "WaterBottle_normal.png"}


def source_normals(path: Path, mip: int) -> np.ndarray:
    """The source's r, g, b as 2v - 1 at reference mip ``mip``, normalised."""
    import OpenImageIO as oiio

    from bcfpipe.texset.normals import unit
    from bcfpipe.texset.texture_set import build_mip_chain

    rgb = np.asarray(oiio.ImageBuf(str(path)).get_pixels(oiio.FLOAT), np.float32)[..., :3]
    return unit(build_mip_chain(rgb)[mip] * 2.0 - 1.0)


def oiio_texels(path: Path) -> np.ndarray:
    """Level 0 of a DDS as OpenImageIO decodes it, (h, w, channels) in [0, 1]."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    if buf.has_error:
        raise SystemExit(f"OpenImageIO cannot read {path}: {buf.geterror()}")
    return np.asarray(buf.get_pixels(oiio.FLOAT), np.float32)


def measure(name: str, path: Path, resolution: int | None) -> list[tuple[str, float, float, int, float]]:
    """(candidate, mean°, p99°, bytes, seconds) for one normal map."""
    from bcfpipe.formats import dds
    from bcfpipe.formats.bcn import DXGI
    from bcfpipe.layout import classic as C
    from bcfpipe.texset.baselines import bc5_mips, bc7_mips
    from bcfpipe.texset.normals import angular_stats, rebuild_z, stored_xyz, usd_normal
    from bcfpipe.texset.texture_set import TextureSpec, build_mip_chain, load_texture_set

    ts = load_texture_set([TextureSpec("normal", str(path), "xy")])
    side = max(ts.width, ts.height)
    r = resolution or side
    mip = int(round(np.log2(side / r)))
    ref_mips = build_mip_chain(ts.data)
    truth = source_normals(path, mip)
    rows = []
    t = time.perf_counter()
    (group,) = C.encode(ts, r, ref_mips)
    assert group.group.slope and group.slope is not None
    m = group.slope
    big = max(m, 1.0)  # the USD layer's scale and bias (bcfpipe.builder.usd_classic)
    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / "C0.dds"
        dds.write(f, group.levels, dxgi_format=DXGI[group.group.format])
        shipped = usd_normal(oiio_texels(f), (2 * m / big, 2 * m / big, 0.0), (-m / big, -m / big, 1 / big))
        size = f.stat().st_size
    rows.append((f"BC5 slopes (shipped, m = {m:.2f}) as USD reads it", *angular_stats(truth, shipped), size,
                 time.perf_counter() - t))
    t = time.perf_counter()
    blocks: list = []
    dec, _ = bc7_mips([np.concatenate([stored_xyz(x), np.ones_like(x[..., :1])], -1) for x in ref_mips[mip:]], blocks)
    rows.append(("BC7 x, y, z as USD reads it", *angular_stats(truth, usd_normal(dec[0])),
                 dds.HEADER_BYTES + sum(b.nbytes for b, _, _ in blocks), time.perf_counter() - t))
    t = time.perf_counter()
    blocks = []
    dec, _ = bc5_mips([(x + 1.0) * 0.5 for x in ref_mips[mip:]], blocks)
    xy = dec[0] * 2.0 - 1.0
    bc5 = dds.HEADER_BYTES + sum(b.nbytes for b, _, _ in blocks)
    rows.append(("BC5, z rebuilt (engines)", *angular_stats(truth, rebuild_z(xy)), bc5, time.perf_counter() - t))
    rows.append(("BC5, z = 1 (USD before)", *angular_stats(truth, np.concatenate([xy, np.ones_like(xy[..., :1])], -1)),
                 bc5, 0.0))
    rows.append(("source x, y, z rebuilt", *angular_stats(truth, rebuild_z(ref_mips[mip])), 0, 0.0))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("maps", nargs="*", help="normal maps (default: the brick's and the water bottle's)")
    ap.add_argument("--resolution", type=int, default=None, help="R (default: the source's side)")
    a = ap.parse_args()
    sets = {Path(p).stem: Path(p) for p in a.maps} if a.maps else SETS
    missing = [str(p) for p in sets.values() if not p.is_file()]
    if missing:
        raise SystemExit(f"needs {', '.join(missing)} (the shared scenes at {SHARED})")
    print(f"# {machine()}")
    print("| set | R | candidate | mean ° | p99 ° | bytes | s |")
    print("|---|---|---|---|---|---|---|")
    for name, path in sets.items():
        for cand, mean, p99, size, secs in measure(name, path, a.resolution):
            print(f"| {name} | {a.resolution or 'source'} | {cand} | {mean:.2f} | {p99:.2f} | {size or ''} | {secs:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
