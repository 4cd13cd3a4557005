"""The decoder MLP f_eta (paper eq. 2) and its portable forms: fp16 weight records and ONNX.

Output post-processing, identical in torch, ONNX and GLSL:
  y = clamp(mlp(features) * out_scale + out_bias, lo, hi)   per channel
  lo, hi = (-1, 1) for normal x/y, (0, 1) otherwise
  y = (exp2(log_gain * y) - 1) * (1 / (exp2(log_gain) - 1))  where log_gain > 0 (HDR channels
      learnt in a log domain, bcfpipe.texset.encoding; version 2 records only)
  normal z = sqrt(max(0, 1 - x^2 - y^2)) is appended right after normal y.

The weight record (``BCFW``) that holds them, one per material and inside a build's combined
buffer, is laid out in `bcfpipe.formats.weights`: version 1, or version 2 when a channel is HDR
(its log_gain array); a decoder without HDR channels is written as version 1, byte for byte what
it always was. fp16 value e sits in 32-bit word (24/4 + e/2), low half when e is even.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from bcfpipe.formats.material import ONNX_INPUT, ONNX_OUTPUT
from bcfpipe.formats.weights import (RECORD_HEADER as HEADER, RECORD_MAGIC as MAGIC, RECORD_VERSION as VERSION,
                                     RECORD_VERSION_LOG as VERSION_LOG, record_values)

HEADER_BYTES = HEADER.size  # 24



@dataclass(frozen=True)
class MlpWeights:
    """Decoder parameters as float32 numpy arrays (values exactly representable in fp16 once rounded)."""

    w1: np.ndarray  # (hidden, n_in)
    b1: np.ndarray  # (hidden,)
    w2: np.ndarray  # (n_out, hidden)
    b2: np.ndarray  # (n_out,)
    out_scale: np.ndarray  # (n_out,)
    out_bias: np.ndarray  # (n_out,)
    log_gain: np.ndarray | None = None  # (n_out,): 0 linear, > 0 the HDR log domain; None: all linear

    @property
    def dims(self) -> tuple[int, int, int]:
        return self.w1.shape[1], self.w1.shape[0], self.w2.shape[0]

    @property
    def version(self) -> int:
        return VERSION_LOG if self.log_gain is not None else VERSION

    def to_fp16(self) -> "MlpWeights":
        """Round every array to fp16 (kept as float32 so every consumer computes in fp32), after
        :func:`balance_for_fp16`; FloatingPointError (training failed) if a value still cannot be held."""
        w = balance_for_fp16(self)
        peak = max(float(np.abs(a).max(initial=0.0)) for a in w.arrays())
        if not np.isfinite(peak) or peak > FP16_MAX:
            raise FloatingPointError(f"decoder weights reach {peak:.4g}, beyond fp16's {FP16_MAX:g} even after rescaling")
        return MlpWeights(*(np.asarray(a, np.float32).astype(np.float16).astype(np.float32) for a in w.arrays()))

    def arrays(self) -> tuple[np.ndarray, ...]:
        gain = () if self.log_gain is None else (self.log_gain,)
        return (self.w1, self.b1, self.w2, self.b2, self.out_scale, self.out_bias, *gain)

    def halves(self) -> np.ndarray:
        return np.concatenate([np.asarray(a, np.float32).reshape(-1) for a in self.arrays()]).astype(np.float16)


FP16_MAX = 65504.0


def _pow2_split(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per entry, the power of two 2^k that brings max(a / 2^k, b * 2^k) lowest: k = round(log2(sqrt(a / b)))."""
    with np.errstate(divide="ignore"):
        k = np.round(0.5 * (np.log2(np.maximum(a, 1e-30)) - np.log2(np.maximum(b, 1e-30))))
    return np.exp2(k).astype(np.float32)


def balance_for_fp16(w: MlpWeights) -> MlpWeights:
    """The same function, rescaled by powers of two so that every value fits fp16 where that is possible.

    ReLU is positively homogeneous: hidden unit j's row of W1 and b1 may be divided by 2^k and its
    column of W2 multiplied by 2^k; output c's row of W2 and b2 may be divided by 2^k and out_scale[c]
    multiplied by it. Powers of two keep every mantissa, and only units or outputs with a value beyond
    fp16's range are touched, so records that already fit are returned unchanged (byte-identical).
    """
    w1, b1, w2, b2, sc, bi = (np.array(a, np.float32) for a in w.arrays()[:6])
    first = np.maximum(np.abs(w1).max(1, initial=0.0), np.abs(b1))  # per hidden unit
    second = np.abs(w2).max(0, initial=0.0)
    bad = (first > FP16_MAX) | (second > FP16_MAX)
    if bad.any():
        f = np.where(bad, _pow2_split(first, second), np.float32(1))
        w1, b1, w2 = w1 / f[:, None], b1 / f, w2 * f[None, :]
    rows = np.maximum(np.abs(w2).max(1, initial=0.0), np.abs(b2))  # per output
    bad = (rows > FP16_MAX) | (np.abs(sc) > FP16_MAX)
    if bad.any():
        f = np.where(bad, _pow2_split(rows, np.abs(sc)), np.float32(1))
        w2, b2, sc = w2 / f[:, None], b2 / f, sc * f
    return MlpWeights(w1, b1, w2, b2, sc, bi, w.log_gain)


