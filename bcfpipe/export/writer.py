"""Export one trained material to a folder, and evaluate what was exported.

Folder layout (``material.json`` describes it completely for consumers that do not use bcfpipe):
  T0.dds .. T3.dds   mipmapped BC6H feature layers (mode 11110 blocks), DX10 header
  weights.bin        the decoder as one BCFW v1 fp16 record (see bcfpipe.decoder)
  decoder.onnx       the decoder with output post-processing: features (N, 12) -> channels (N, c_out)
  material.json      everything needed to decode
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from bcfpipe import __version__
from bcfpipe.formats import dds
from bcfpipe.model import neural as M
from bcfpipe.bc6h import decode as bc6h_decode
from bcfpipe.bc6h import mode10
from bcfpipe.config import N_LAYERS, ModelConfig
from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, MlpWeights, from_bytes, normal_xy_index, to_bytes, to_onnx
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.texset.texture_set import Channel, semantic_info

FORMAT = "bcfpipe-material"
FORMAT_VERSION = 1
DESCRIPTION = "material.json"
WEIGHTS = "weights.bin"
ONNX = "decoder.onnx"


def layer_file(i: int) -> str:
    return f"T{i}.dds"


def output_channels(channels: tuple[Channel, ...]) -> list[dict]:
    """Decoder outputs in order, with their UsdPreviewSurface targets; normal z follows normal y."""
    out = []
    for ch in channels:
        usd = semantic_info(ch.semantic).usd_input
        comp = ch.component
        target = None if usd is None else (usd if semantic_info(ch.semantic).channels == 1 else f"{usd}.{comp}")
        lo, hi = ch.value_range
        out.append({"name": ch.name, "semantic": ch.semantic, "component": comp, "kind": ch.kind,
                    "usd_target": target, "range": [lo, hi], "source": ch.source,
                    "source_channel": ch.source_channel, "reconstructed": False})
        if ch.kind == "normal" and comp == "y":
            out.append({"name": f"{ch.semantic}.z", "semantic": ch.semantic, "component": "z", "kind": "normal",
                        "usd_target": "normal.z", "range": [0.0, 1.0], "source": None, "source_channel": None,
                        "reconstructed": True})
    return out


_atomic_write = atomic_write


def export(tm, out_dir: str | os.PathLike, extra: dict | None = None) -> Path:
    """Write a trained material (``bcfpipe.train.TrainedMaterial``) into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mc: ModelConfig = tm.config.model
    ts = tm.texture_set
    layers = []
    for i, layer in enumerate(tm.layers):
        levels = [(mode10.pack(bl.endpoints, bl.indices, bl.partition, signed=mc.signed), bl.size, bl.size)
                  for bl in layer]
        dds.write(out / layer_file(i), levels, signed=mc.signed)
        layers.append({"file": layer_file(i), "resolution": mc.resolutions[i], "mip_count": len(layer),
                       "lod_bias": tm.lod_biases[i], "channels": 3})
    record = to_bytes(tm.mlp)
    _atomic_write(out / WEIGHTS, record)
    _atomic_write(out / ONNX, to_onnx(tm.mlp, tm.kinds).SerializeToString())
    n_in, hidden, n_out = tm.mlp.dims
    desc = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "bcfpipe_version": __version__,
        "layers": layers,
        "bc6h": {"dxgi_format": dds.DXGI_FORMAT_BC6H_SF16 if mc.signed else dds.DXGI_FORMAT_BC6H_UF16,
                 "signed": mc.signed, "block_mode": "11110 (two regions, 6-bit endpoints, 3-bit indices)"},
        "sampling": {
            "addressing": mc.wrap, "filter": "trilinear (LINEAR_MIPMAP_LINEAR), lod clamped to [0, mip_count-1]",
            "uv": "u along width, v along height; v = 0 is the first stored row (for USD st use v = 1 - t)",
            "lod": "s_i = s + lod_bias_i, with s = log2 of the pixel footprint in reference texels",
        },
        "reference": {"width": ts.width, "height": ts.height,
                      "mip_count": max(ts.width, ts.height).bit_length()},
        "mlp": {"weights": WEIGHTS, "offset": 0, "size_bytes": len(record), "n_in": n_in, "n_hidden": hidden,
                "n_out": n_out, "activation": "relu", "precision": "fp16", "record": "BCFW v1",
                "input_order": [f"T{i}.{c}" for i in range(N_LAYERS) for c in "rgb"],
                "out_scale": tm.mlp.out_scale.tolist(), "out_bias": tm.mlp.out_bias.tolist()},
        "outputs": output_channels(ts.channels),
        "onnx": {"file": ONNX, "input": ONNX_INPUT, "output": ONNX_OUTPUT, "opset": 17},
        "training": {"profile_resolutions": list(mc.resolutions), "preset": tm.config.preset_name,
                     "seed": tm.config.seed, "device": tm.config.device,
                     "phase_seconds": {k: round(v, 3) for k, v in tm.phase_seconds.items()}},
    }
    if extra:
        desc.update(extra)
    # digests let `bcfpipe verify` detect any changed byte, which a decode comparison cannot
    # (a flipped index bit still decodes identically on every correct decoder)
    desc["sha256"] = {f: hashlib.sha256((out / f).read_bytes()).hexdigest()
                      for f in [l["file"] for l in layers] + [WEIGHTS, ONNX]}
    _atomic_write(out / DESCRIPTION, (json.dumps(desc, indent=2) + "\n").encode())
    return out


