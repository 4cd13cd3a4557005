"""One bench cell: a BCf (profile, preset) or a classic baseline, measured with the same metric code.

A BCf cell trains, exports, and is measured from the exported files (BC6H DDS + fp16 decoder
through onnxruntime), as `bcfpipe train` does. A baseline cell encodes and decodes every mip of
the texture set with a classic codec (bcfpipe.texset.baselines): BC@R, the BC7 quality set beside
it, ASTC. Both keep what the report needs beyond the metrics: a lod sweep, the decoded texels of
the crop windows, and their sizes twice (issue 52): GPU bytes and bytes on disk, each shipped file
zstd-compressed at `formats.sizes.DISK_ZSTD_LEVEL`, as games ship BC textures.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from bcfpipe.export import writer as E
from bcfpipe.export.material import shipped_disk_bytes
from bcfpipe.fit import fit
from bcfpipe.formats.bcn import DXGI, ClassicFormat
from bcfpipe.formats.dds import encode_header
from bcfpipe.formats.sizes import disk_bytes
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.bench import lod_sweep as L
from bcfpipe.texset.baselines import BC7_QUALITY, encode_texture_set_baseline
from bcfpipe.texset.baselines import parse_block
from bcfpipe.texset.baselines import bilinear_up, slope_mips
from bcfpipe.texset.normals import angular_stats, rebuild_z
from bcfpipe.texset.normals import angular_stats, rebuild_z, unit
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.texset.metrics import Metrics, compute_metrics

__all__ = ["Baseline", "Cell", "baseline_grid", "measure_baseline", "train_cell", "Windows", "blocks_disk_bytes", "texture_files",
           "files_disk_bytes"]

# (mip, x, y, side) of each crop window; a cell keeps its decoded texels there
Windows = Sequence[tuple[int, int, int, int]]
CURVE_POINTS = 200
ENCODERS = {"bc": "quicktex (BC1 level 18, BC4, BC5)", BC7_QUALITY: "ISPC BC7 (alpha_basic) for BC1; quicktex BC4, BC5",
            "astc": "astcenc -thorough, LDR linear"}


@dataclass(frozen=True)
class Baseline:
    """A classic encoding of the set: ``codec`` 'bc' (BC1/BC4/BC5 as an engine packs the set),
    `BC7_QUALITY` (the same with BC7 for BC1: the BC7 quality set) or 'astc' with ``block``, at the
    set's resolution divided by 2**``shift``."""

    codec: str
    block: str | None
    shift: int

    def label(self, side: int) -> str:
        name = {"bc": "BC", BC7_QUALITY: "BC7 quality"}.get(self.codec, f"ASTC {self.block}")
        return f"{name} @{side >> self.shift}"


def baseline_grid(codecs: Sequence[str], astc_blocks: Sequence[str], shifts: Sequence[int],
                  bc_shifts: Sequence[int] = ()) -> list[Baseline]:
    """Every requested codec at every resolution step: BC once and the BC7 quality set beside it,
    ASTC once per block size; BC and the quality set also at ``bc_shifts`` (the BCf cells' R)."""
    out = []
    for shift in sorted({*shifts, *bc_shifts}):
        for codec in codecs if shift in shifts else [c for c in codecs if c == "bc"]:
            blocks = astc_blocks if codec == "astc" else (None,)
            out.extend(Baseline(codec, b, shift) for b in blocks)
            if codec == "bc":
                out.append(Baseline(BC7_QUALITY, None, shift))
    return out


