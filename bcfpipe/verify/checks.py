"""``bcfpipe verify``: check exported neural materials end to end, through the real GLSL decoder.

For every material (one exported folder, or every material of a build) the checks are:

``files``      material.json agrees with the DDS headers (size, mip count, BC6H signedness) and the
               weight record (dimensions, output count); every block uses the declared BC6H mode.
``integrity``  SHA-256 of each file against material.json's ``sha256`` (the exporter records them);
               "not recorded" for a material.json without them.
``weights``    the fp16 record the runtime reads (the material's weights.bin, or the build's combined
               buffer at the material's offset) holds exactly the values of decoder.onnx.
``openimageio`` OpenImageIO reads every mip of every DDS to the same fp16 bits as bcfpipe.bc6h.decode.
``glsl``       glsl/bcf_decode.comp, run through OpenGL (moderngl on EGL: the GPU driver, or Mesa
               llvmpipe), against an independent path: features sampled in numpy/torch from the DDS
               decoded by bcfpipe.bc6h.decode (bcfpipe.sampling conventions) fed to decoder.onnx
               through onnxruntime. Sampled at a grid of (u, v, s) with texel centres and edges of
               every level of every layer, uv across and far beyond the borders (repeat / clamp),
               s < 0 (magnification), integer and fractional s, and s past every layer's last mip.

Tolerance (``glsl``), per sample point p and output channel c, derived from the material itself:

  * The two paths decode identical BC6H texels (bit-exact fp16 on both sides; Mesa's -0 for signed
    texels that round to zero is the same value) and use identical fp16 weights, so they differ only
    by (a) the filtering precision of the texture unit and (b) fp32 rounding.
  * (a) Texture units fix the bilinear sub-texel fractions and the mip blend fraction to limited
    precision; 8 fractional bits is the norm (D3D11 requires 8 sub-texel bits; NVIDIA documents
    9-bit weights with 8 fractional bits). We allow an error of delta = 2^-FILTER_BITS (one full step:
    rounding or truncation) on each fraction that is not exactly on that fixed-point grid (texel
    centres and edges of power-of-two levels and exact lods are). Bilinear filtering is exactly
    ``B = t00 + fx*dx + fy*dy + fx*fy*cross``, so a fraction error moves a layer's 3 features along
    the vector dB/dfx (resp. dB/dfy) of the cell it falls in, and a mip-blend error along
    B_k+1 - B_k; the remaining terms are second order (delta^2 * cross, delta * bilinear error).
  * Through the MLP: hidden units that are active with a margin larger than their possible input
    change form the exact linear map J = diag(out_scale) W2 diag(active) W1 (fp16 weights), and each
    first-order term contributes delta * max over its candidate cells of |J v| (signs kept: the
    three channels of a layer move together); second-order terms go through |J|; units that may
    switch (|h_j| <= r_j = sum_i |W1_ji| e_i) add |out_scale| |W2_cj| r_j (ReLU is 1-Lipschitz). The
    clamp to the output range can only shrink the change; normal z = sqrt(1 - x^2 - y^2) changes by
    at most min(sqrt(D), D / (z + sqrt(max(0, z^2 - D)))) with D = 2|x|e_x + 2|y|e_y + e_x^2 + e_y^2.
  * (b) fp32: the standard dot-product rounding bound (n_hidden + 16) * 2^-23 * (sum of |terms|)
    with the network's actual magnitudes, and 2^-20 of the largest feature for the filter arithmetic.

The bound is checked against a simulated 8-bit texture unit (rounding and truncating) in the tests:
it holds and is nearly reached (max error / bound ~0.9-0.98 with truncation). llvmpipe filters in
fp32 and agrees to ~1e-7. The check fails when any |GL - ONNX| exceeds its bound (``--tolerance X``
replaces it by a fixed X). The bound grows with the features' texel-to-texel differences: the
report says for how many values it exceeds the 2e-3 target (materials whose features have large
values are sensitive to hardware filtering precision).

Exit codes (verify_cli): 0 all checks passed, 1 a check failed, 2 bad input or no OpenGL.
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from bcfpipe.errors import InputError
from bcfpipe.bc6h import mode10
from bcfpipe.formats import dds
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf
from bcfpipe.formats.record import FormatError
from bcfpipe.export import writer as E
from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, from_bytes
from bcfpipe.verify.glsl import GLRuntime, GLUnavailable, MaterialDesc, read_material

FILTER_BITS = 8
FP32_ULP = 2.0 ** -23
TARGET = 2e-3


class VerifyInputError(InputError):
    """The folder is not a material / build, or a file cannot be parsed (exit code 2)."""


# ------------------------------------------------------------------------------------------- inputs

@dataclass
class Target:
    """One material to verify, and every name (prim path) that uses it."""

    desc: MaterialDesc
    aliases: list[str] = field(default_factory=list)  # every name (prim path) that uses it


def sha256_file(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _manifest_targets(root: Path, manifest: mfst.Manifest) -> list[Target]:
    """The built materials of a build manifest, each decoded with its record in the combined
    weights.bin; materials sharing one trained folder and record are verified once (the others
    are kept as aliases)."""
    combined = root / manifest.weights
    by_key: dict[tuple, Target] = {}
    for e in manifest.built():
        if e.outputs is None:
            raise VerifyInputError(f"{root / mfst.FILE}: built material {e.path} has no outputs")
        folder = root / e.outputs.folder
        if not (folder / mf.FILE).is_file():
            raise VerifyInputError(f"{root / mfst.FILE} lists {folder}, which has no {mf.FILE}")
        if not combined.is_file():
            raise VerifyInputError(f"{root / mfst.FILE} points into {combined}, which is missing")
        key = (str(folder.resolve()), e.outputs.weights_offset)
        if key in by_key:
            by_key[key].aliases.append(e.path)
            continue
        by_key[key] = Target(read_material(folder, combined, e.outputs.weights_offset, name=e.path), [e.path])
    return list(by_key.values())


def find_targets(path: str | os.PathLike) -> list[Target]:
    """A material folder (material.json), a build folder (manifest.json), or any folder whose
    subfolders (one or two levels down) hold material.json files."""
    root = Path(path)
    if not root.is_dir():
        raise VerifyInputError(f"{root}: not a folder")
    try:
        if (root / mf.FILE).is_file():
            return [Target(read_material(root))]
        if (root / mfst.FILE).is_file():  # a build: exactly what it built (possibly nothing)
            return _manifest_targets(root, mfst.read(root))
        found = sorted({p.parent for pat in ("*/" + mf.FILE, "*/*/" + mf.FILE) for p in root.glob(pat)})
        targets = [Target(read_material(f, name=str(f.relative_to(root)))) for f in found]
    except FormatError as ex:
        raise VerifyInputError(str(ex)) from None
    if not targets:
        raise VerifyInputError(f"{root}: no {mf.FILE} or {mfst.FILE} here or in its subfolders")
    return targets


# ------------------------------------------------------------------------------------------- sample grid

CATEGORIES = ("texel centres", "texel edges", "borders / wrap", "s < 0", "fractional s", "s > last mip", "random")


def verification_points(m: MaterialDesc, level_sizes: Sequence[Sequence[tuple[int, int]]], seed: int = 0,
                        per_level: int = 24, n_random: int = 4096) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(uv (N, 2) float32, s (N,) float32, category index (N,)) covering the cases in CATEGORIES."""
    rng = np.random.default_rng(seed)
    uvs, ss, cats = [], [], []

    def add(uv, s, cat):
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        uvs.append(uv)
        ss.append(np.broadcast_to(np.asarray(s, np.float64), (uv.shape[0],)))
        cats.append(np.full(uv.shape[0], CATEGORIES.index(cat)))

    biases = m.lod_biases
    s_last = max(n - 1 - b for n, b in zip(m.mip_counts, biases))  # every layer at its last mip beyond this
    for i, sizes in enumerate(level_sizes):
        for k, (w, h) in enumerate(sizes):
            xi = np.concatenate([[0, w - 1], rng.integers(0, w, per_level - 2)])
            yi = np.concatenate([[h - 1, 0], rng.integers(0, h, per_level - 2)])
            s = k - biases[i]  # layer i exactly at level k (others wherever that puts them)
            add(np.stack([(xi + 0.5) / w, (yi + 0.5) / h], 1), s, "texel centres")
            add(np.stack([xi / w, yi / h], 1), s, "texel edges")
            add(np.stack([xi / w, (yi + 0.5) / h], 1), s + 0.5, "texel edges")
    w0 = level_sizes[0][0][0]
    border = np.array([-2.25, -1.0, -0.5, -0.5 / w0, -1e-4, 0.0, 1e-4, 0.5 / w0, 1 - 0.5 / w0, 1 - 1e-4, 1.0,
                       1 + 1e-4, 1.5, 3.75])
    bu, bv = np.meshgrid(border, border, indexing="ij")
    grid = np.stack([bu.ravel(), bv.ravel()], 1)
    for s in (-2.0, 0.0, 0.5, 1.75, s_last + 1):
        add(grid, s, "borders / wrap")
    for s in (-8.0, -2.5, -1.0, -0.3):
        add(rng.random((256, 2)), s, "s < 0")
    for s in (0.25, 0.5, 1.37, 2.9, 3.5, 4.125):
        add(rng.random((256, 2)), s, "fractional s")
    add(rng.random((512, 2)), rng.uniform(-1, s_last + 1, 512), "fractional s")
    for s in (s_last, s_last + 0.5, s_last + 3, 40.0):
        add(rng.random((128, 2)) * 3 - 1, s, "s > last mip")
    add(rng.random((n_random, 2)) * 5 - 2, rng.uniform(-4, s_last + 2, n_random), "random")
    return (np.concatenate(uvs).astype(np.float32), np.concatenate(ss).astype(np.float32),
            np.concatenate(cats))