def to_bytes(w: MlpWeights) -> bytes:
    """Serialise one weight record (see module docstring)."""
    n_in, hidden, n_out = w.dims
    h = w.halves()
    body = h.astype("<f2").tobytes()
    body += b"\0" * (-len(body) % 4)
    return HEADER.pack(MAGIC, w.version, n_in, hidden, n_out, h.size) + body


def from_bytes(data: bytes, offset: int = 0) -> tuple[MlpWeights, int]:
    """Parse one weight record at ``offset``; returns the weights and the record's byte size."""
    head, h = record_values(data, offset)
    n_in, hidden, n_out = head.dims
    parts, i = [], 0
    for shape in ((hidden, n_in), (hidden,), (n_out, hidden), *((n_out,),) * (3 if head.version == VERSION else 4)):
        n = int(np.prod(shape))
        parts.append(h[i:i + n].reshape(shape))
        i += n
    return MlpWeights(*parts), head.size


def output_ranges(kinds: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([-1.0 if k == "normal" else 0.0 for k in kinds], np.float32)
    return lo, np.ones(len(kinds), np.float32)


def normal_xy_index(kinds: tuple[str, ...]) -> int | None:
    """Index of normal x (normal y follows) among the model channels, or None."""
    for i, k in enumerate(kinds):
        if k == "normal":
            if i + 1 >= len(kinds) or kinds[i + 1] != "normal":
                raise ValueError("normal channels must come as an adjacent x, y pair")
            return i
    return None


def mlp_raw(params: dict[str, torch.Tensor], feats: torch.Tensor) -> torch.Tensor:
    """12 -> hidden (ReLU) -> c, no post-processing (the training loss sees this, scaled)."""
    h = torch.relu(feats @ params["w1"].t() + params["b1"])
    return h @ params["w2"].t() + params["b2"]


def expand_log(y: torch.Tensor, log_gain: torch.Tensor) -> torch.Tensor:
    """HDR channels (gain > 0) from their clamped log-domain value back to linear [0, 1]."""
    g = log_gain.to(y)
    hdr = g > 0
    inv = torch.where(hdr, 1.0 / (torch.exp2(g.double()) - 1.0).to(y), torch.zeros_like(g))
    return torch.where(hdr, (torch.exp2(g * y) - 1.0) * inv, y)


def postprocess(raw: torch.Tensor, out_scale: torch.Tensor, out_bias: torch.Tensor,
                kinds: tuple[str, ...], clamp: bool = True, log_gain: torch.Tensor | None = None) -> torch.Tensor:
    """Scale/bias, clamp, the HDR expansion, and append normal z (see module docstring)."""
    y = raw * out_scale + out_bias
    if clamp:
        lo, hi = (torch.as_tensor(a, device=y.device) for a in output_ranges(kinds))
        y = torch.maximum(torch.minimum(y, hi), lo)
    if log_gain is not None:
        y = expand_log(y, torch.as_tensor(log_gain))
    n = normal_xy_index(kinds)
    if n is None:
        return y
    z = torch.sqrt(torch.clamp(1 - y[:, n] ** 2 - y[:, n + 1] ** 2, min=0)).unsqueeze(1)
    return torch.cat([y[:, : n + 2], z, y[:, n + 2:]], 1)


def decode_numpy(w: MlpWeights, feats: np.ndarray, kinds: tuple[str, ...]) -> np.ndarray:
    """Reference float32 evaluation of the whole decoder (used by tests and verify)."""
    t = {k: torch.from_numpy(np.asarray(v, np.float32)) for k, v in zip(("w1", "b1", "w2", "b2"), w.arrays())}
    raw = mlp_raw(t, torch.from_numpy(np.asarray(feats, np.float32)))
    gain = torch.from_numpy(np.asarray(w.log_gain, np.float32)) if w.log_gain is not None else None
    return postprocess(raw, torch.from_numpy(w.out_scale), torch.from_numpy(w.out_bias), kinds, log_gain=gain).numpy()


def to_onnx(w: MlpWeights, kinds: tuple[str, ...], name: str = "bcf_decoder"):
    """An onnx.ModelProto of the full decoder: features (N, n_in) float32 -> channels (N, c_out)."""
    import onnx  # lazy: start-up
    from onnx import TensorProto, helper, numpy_helper  # lazy: start-up

    n_in, hidden, n_out = w.dims
    lo, hi = output_ranges(kinds)
    inits = [numpy_helper.from_array(np.asarray(a, np.float32), n) for a, n in (
        (w.w1, "W1"), (w.b1, "b1"), (w.w2, "W2"), (w.b2, "b2"),
        (w.out_scale, "out_scale"), (w.out_bias, "out_bias"), (lo, "lo"), (hi, "hi"))]
    nodes = [
        helper.make_node("Gemm", [ONNX_INPUT, "W1", "b1"], ["h_pre"], transB=1),
        helper.make_node("Relu", ["h_pre"], ["h"]),
        helper.make_node("Gemm", ["h", "W2", "b2"], ["raw"], transB=1),
        helper.make_node("Mul", ["raw", "out_scale"], ["scaled"]),
        helper.make_node("Add", ["scaled", "out_bias"], ["biased"]),
        helper.make_node("Max", ["biased", "lo"], ["above"]),
        helper.make_node("Min", ["above", "hi"], ["clamped" if w.log_gain is None else "clamped_t"]),
    ]
    if w.log_gain is not None:  # HDR: (2^(g y) - 1) * inv where g > 0, y itself where g = 0
        g = np.asarray(w.log_gain, np.float32)
        with np.errstate(divide="ignore"):
            inv = np.where(g > 0, 1.0 / (np.exp2(g.astype(np.float64)) - 1.0), 0.0).astype(np.float32)
        inits += [numpy_helper.from_array(g, "log_gain"), numpy_helper.from_array(inv, "log_inv"),
                  numpy_helper.from_array((g <= 0).astype(np.float32), "log_linear"),
                  numpy_helper.from_array(np.array(2.0, np.float32), "two"),
                  numpy_helper.from_array(np.array(1.0, np.float32), "log_one")]
        nodes += [
            helper.make_node("Mul", ["clamped_t", "log_gain"], ["gy"]),
            helper.make_node("Pow", ["two", "gy"], ["p2"]),
            helper.make_node("Sub", ["p2", "log_one"], ["p2m1"]),
            helper.make_node("Mul", ["p2m1", "log_inv"], ["expanded"]),
            helper.make_node("Mul", ["clamped_t", "log_linear"], ["kept"]),
            helper.make_node("Add", ["expanded", "kept"], ["clamped"]),
        ]
    n = normal_xy_index(kinds)
    n_total = n_out
    if n is None:
        nodes.append(helper.make_node("Identity", ["clamped"], [ONNX_OUTPUT]))
    else:
        n_total += 1
        inits += [numpy_helper.from_array(np.array(v, np.int64), k) for k, v in (
            ("i_head", [0]), ("i_xy_end", [n + 2]), ("i_end", [n_out]), ("i_xy", [n]), ("axis1", [1]))]
        inits += [numpy_helper.from_array(np.array(1.0, np.float32), "one"),
                  numpy_helper.from_array(np.array(0.0, np.float32), "zero")]
        nodes += [
            helper.make_node("Slice", ["clamped", "i_head", "i_xy_end", "axis1"], ["head"]),
            helper.make_node("Slice", ["clamped", "i_xy_end", "i_end", "axis1"], ["tail"]),
            helper.make_node("Slice", ["clamped", "i_xy", "i_xy_end", "axis1"], ["xy"]),
            helper.make_node("Mul", ["xy", "xy"], ["xy2"]),
            helper.make_node("ReduceSum", ["xy2", "axis1"], ["r2"], keepdims=1),
            helper.make_node("Sub", ["one", "r2"], ["z2"]),
            helper.make_node("Max", ["z2", "zero"], ["z2c"]),
            helper.make_node("Sqrt", ["z2c"], ["z"]),
            helper.make_node("Concat", ["head", "z", "tail"], [ONNX_OUTPUT], axis=1),
        ]
    graph = helper.make_graph(
        nodes, name,
        [helper.make_tensor_value_info(ONNX_INPUT, TensorProto.FLOAT, ["N", n_in])],
        [helper.make_tensor_value_info(ONNX_OUTPUT, TensorProto.FLOAT, ["N", n_total])],
        inits)
    model = helper.make_model(graph, producer_name="bcfpipe", opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.checker.check_model(model)
    return model