def texture_files(textures: Sequence, astc_block: str | None = None) -> list[bytes]:
    """The files of the shipped ``textures`` ((format, channels, [(blocks, w, h) per level])): a BC
    texture is one DDS file of every level (`formats.dds` header, then the blocks, as `dds.write`
    writes it); with ``astc_block``, each ASTC level is one .astc file (16-byte header, then the blocks)."""
    if astc_block is None:
        return [encode_header(lv[0][1], lv[0][2], len(lv), False, DXGI[ClassicFormat(fmt)])
                + b"".join(np.ascontiguousarray(b).tobytes() for b, _, _ in lv) for fmt, _, lv in textures]

    bw, bh = parse_block(astc_block)
    return [bytes([0x13, 0xAB, 0xA1, 0x5C, bw, bh, 1]) + w.to_bytes(3, "little") + h.to_bytes(3, "little")
            + (1).to_bytes(3, "little") + np.ascontiguousarray(b).tobytes() for _, _, lv in textures for b, w, h in lv]


def blocks_disk_bytes(textures: Sequence, astc_block: str | None = None) -> int:
    """Bytes on disk of the shipped ``textures``: each of their files (`texture_files`) zstd-compressed
    whole (`formats.sizes.disk_bytes`), as the export writes them and layout.json counts them."""
    return disk_bytes(texture_files(textures, astc_block))


def files_disk_bytes(folder: Path) -> int:
    """Bytes on disk of an exported material's shipped files (`export.material.shipped_disk_bytes`)."""
    return shipped_disk_bytes(folder)


@dataclass
class Cell:
    """A measured cell; ``json`` is what the report and its data file keep."""

    method: str
    kind: str  # "bcf", "bc", BC7_QUALITY or "astc"
    metrics: Metrics
    size_bytes: int  # GPU bytes: a baseline's blocks; a BCf cell's shipped files
    seconds: float  # BCf: training wall time; baselines: encode + decode
    sweep: list[float]
    crops: list[np.ndarray]  # one (side, side, c) array per window
    extra: dict = field(default_factory=dict)
    textures: list | None = None  # a BC baseline's blocks, for the decode-cost pass
    folder: Path | None = None  # a BCf cell's exported material
    disk_bytes: int | None = None  # its files on disk, zstd-compressed (`blocks_disk_bytes`, `files_disk_bytes`)

    def to_json(self) -> dict:
        m = self.metrics
        disk = self.disk_bytes
        return {"method": self.method, "kind": self.kind, **self.extra, "size_bytes": self.size_bytes,
                "size_mib": self.size_bytes / 2**20, "disk_bytes": disk,
                "disk_mib": None if disk is None else disk / 2**20, "psnr": m.psnr, "psnr_per_mip": list(m.psnr_per_mip),
                "psnr_per_group": dict(m.psnr_per_group), "ssim": m.ssim, "flip": m.flip, "seconds": self.seconds,
                "lod_sweep": self.sweep}


def normal_angle(ts: TextureSet, ref: np.ndarray, dec: np.ndarray) -> dict:
    """``{"normal_angle_deg": {"mean", "p99"}}``: the angle at mip 0 between the set's normal map and
    the decoded one, both with z rebuilt from x, y as engines (and bcfpipe's decoder) read them
    (issue 57: beside the PSNR, which measures x and y only); {} without a normal map."""
    xy = [i for i, c in enumerate(ts.channels) if c.kind == "normal"]
    if len(xy) != 2:
        return {}
    mean, p99 = angular_stats(rebuild_z(ref[..., xy]), rebuild_z(dec[..., xy]))
    return {"normal_angle_deg": {"mean": round(mean, 3), "p99": round(p99, 3)}}


def shipped_normal_angle(ts: TextureSet, ref: Sequence[np.ndarray], shift: int) -> dict:
    """``{"normal_angle_deg_shipped": {"mean", "p99", "m"}}``: BC@R's normal as a layout ships it for
    USD (BC5 of its slopes, `baselines.slope_mips`, read as (s_x, s_y, 1) normalised; level 0 at R
    magnified to mip 0 as the baseline is), beside the cell's BC5 with z rebuilt (issue 57); {}
    without a normal map."""
    xy = [i for i, c in enumerate(ts.channels) if c.kind == "normal"]
    if len(xy) != 2:
        return {}
    k = min(shift, len(ref) - 1)
    normals, m, _ = slope_mips([r[..., xy] for r in ref[k:k + 1]])
    seen = unit(bilinear_up(normals[0], *ref[0].shape[:2])) if k else normals[0]
    mean, p99 = angular_stats(rebuild_z(ref[0][..., xy]), seen)
    return {"normal_angle_deg_shipped": {"mean": round(mean, 3), "p99": round(p99, 3), "m": round(m, 4)}}