# ------------------------------------------------------------------------------------------- tolerance

def _addr(i: np.ndarray, n: int, wrap: str) -> np.ndarray:
    return np.mod(i, n) if wrap == "repeat" else np.clip(i, 0, n - 1)


def _off_grid(x: np.ndarray, delta: float) -> np.ndarray:
    """1.0 where ``x`` is not a multiple of ``delta`` (a fixed-point fraction would round or
    truncate it), 0.0 where it is exact (texel centres and edges of power-of-two levels, exact lods)."""
    q = x / delta
    return (np.abs(q - np.round(q)) > 1e-6).astype(np.float64)


def _bilinear_terms(tex: np.ndarray, uv: np.ndarray, wrap: str, delta: float):
    """Bilinear value B, the slopes dB/dfx and dB/dfy of every cell within ``delta`` of each point
    (2 candidates each, zero where the coordinate is exact on the fixed-point grid), the second-order
    bound and the abs error bound of B for fraction errors up to ``delta``."""
    h, w, _ = tex.shape
    x = uv[:, 0].astype(np.float64) * w - 0.5
    y = uv[:, 1].astype(np.float64) * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    ax, ay = _off_grid(x, delta)[:, None], _off_grid(y, delta)[:, None]

    def texel(cx, cy):
        return tex[_addr(cy.astype(np.int64), h, wrap), _addr(cx.astype(np.int64), w, wrap)]

    t00, t01, t10, t11 = texel(x0, y0), texel(x0 + 1, y0), texel(x0, y0 + 1), texel(x0 + 1, y0 + 1)
    value = (t00 * (1 - fx) + t01 * fx) * (1 - fy) + (t10 * (1 - fx) + t11 * fx) * fy
    dx = [ax * ((1 - fy) * (texel(cx + 1, y0) - texel(cx, y0)) + fy * (texel(cx + 1, y0 + 1) - texel(cx, y0 + 1)))
          for cx in (np.floor(x - delta), np.floor(x + delta))]
    dy = [ay * ((1 - fx) * (texel(x0, cy + 1) - texel(x0, cy)) + fx * (texel(x0 + 1, cy + 1) - texel(x0 + 1, cy)))
          for cy in (np.floor(y - delta), np.floor(y + delta))]
    cross = 0
    for cx in (np.floor(x - delta), np.floor(x + delta)):
        for cy in (np.floor(y - delta), np.floor(y + delta)):
            cross = np.maximum(cross, np.abs(texel(cx, cy) - texel(cx + 1, cy) - texel(cx, cy + 1)
                                             + texel(cx + 1, cy + 1)))
    second = delta * delta * cross * ax * ay
    err = delta * (np.maximum(*map(np.abs, dx)) + np.maximum(*map(np.abs, dy))) + second
    return value, dx, dy, second, err