@dataclass(frozen=True)
class ExportedMaterial:
    """An exported material read back from disk: decoded feature levels and the fp16 decoder."""

    desc: dict
    levels: list[list[np.ndarray]]  # per layer, per mip: (H, W, 3) float32 decoded by bcfpipe.bc6h.decode
    weights: MlpWeights
    onnx_path: Path

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(o["kind"] for o in self.desc["outputs"] if not o["reconstructed"])

    @property
    def lod_biases(self) -> tuple[float, ...]:
        return tuple(layer["lod_bias"] for layer in self.desc["layers"])

    @property
    def wrap(self) -> str:
        return self.desc["sampling"]["addressing"]


def load(folder: str | os.PathLike) -> ExportedMaterial:
    """Read an exported material folder back (DDS through bcfpipe.bc6h.decode, fp16 weights)."""
    folder = Path(folder)
    desc = json.loads((folder / DESCRIPTION).read_text())
    if desc.get("format") != FORMAT:
        raise ValueError(f"{folder / DESCRIPTION}: not a bcfpipe material description")
    levels = []
    for layer in desc["layers"]:
        tex = dds.read(folder / layer["file"])
        levels.append([bc6h_decode(b, w, h, signed=tex.signed).astype(np.float32) for b, w, h in tex.levels])
    m = desc["mlp"]
    data = (folder / m["weights"]).read_bytes()
    weights, _ = from_bytes(data, m.get("offset", 0))
    return ExportedMaterial(desc, levels, weights, folder / desc["onnx"]["file"])


def sample_exported_features(em: ExportedMaterial, uv: np.ndarray, s: float | np.ndarray) -> np.ndarray:
    """Feature vectors (N, 12) sampled from the decoded DDS levels with the hardware conventions."""
    levels = [[torch.from_numpy(np.ascontiguousarray(np.moveaxis(l, -1, 0))) for l in layer] for layer in em.levels]
    lvl = M.cached_level_fn(levels)
    s_t = torch.as_tensor(s, dtype=torch.float32) if isinstance(s, np.ndarray) else float(s)
    with torch.no_grad():
        f = M.sample_features(lvl, [len(l) for l in levels], em.lod_biases, torch.from_numpy(uv.astype(np.float32)),
                              s_t, em.wrap)
    return f.numpy()


def onnx_session(em: ExportedMaterial):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    return ort.InferenceSession(str(em.onnx_path), so, providers=["CPUExecutionProvider"])


def decode_mips(em: ExportedMaterial, ref_shapes: list[tuple[int, int]], chunk: int = 1 << 18,
                drop_normal_z: bool = True) -> list[np.ndarray]:
    """The exported material decoded through onnxruntime at each reference mip's texel centres
    (s = mip index) -> [(H, W, c)]; normal z is dropped unless asked for."""
    sess = onnx_session(em)
    kinds = em.kinds
    nz = normal_xy_index(kinds)
    out = []
    for k, (h, w) in enumerate(ref_shapes):
        ys, xs = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
        uv = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
        parts = []
        for a in range(0, uv.shape[0], chunk):
            feats = sample_exported_features(em, uv[a:a + chunk], float(k))
            y = sess.run([ONNX_OUTPUT], {ONNX_INPUT: feats})[0]
            if drop_normal_z and nz is not None:
                y = np.delete(y, nz + 2, axis=1)
            parts.append(y)
        out.append(np.concatenate(parts).reshape(h, w, -1))
    return out