def _crops(mips: Sequence[np.ndarray], windows: Windows) -> list[np.ndarray]:
    return [np.array(mips[k][y:y + n, x:x + n]) for k, x, y, n in windows]


def measure_baseline(ts: TextureSet, ref: Sequence[np.ndarray], b: Baseline, grid: L.LodGrid, windows: Windows,
                     tmp_dir: str | None = None) -> Cell:
    """Encode and decode every mip with baseline ``b``; metrics, lod sweep and crops of the result."""
    side = max(ts.width, ts.height)
    textures: list = []
    t0 = time.perf_counter()
    dec, size = encode_texture_set_baseline(ts, b.codec, side >> b.shift, ref_mips=ref,
                                            astc_block=b.block or "12x12", textures=textures, tmp_dir=tmp_dir)
    seconds = time.perf_counter() - t0
    metrics = compute_metrics(ref, dec, ts.channels)
    sweep = L.sweep(grid, L.mips_answer(dec, grid.wrap))
    extra = {"codec": b.codec, "block": b.block, "resolution": side >> b.shift, "encoder": ENCODERS[b.codec],
             "formats": [fmt for fmt, _, _ in textures], **normal_angle(ts, ref[0], dec[0]),
             **(shipped_normal_angle(ts, ref, b.shift) if b.codec == "bc" else {})}
    disk = blocks_disk_bytes(textures, b.block if b.codec == "astc" else None)
    return Cell(b.label(side), b.codec, metrics, size, seconds, sweep, _crops(dec, windows), extra,
                textures if b.codec == "bc" and b.shift == 0 else None, disk_bytes=disk)


def train_cell(ts: TextureSet, ref: Sequence[np.ndarray], options, out_dir: Path, grid: L.LodGrid,
               windows: Windows, *, wrap: str = Wrap.REPEAT, progress: Callable[[float], None] | None = None) -> Cell:
    """Train BCf as ``options`` (a `config.TrainingOptions` with its profile, preset and features;
    all neural) ask into ``out_dir``; measure the exported files. A bc7 cell's method name ends in
    " bc7"."""
    preset, features = options.preset, options.features.value
    curve: list[tuple[float, float]] = []

    def on_progress(p) -> None:
        if np.isfinite(p.psnr):
            curve.append((round(p.elapsed, 2), round(p.psnr, 3)))
        if progress is not None and p.steps:
            progress(min(1.0, (p.elapsed / max(p.elapsed + p.eta, 1e-9))))

    res = fit(ts, options, out_dir, wrap=wrap, progress=on_progress).result
    name = res.profile
    dec = E.decode_mips(E.load(out_dir), [m.shape[:2] for m in ref])
    crops = _crops(dec, windows)
    angle = normal_angle(ts, ref[0], dec[0])
    del dec
    sweep = L.sweep(grid, L.exported_answer(out_dir))
    step = max(1, len(curve) // CURVE_POINTS)
    extra = {"profile": name, "preset": preset, "features": features, "resolutions": list(res.resolutions), "device": res.device,
             "train_seconds": res.train_seconds,
             "float_psnr": res.float_metrics.psnr if res.float_metrics is not None else None, **angle,
             "training_curve": curve[::step] + ([curve[-1]] if curve and (len(curve) - 1) % step else [])}
    return Cell(f"BCf {name} {preset}" + ("" if features == "bc6h" else f" {features}"), "bcf", res.metrics,
                res.size_bytes, res.train_seconds, sweep, crops, extra, folder=Path(out_dir),
                disk_bytes=files_disk_bytes(Path(out_dir)))