@dataclass
class FilterError:
    """How hardware filtering precision can move the features at each point.

    ``groups``: first-order terms; each is (K, N, F) candidate feature-change vectors v_k, meaning
    the features move by up to delta * v for one unknown fraction error in [-1, 1] * delta and some
    k (the cell or mip pair it falls in). ``second``: (N, F) abs bound of the rest (second order and
    fp32 filtering arithmetic). ``total``: (N, F) abs bound of the whole feature error.
    """

    delta: float
    groups: list[np.ndarray]
    second: np.ndarray
    total: np.ndarray


def filter_error(levels: Sequence[Sequence[np.ndarray]], biases: Sequence[float], uv: np.ndarray,
                 s: np.ndarray, wrap: str, filter_bits: int = FILTER_BITS) -> FilterError:
    """Feature-error terms of trilinear filtering with 2^-filter_bits precision on the bilinear
    fractions and on the mip blend fraction (see the module docstring)."""
    delta = 2.0 ** -filter_bits
    n_pts = uv.shape[0]
    n_feat = 3 * len(levels)
    groups, second, total = [], np.zeros((n_pts, n_feat)), np.zeros((n_pts, n_feat))
    for i, (layer, b) in enumerate(zip(levels, biases)):
        sl = slice(3 * i, 3 * i + 3)
        n = len(layer)
        lam = (s.astype(np.float32) + np.float32(b)).astype(np.float64)
        lc = np.clip(lam, 0, n - 1)
        lo = np.floor(lc).astype(np.int64)
        t = (lc - lo)[:, None]
        hi = np.minimum(lo + 1, n - 1)
        terms = [_bilinear_terms(tex.astype(np.float64), uv, wrap, delta) for tex in layer]
        vals = np.stack([tr[0] for tr in terms])  # (n, N, 3)
        pick = lambda arr, k: np.take_along_axis(arr, k[None, :, None], 0)[0]  # noqa: E731
        for weight, k in ((1 - t, lo), (t, hi)):
            for part in (1, 2):  # dB/dfx, dB/dfy candidates of the level in use
                cand = np.stack([pick(np.stack([tr[part][c] for tr in terms]), k) for c in range(2)]) * weight
                g = np.zeros((2, n_pts, n_feat))
                g[:, :, sl] = cand
                groups.append(g)
                total[:, sl] += delta * np.abs(cand).max(0)
            second[:, sl] += weight * pick(np.stack([tr[3] for tr in terms]), k)
        # mip blend: slopes B_k+1 - B_k of the segments within delta of the lod (0 outside [0, n-1])
        al = _off_grid(lam, delta)  # an exact lod blends exactly
        k1 = np.floor(lam - delta * al).astype(np.int64)
        k2 = np.floor(lam + delta * al).astype(np.int64)
        seg = np.zeros((2, n_pts, n_feat))
        for c, k in enumerate((k1, k2)):
            ok = ((k >= 0) & (k <= n - 2))[:, None]
            kk = np.clip(k, 0, max(n - 2, 0))
            d = pick(vals, np.minimum(kk + 1, n - 1)) - pick(vals, kk)
            seg[c, :, sl] = np.where(ok, d, 0.0) * al[:, None]
        groups.append(seg)
        total[:, sl] += delta * np.abs(seg[:, :, sl]).max(0)
        # blend error x bilinear errors of every level that can take part, and fp32 filtering arithmetic
        errs = np.stack([tr[4] for tr in terms])
        for k in range(n):
            inside = ((k >= np.clip(k1, 0, n - 1)) & (k <= np.clip(k2 + 1, 0, n - 1)))[:, None]
            second[:, sl] += np.where(inside, delta * al[:, None] * errs[k], 0.0)
        second[:, sl] += 2.0 ** -20 * max(float(np.abs(tex).max()) for tex in layer)
    total += second
    return FilterError(delta, groups, second, total)


