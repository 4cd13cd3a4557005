"""Export one trained material to a folder, and evaluate what was exported.

Folder layout (``material.json`` describes it completely for consumers that do not use bcfpipe):
  T0.dds .. T3.dds   mipmapped feature layers, DX10 header: BC6H mode 11110 blocks (3 channels), or
                     BC7 mode 6 blocks (4 channels) with --features bc7; a fixed T_0 (--t0 pca) in any
                     BC7 mode. A T_0 of two or three layers of principal components (ModelConfig.t0_layers,
                     issue 52) adds T0b.dds (components 4-7) and T0c.dds (8-11), at T_0's resolution and
                     lod bias, before T1.dds: the MLP reads T0, T0b(, T0c), T1, T2, T3 in that order, as
                     material.json's ``layers`` list them (its ``layers[i].file`` is authoritative; format 6)
  weights.bin        the decoder as one BCFW fp16 record (v1; v2 with HDR channels; bcfpipe.model.decoder)
  decoder.onnx       the decoder with output post-processing: features (N, n_in) -> channels (N, c_out),
                     n_in = 4 (BC7) or 3 (BC6H) per layer
  material.json      everything needed to decode (bcfpipe.formats.material, schemas/material.schema.json)

Reading a folder back imports torch only for its feature layers: a classic layout's textures are
filtered in numpy (`bcfpipe.formats.filtering`), so measuring one needs no torch.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np

from bcfpipe.formats import dds
from bcfpipe.formats.bcn import FORMAT_OF, decode_levels
from bcfpipe.formats.digest import sha256_file
from bcfpipe.formats import material as mf
from bcfpipe.bc6h import decode as bc6h_decode
from bcfpipe.bc6h import mode10
from bcfpipe.bc7 import decode as bc7_decode
from bcfpipe.bc7.mode6 import DESCRIPTION as BC7_MODE
from bcfpipe.config import ModelConfig
from bcfpipe.formats.vocabulary import FeatureFormat
from bcfpipe.formats.filtering import trilinear, whole_level
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset.texture_set import Channel, semantic_info

if TYPE_CHECKING:
    from bcfpipe.model.decoder import MlpWeights


def output_channels(channels: tuple[Channel, ...]) -> tuple[mf.Output, ...]:
    """Decoder outputs in order, with their UsdPreviewSurface targets; normal z follows normal y."""
    out = []
    for ch in channels:
        usd = semantic_info(ch.semantic).usd_input
        comp = ch.component
        target = None if usd is None else (usd if semantic_info(ch.semantic).channels == 1 else f"{usd}.{comp}")
        lo, hi = ch.value_range
        out.append(mf.Output(ch.name, ch.semantic, comp, ch.kind, target, (lo, hi), ch.source_channel,
                             ch.source_format or None, reconstructed=False, value_scale=float(ch.value_scale),
                             value_bias=float(ch.value_bias), log_gain=float(ch.log_gain) if ch.log_gain else None))
        if ch.kind == "normal" and comp == "y":
            out.append(mf.Output(f"{ch.semantic}.z", ch.semantic, "z", "normal", "normal.z", (0.0, 1.0), None, None,
                                 reconstructed=True))
    return tuple(out)


def export(tm, out_dir: str | os.PathLike) -> Path:
    """Write a trained material (``bcfpipe.train.TrainedMaterial``) into ``out_dir``; material.json
    last, so a folder with one is complete. Nothing in it depends on paths or times: the same
    training gives the same bytes (the build's cache relies on it)."""
    from bcfpipe.model.decoder import to_bytes, to_onnx  # lazy: start-up
    from bcfpipe.model.features import codec_of  # lazy: start-up

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mc: ModelConfig = tm.config.model
    ts = tm.texture_set
    codec = codec_of(mc)
    layers = []
    packed = tm.layers.each(lambda lv: (lv.blocks, lv.size, lv.size),  # a fixed level's blocks as encoded
                            lambda q, i, k: (codec.pack(q, mc), q.size, q.size))
    for i, levels in enumerate(packed):
        name = mf.layer_file(i, mc.t0_layers)
        dds.write(out / name, levels, signed=mc.signed, dxgi_format=codec.dxgi_format(mc))
        layers.append(mf.Layer(name, mc.layer_resolutions[i], len(levels), tm.lod_biases[i], codec.channels,
                               mf.ANY_BC7_MODE if i in tm.layers.fixed else None))  # a fixed T_0 is in any BC7 mode
    bc7 = FeatureFormat(mc.features) == FeatureFormat.BC7
    record = to_bytes(tm.mlp)
    atomic_write(out / mf.WEIGHTS, record)
    atomic_write(out / mf.ONNX, to_onnx(tm.mlp, tm.kinds).SerializeToString())
    n_in, hidden, n_out = tm.mlp.dims
    desc = mf.MaterialFile(
        layers=tuple(layers),
        bc6h=None if bc7 else mf.BC6H(codec.dxgi_format(mc), mc.signed, mode10.DESCRIPTION),
        bc7=mf.BC7(codec.dxgi_format(mc), BC7_MODE) if bc7 else None,
        sampling=mf.Sampling.of(mc.wrap),
        reference=mf.Reference(ts.width, ts.height, max(ts.width, ts.height).bit_length()),
        mlp=mf.Mlp(mf.WEIGHTS, 0, len(record), n_in, hidden, n_out, "relu", "fp16", f"BCFW v{tm.mlp.version}",
                   tuple(f"{mf.layer_name(i, mc.t0_layers)}.{c}" for i in range(mc.n_layers)
                         for c in "rgba"[:codec.channels]),
                   tuple(tm.mlp.out_scale.tolist()), tuple(tm.mlp.out_bias.tolist())),
        outputs=output_channels(ts.channels),
        onnx=mf.Onnx(mf.ONNX, mf.ONNX_INPUT, mf.ONNX_OUTPUT, 17),
        training=mf.Training(tuple(mc.resolutions), tm.config.preset_name, tm.config.seed,
                             str(tm.config.device).split(":")[0]))
    # digests let `bcfpipe verify` detect any changed byte, which a decode comparison cannot
    # (a flipped index bit still decodes identically on every correct decoder)
    desc = replace(desc, sha256={f: sha256_file(out / f) for f in desc.files})
    mf.write(out, desc)
    return out


@dataclass(frozen=True)
class ExportedMaterial:
    """An exported material read back from disk: decoded feature levels and the fp16 decoder."""

    desc: mf.MaterialFile
    levels: list[list[np.ndarray]]  # per layer, per mip: (H, W, C) float32 from the spec decoder (bc6h / bc7)
    weights: MlpWeights | None  # None when no output comes from the MLP (a classic-only layout)
    onnx_path: Path | None
    classic: list[list[np.ndarray]] = field(default_factory=list)  # per classic texture, per mip: texels in [0, 1]

    @property
    def kinds(self) -> tuple[str, ...]:
        return self.desc.kinds

    @property
    def lod_biases(self) -> tuple[float, ...]:
        return self.desc.lod_biases

    @property
    def wrap(self) -> tuple[str, str]:
        """(S, T) addressing."""
        return self.desc.wrap


def load(folder: str | os.PathLike) -> ExportedMaterial:
    """Read an exported material folder back (DDS through bcfpipe.bc6h or bcfpipe.bc7's decoder,
    fp16 weights)."""
    folder = Path(folder)
    desc = mf.read(folder)
    levels = []
    for layer in desc.layers:
        tex = dds.read(folder / layer.file)
        if tex.dxgi_format not in (dds.DXGI_FORMAT_BC6H_UF16, dds.DXGI_FORMAT_BC6H_SF16, dds.DXGI_FORMAT_BC7_UNORM):
            raise dds.DdsError(f"{folder / layer.file}: {tex.format_name} is no feature-layer format")
        if tex.is_bc7:
            levels.append([bc7_decode(b, w, h)[..., :layer.channels] for b, w, h in tex.levels])
        else:
            levels.append([bc6h_decode(b, w, h, signed=tex.signed).astype(np.float32) for b, w, h in tex.levels])
    classic = []
    for c in desc.classic:
        tex = dds.read(folder / c.file)
        if tex.dxgi_format not in FORMAT_OF or tex.dxgi_format != c.dxgi_format:
            raise dds.DdsError(f"{folder / c.file}: {tex.format_name}, where material.json says {c.format}")
        classic.append([t[..., :c.channels] for t in decode_levels(FORMAT_OF[tex.dxgi_format], tex.levels)])
    if desc.mlp is None:
        return ExportedMaterial(desc, levels, None, None, classic)
    from bcfpipe.model.decoder import from_bytes  # lazy: start-up

    weights, _ = from_bytes((folder / desc.mlp.weights).read_bytes(), desc.mlp.offset)
    return ExportedMaterial(desc, levels, weights, folder / desc.onnx.file, classic)


def sample_exported_features(em: ExportedMaterial, uv: np.ndarray, s: float | np.ndarray) -> np.ndarray:
    """Feature vectors (N, n_in) sampled from the decoded DDS levels with the hardware conventions:
    every layer material.json lists, in its order (3 or 4 channels each)."""
    import torch  # lazy: start-up
    from bcfpipe.model import neural as M  # lazy: start-up

    levels = [[torch.from_numpy(np.ascontiguousarray(np.moveaxis(l, -1, 0))) for l in layer] for layer in em.levels]
    lvl = M.cached_level_fn(levels)
    s_t = torch.as_tensor(s, dtype=torch.float32) if isinstance(s, np.ndarray) else float(s)
    with torch.no_grad():
        f = M.sample_features(lvl, [len(l) for l in levels], em.lod_biases, torch.from_numpy(uv.astype(np.float32)),
                              s_t, em.wrap)
    return f.numpy()


def onnx_session(em: ExportedMaterial):
    # onnxruntime otherwise writes a device id and a telemetry database under ~/.cache/Microsoft:
    # bcfpipe writes only to OUT and its cache
    os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")
    import onnxruntime as ort  # lazy: start-up

    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    trace_pool("onnxruntime", so.intra_op_num_threads)
    return ort.InferenceSession(str(em.onnx_path), so, providers=["CPUExecutionProvider"])


def decode_mips(em: ExportedMaterial, ref_shapes: list[tuple[int, int]], chunk: int = 1 << 18,
                drop_normal_z: bool = True, on_chunk: Callable[[int, int], None] | None = None,
                texels: Sequence[np.ndarray | None] | None = None) -> list[np.ndarray]:
    """The exported material decoded at each reference mip's texel centres (s = mip index) ->
    [(H, W, c)], every output in material.json's order: the decoder's through onnxruntime, a
    classic output from its texture (trilinear, like the layers); normal z is dropped unless asked
    for. ``on_chunk(k, texels)`` hears each chunk decoded: its mip and its texels (for progress).
    ``texels``: per mip, the texels to decode, row-major indices (None: all), giving (n, 1, c)."""
    sess = onnx_session(em) if em.desc.mlp is not None else None
    outputs = em.desc.outputs
    mlp_cols = [i for i, o in enumerate(outputs) if o.source != mf.Source.CLASSIC]
    keep = [i for i, o in enumerate(outputs) if not (drop_normal_z and o.reconstructed)]
    out = []
    for k, (h, w) in enumerate(ref_shapes):
        picked = None if texels is None or texels[k] is None else np.asarray(texels[k])
        n = h * w if picked is None else len(picked)
        whole = _whole_levels(em, float(k), h, w) if picked is None else None
        level = np.empty((n, len(keep)), np.float32)
        for a in range(0, n, chunk):  # texel-centre uvs made per chunk: O(chunk) scratch at 8K
            m = min(chunk, n - a)
            uv = None
            if sess is not None or whole is None:
                ids = np.arange(a, a + m) if picked is None else picked[a:a + chunk]
                uv = np.stack([(ids % w + 0.5) / w, (ids // w + 0.5) / h], 1).astype(np.float32)
            y = np.empty((m, len(outputs)), np.float32)
            if sess is not None:
                y[:, mlp_cols] = sess.run([mf.ONNX_OUTPUT], {mf.ONNX_INPUT: sample_exported_features(em, uv, float(k))})[0]
            if em.classic:
                samples = None if whole is None else np.concatenate([t[a:a + m] for t in whole], 1)
                classic_outputs(em, uv, float(k), y, samples)
            level[a:a + m] = y[:, keep]
            if on_chunk is not None:
                on_chunk(k, m)
        out.append(level.reshape(h, w, -1) if picked is None else level[:, None])
    return out


def split_weight(split: int, s: float) -> float:
    """How much of a split output is the MLP's at lod ``s``: 0 up to split - 1, 1 from split on,
    linear between (material.json ``split``)."""
    return float(min(1.0, max(0.0, s - (split - 1))))


def _unslope(outputs, v: dict) -> None:
    """A normal stored as slopes (material.json encoding "slope"): its x and y columns of ``v`` (s_x,
    s_y) become the unit normal's, (s_x, s_y, 1) normalised, as a UsdPreviewSurface reads it."""
    by_semantic: dict[str, list[int]] = {}
    for i in v:
        if outputs[i].encoding == mf.SLOPE:
            by_semantic.setdefault(outputs[i].semantic, []).append(i)
    for ix, iy in by_semantic.values():
        inv = 1.0 / np.sqrt(1.0 + v[ix] * v[ix] + v[iy] * v[iy])
        v[ix], v[iy] = v[ix] * inv, v[iy] * inv


def _whole_levels(em: ExportedMaterial, s: float, height: int, width: int) -> list[np.ndarray] | None:
    """Per classic texture, what sampling every texel centre of an (H, W) mip at lod ``s`` reads,
    when each reads a level of its own texel for texel (`filtering.whole_level`), else None."""
    whole = [whole_level(tex, s + c.lod_bias, height, width) for tex, c in zip(em.classic, em.desc.classic)]
    return None if any(t is None for t in whole) else whole


def classic_outputs(em: ExportedMaterial, uv: np.ndarray | None, s: float, y: np.ndarray,
                    samples: np.ndarray | None = None) -> None:
    """Fill the classic outputs' columns of ``y`` (N, outputs): each texture sampled trilinearly at
    s + its lod_bias (lod clamped to its mips, so below 0 level 0 is magnified), value = texel *
    texel_scale + texel_bias clamped to the output's range (a normal stored as slopes: (s_x, s_y, 1)
    normalised first, `_unslope`); a normal's z from its x and y. A split
    output's column, which holds the MLP's value, becomes the two mixed by `split_weight`.
    ``samples``: the textures' samples at ``uv``, side by side, when the caller has them (a whole
    level read texel for texel: `_whole_levels`; then ``uv`` may be None)."""
    desc = em.desc
    w = split_weight(desc.split, s) if desc.split is not None else 1.0
    # the outputs this fills: every classic one; a split one unless the MLP's value stands alone
    mine = [o.source == mf.Source.CLASSIC or (o.source == mf.Source.SPLIT and w < 1.0) for o in desc.outputs]
    if not any(mine):  # a split material from its split on: no texture to sample
        return
    t = samples if samples is not None else \
        np.concatenate([trilinear(tex, uv, s + c.lod_bias, desc.wrap) for tex, c in zip(em.classic, desc.classic)], 1)
    first = np.cumsum([0] + [c.channels for c in desc.classic])
    v = {i: t[:, first[o.texture] + o.texel_channel] * o.texel_scale + o.texel_bias
         for i, o in enumerate(desc.outputs) if mine[i] and not o.reconstructed}
    _unslope(desc.outputs, v)
    for i, vi in v.items():
        vi = np.clip(vi, *desc.outputs[i].range)
        y[:, i] = vi if desc.outputs[i].source == mf.Source.CLASSIC else (1.0 - w) * vi + w * y[:, i]
    for i, o in enumerate(desc.outputs):
        if mine[i] and o.reconstructed:  # normal z after its x and y (a split one's: of the mixed x and y)
            x, yy = y[:, i - 2], y[:, i - 1]
            y[:, i] = np.sqrt(np.maximum(0.0, 1.0 - x * x - yy * yy))