def output_tolerance(weights, kinds: tuple[str, ...], feats: np.ndarray, fe: FilterError,
                     ref_out: np.ndarray) -> np.ndarray:
    """Per point, per output channel (incl. normal z): bound on |GL - ONNX| (see module docstring)."""
    from bcfpipe.model.decoder import normal_xy_index, output_ranges

    w1, b1, w2, b2, sc, bi = (np.asarray(a, np.float64) for a in weights.arrays())
    f = feats.astype(np.float64)
    h = f @ w1.T + b1
    r = fe.total @ np.abs(w1).T  # bound on each hidden pre-activation's change
    safe_on = (h > r).astype(np.float64)  # active whatever the filtering error: linear there
    kink = np.abs(h) <= r  # may switch: treated with |.| (ReLU is 1-Lipschitz)
    jac = np.einsum("nh,ch,hi->nci", safe_on, w2, w1) * sc[None, :, None]  # (N, C, F)
    first = np.zeros(jac.shape[:2])
    for g in fe.groups:
        first += np.abs(np.einsum("nci,kni->knc", jac, g)).max(0)
    dy = fe.delta * first + np.einsum("nci,ni->nc", np.abs(jac), fe.second)
    dy += np.abs(sc) * (np.where(kink, r, 0.0) @ np.abs(w2).T)
    # fp32 rounding of both evaluations (dot-product bound with the actual magnitudes)
    a1 = np.abs(f) @ np.abs(w1).T + np.abs(b1)
    mag = np.abs(sc) * (a1 @ np.abs(w2).T + np.abs(b2)) + np.abs(bi)
    dy += (w1.shape[0] + 16) * FP32_ULP * mag + FP32_ULP
    y = (np.maximum(h, 0) @ w2.T + b2) * sc + bi
    lo, hi = (np.asarray(a, np.float64) for a in output_ranges(kinds))
    cy = np.clip(y, lo, hi)
    e = np.maximum(np.clip(y + dy, lo, hi) - cy, cy - np.clip(y - dy, lo, hi)) + FP32_ULP
    n = normal_xy_index(kinds)
    if n is None:
        return e
    x, yy = ref_out[:, n].astype(np.float64), ref_out[:, n + 1].astype(np.float64)
    ex, ey = e[:, n], e[:, n + 1]
    d = 2 * np.abs(x) * ex + 2 * np.abs(yy) * ey + ex * ex + ey * ey
    z = np.sqrt(np.maximum(0.0, 1 - x * x - yy * yy))
    with np.errstate(divide="ignore", invalid="ignore"):
        ez = np.minimum(np.sqrt(d), d / (z + np.sqrt(np.maximum(0.0, z * z - d))))
    ez = np.where(np.isfinite(ez), ez, np.sqrt(d)) + 4 * FP32_ULP
    return np.concatenate([e[:, :n + 2], ez[:, None], e[:, n + 2:]], 1)


# ------------------------------------------------------------------------------------------- checks

@dataclass
class Check:
    name: str
    passed: bool | None  # None: skipped / not applicable
    detail: str

    def to_dict(self) -> dict:
        return {"name": self.name, "passed": self.passed, "detail": self.detail}


@dataclass
class MaterialReport:
    name: str
    folder: str
    checks: list[Check] = field(default_factory=list)
    channels: list[dict] = field(default_factory=list)
    categories: list[dict] = field(default_factory=list)
    n_points: int = 0
    input_error: str | None = None

    @property
    def passed(self) -> bool:
        return self.input_error is None and all(c.passed is not False for c in self.checks)

    def to_dict(self) -> dict:
        return {"name": self.name, "folder": self.folder, "passed": self.passed, "input_error": self.input_error,
                "checks": [c.to_dict() for c in self.checks], "n_points": self.n_points,
                "channels": self.channels, "categories": self.categories}


def check_files(m: MaterialDesc) -> tuple[Check, list[dds.DdsTexture]]:
    problems, texs = [], []
    for i, path in enumerate(m.layer_files):
        try:
            t = dds.read(path)
        except dds.DdsError as e:
            raise VerifyInputError(str(e)) from None
        texs.append(t)
        layer = m.file.layers[i]
        if t.mip_count != m.mip_counts[i]:
            problems.append(f"{path.name}: {t.mip_count} mips, material.json says {m.mip_counts[i]}")
        if (t.width, t.height) != (layer.resolution, layer.resolution):
            problems.append(f"{path.name}: {t.width}x{t.height}, material.json says {layer.resolution}")
        if t.signed != m.signed:
            problems.append(f"{path.name}: {t.format_name}, material.json says signed={m.signed}")
        if m.file.bc6h.block_mode == mode10.DESCRIPTION:
            for k, (blocks, w, h) in enumerate(t.levels):
                bad = int((~mode10.is_mode10(blocks)).sum())
                if bad:
                    problems.append(f"{path.name} mip {k}: {bad} block(s) not in the declared mode "
                                    f"{mode10.MODE_VALUE:05b}")
    try:
        data = m.weights_file.read_bytes()
        w, size = from_bytes(data, m.weight_offset)
    except (OSError, ValueError) as e:
        raise VerifyInputError(f"{m.weights_file}: {e}") from None
    n_in, hidden, n_out = w.dims
    if n_in != 3 * len(m.layer_files) or n_out != m.n_out:
        problems.append(f"weight record is {n_in}-{hidden}-{n_out}, material.json has {m.n_out} outputs")
    if m.file.mlp.n_hidden != hidden:
        problems.append(f"weight record has {hidden} hidden units, material.json says {m.file.mlp.n_hidden}")
    return Check("files", not problems, "; ".join(problems) or
                 f"{len(texs)} BC6H layers ({'signed' if m.signed else 'unsigned'}), "
                 f"mips {list(m.mip_counts)}, decoder {n_in}-{hidden}-{n_out}"), texs


def check_integrity(t: Target) -> Check:
    m = t.desc
    recorded = dict(m.file.sha256 or {})
    if not recorded:
        return Check("integrity", None, "no SHA-256 recorded (material.json has no 'sha256')")
    bad = []
    for name, hexdigest in sorted(recorded.items()):
        path = m.folder / name
        if not path.is_file():
            bad.append(f"{name} missing")
        elif sha256_file(path) != str(hexdigest).lower():
            bad.append(f"{name} differs from its recorded SHA-256")
    return Check("integrity", not bad, "; ".join(bad) or f"{len(recorded)} files match their SHA-256")


def check_weights_onnx(m: MaterialDesc) -> Check:
    """The record the runtime reads == decoder.onnx's initializers, value for value."""
    import onnx
    from onnx import numpy_helper

    w, _ = from_bytes(m.weights_file.read_bytes(), m.weight_offset)
    try:
        model = onnx.load(str(m.folder / m.file.onnx.file))
    except Exception as e:  # noqa: BLE001
        raise VerifyInputError(f"{m.folder / m.file.onnx.file}: {e}") from None
    inits = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    bad = []
    for name, arr in zip(("W1", "b1", "W2", "b2", "out_scale", "out_bias"), w.arrays()):
        o = inits.get(name)
        if o is None or o.shape != arr.shape:
            bad.append(f"{name}: missing or shaped {None if o is None else o.shape} in decoder.onnx")
            continue
        diff = int((o.astype(np.float32) != arr).sum())
        if diff:
            bad.append(f"{name}: {diff} value(s) differ")
    if m.weights_file != m.folder / m.file.mlp.weights:
        own = m.folder / m.file.mlp.weights
        if own.is_file():
            w_own, _ = from_bytes(own.read_bytes(), m.file.mlp.offset)
            if any((a != b).any() for a, b in zip(w.arrays(), w_own.arrays())):
                bad.append(f"record at byte {m.weight_offset} of {m.weights_file.name} differs from {own}")
    where = f"{m.weights_file.name}@{m.weight_offset}"
    return Check("weights", not bad, "; ".join(bad) or f"{where}: all fp16 values equal decoder.onnx's")


def check_openimageio(texs: Sequence[dds.DdsTexture], files: Sequence[Path]) -> Check:
    from bcfpipe.bc6h import decode as bc6h_decode

    try:
        import OpenImageIO as oiio
    except ImportError as e:
        return Check("openimageio", False, f"OpenImageIO is not importable ({e})")
    bad, n_levels = [], 0
    for tex, path in zip(texs, files):
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            bad.append(f"{path.name}: OpenImageIO cannot open it ({oiio.geterror()})")
            continue
        try:
            for k, (blocks, w, h) in enumerate(tex.levels):
                if not inp.seek_subimage(0, k):
                    bad.append(f"{path.name}: OpenImageIO has no mip {k}")
                    break
                spec = inp.spec()
                img = inp.read_image(format="half")
                if img is None or (spec.width, spec.height) != (w, h):
                    bad.append(f"{path.name} mip {k}: OpenImageIO read failed or size differs")
                    continue
                theirs = np.ascontiguousarray(np.asarray(img).reshape(h, w, -1)[..., :3]).view(np.uint16)
                ours = bc6h_decode(blocks, w, h, signed=tex.signed).view(np.uint16)
                diff = int((theirs != ours).sum())
                n_levels += 1
                if diff:
                    bad.append(f"{path.name} mip {k}: {diff} fp16 value(s) differ")
            if inp.seek_subimage(0, tex.mip_count):
                bad.append(f"{path.name}: OpenImageIO sees more than {tex.mip_count} mips")
        finally:
            inp.close()
    return Check("openimageio", not bad, "; ".join(bad) or f"{n_levels} mip levels bit-identical")


def check_glsl(rt: GLRuntime, m: MaterialDesc, em: E.ExportedMaterial, tolerance: float | None,
               seed: int = 0, filter_bits: int = FILTER_BITS) -> tuple[Check, list[dict], list[dict], int]:
    level_sizes = [[(lv.shape[1], lv.shape[0]) for lv in layer] for layer in em.levels]
    uv, s, cat = verification_points(m, level_sizes, seed)
    gm = rt.load(m)
    try:
        gl = rt.decode(gm, uv, s)
    finally:
        rt.unload(gm)
    feats = E.sample_exported_features(em, uv, s)
    sess = E.onnx_session(em)
    ref = sess.run([ONNX_OUTPUT], {ONNX_INPUT: feats})[0]
    if gl.shape != ref.shape:
        return Check("glsl", False, f"GLSL gives {gl.shape[1]} channels, ONNX {ref.shape[1]}"), [], [], len(uv)
    if tolerance is None:
        fe = filter_error(em.levels, em.lod_biases, uv, s, em.wrap, filter_bits)
        tol = output_tolerance(em.weights, em.kinds, feats, fe, ref)
    else:
        tol = np.full(ref.shape, float(tolerance))
    err = np.abs(gl.astype(np.float64) - ref.astype(np.float64))
    err = np.where(np.isnan(err), np.inf, err)  # a NaN from GL (invalid record) always fails
    names = [o.name for o in m.outputs]
    channels = []
    for c in range(ref.shape[1]):
        worst = int(np.argmax(err[:, c]))
        over = int((err[:, c] > tol[:, c]).sum())
        channels.append({"name": names[c] if c < len(names) else f"ch{c}", "max_abs": float(err[:, c].max()),
                         "mean_abs": float(err[:, c].mean()), "max_tolerance": float(tol[:, c].max()),
                         "mean_tolerance": float(tol[:, c].mean()), "over_tolerance": over,
                         "worst": {"u": float(uv[worst, 0]), "v": float(uv[worst, 1]), "s": float(s[worst]),
                                   "category": CATEGORIES[cat[worst]]},
                         "passed": over == 0})
    categories = []
    for k, name in enumerate(CATEGORIES):
        sel = cat == k
        if sel.any():
            categories.append({"category": name, "n": int(sel.sum()), "max_abs": float(err[sel].max()),
                               "mean_abs": float(err[sel].mean()),
                               "over_tolerance": int((err[sel] > tol[sel]).sum())})
    n_over = sum(ch["over_tolerance"] for ch in channels)
    mode = "derived bound" if tolerance is None else f"fixed {tolerance:g}"
    detail = (f"{len(uv)} (u, v, s) points x {ref.shape[1]} channels: max |GL - ONNX| {err.max():.3g} "
              f"(tolerance: {mode}, max {tol.max():.3g})")
    if n_over:
        detail += f"; {n_over} value(s) over tolerance"
    if tolerance is None:
        loose = float((tol > TARGET).mean())
        if loose > 0:  # informational: how sensitive the material is to hardware filtering precision
            detail += f"; bound > {TARGET:g} for {100 * loose:.1f}% of values"
    return Check("glsl", n_over == 0, detail), channels, categories, len(uv)


# ------------------------------------------------------------------------------------------- driver

@dataclass
class Report:
    path: str
    materials: list[MaterialReport]
    renderer: dict | None
    tolerance: dict
    gl_error: str | None = None

    @property
    def passed(self) -> bool:
        return self.gl_error is None and all(m.passed for m in self.materials)

    @property
    def exit_code(self) -> int:
        if self.gl_error is not None or any(m.input_error for m in self.materials):
            return 2
        return 0 if self.passed else 1

    def to_dict(self) -> dict:
        return {"path": self.path, "passed": self.passed, "exit_code": self.exit_code, "renderer": self.renderer,
                "gl_error": self.gl_error, "tolerance": self.tolerance,
                "materials": [m.to_dict() for m in self.materials]}


def verify_target(t: Target, rt: GLRuntime | None, tolerance: float | None = None, seed: int = 0,
                  filter_bits: int = FILTER_BITS) -> MaterialReport:
    m = t.desc
    rep = MaterialReport(m.name, str(m.folder))
    try:
        files, texs = check_files(m)
        rep.checks.append(files)
        rep.checks.append(check_integrity(t))
        rep.checks.append(check_weights_onnx(m))
        rep.checks.append(check_openimageio(texs, m.layer_files))
        if rt is not None:
            em = E.load(m.folder)
            em = E.ExportedMaterial(em.desc, em.levels, from_bytes(m.weights_file.read_bytes(), m.weight_offset)[0],
                                    em.onnx_path)
            chk, rep.channels, rep.categories, rep.n_points = check_glsl(rt, m, em, tolerance, seed, filter_bits)
            rep.checks.append(chk)
        else:
            rep.checks.append(Check("glsl", None, "skipped (--no-glsl)"))
    except VerifyInputError as e:
        rep.input_error = str(e)
    except (OSError, KeyError, dds.DdsError) as e:
        rep.input_error = f"{type(e).__name__}: {e}"
    return rep


def verify(path: str | os.PathLike, tolerance: float | None = None, glsl: bool = True, seed: int = 0,
           filter_bits: int = FILTER_BITS, runtime: GLRuntime | None = None, progress=None) -> Report:
    """Verify every material under ``path``; raises VerifyInputError when there is nothing to verify."""
    targets = find_targets(path)
    tol_info = {"mode": "derived" if tolerance is None else "fixed", "filter_bits": filter_bits,
                "target": TARGET}
    if tolerance is not None:
        tol_info["value"] = tolerance
    rt, own = runtime, False
    if glsl and rt is None:
        try:
            rt, own = GLRuntime(), True
        except GLUnavailable as e:
            return Report(str(path), [], None, tol_info, gl_error=str(e))
    try:
        renderer = rt.info if rt is not None else None
        reports = []
        for t in targets:
            if progress:
                progress(t.desc.name)
            reports.append(verify_target(t, rt if glsl else None, tolerance, seed, filter_bits))
        return Report(str(path), reports, renderer, tol_info)
    finally:
        if own:
            rt.release()
