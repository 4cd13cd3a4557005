"""BC6H encoder restricted to mode 10 (mode bits ``11110``), vectorized with torch.

``encode(texels)`` turns an (H, W, 3) float image into (H/4 * W/4, 16) uint8
BC6H blocks (row-major block order) that all use the two-region mode with 6-bit
untransformed endpoints -- the block layout of bcfpipe's learned feature
textures.  ``encode_params`` returns the same result as unpacked integer
parameters (conventions of :mod:`bcfpipe.bc6h.mode10`), which the trainer uses
to initialise its block parameters.

Working domain.  BC6H interpolates in the *unquantized 16-bit integer domain*
``V`` (``V = (Ua*(64-w) + Ub*w + 32) >> 6``), which becomes half-float bits
through ``F = V*31 >> 6`` (unsigned) or ``F = trunc(V*31/32)`` (signed,
sign-magnitude).  Half bits are a monotone piecewise-linear function of the
value, so a target ``t`` is mapped to its continuous half-bit position ``y(t)``
(the inverse of paper eq. 8) and on to ``q = (y + 1/2) * 64/31`` (``32/31``
signed): the centre of the ``V`` interval that decodes to ``round(y)``.  Lines
are fitted to ``q``; the least-squares steps weight each texel and channel by
``(d value / d q)^2`` so that they approximate the error of the decoded value.
Everything that *decides* (shape, indices, accepted endpoints) uses the exact
decoded error: squared difference between the exactly decoded half value and
the target, summed over channels (a 64 x 64 x 8 table holds every decodable
value of a channel).

Out-of-range values clamp: unsigned to [0, 65504], signed to [-65504, 65504]
(half bits 0x7BFF, reached by ``0xFFFF*31 >> 6`` and by ``0x7FFF*31 >> 5``).

Algorithm, vectorized over blocks (processed in cache-sized chunks, in parallel
CPU threads) and shapes; no per-block Python loops:

1. Screening of all 32 shapes (64 subsets): per subset the mean and principal
   axis of ``q`` (power iteration on the 3x3 covariance), the variance off that
   axis and the extent along it.  A shape's score is the weighted off-axis
   variance plus the quantization noise of 8 palette entries over the extent;
   the ``refine_top`` best-scoring shapes -- always including the shape whose
   subsets are closest to two exact line segments -- are refined.
2. Refinement, per candidate shape and subset, from three starts: two index
   patterns from the texels' positions along the principal segment (spread
   over indices 0..7, and squeezed to 3..4, which lets nearly constant subsets
   place values between the coarse 6-bit endpoint grid by interpolation) and
   the segment's ends quantized *outwards* to 6-bit codes.
   Each start alternates ``rounds`` times
   (a) endpoints: for fixed indices, the grid-optimal endpoint pair of the
       weighted least-squares surrogate, per channel -- endpoint A over a
       window of codes around the continuous optimum, the best B for each A in
       closed form (quantization clamps to the representable range) -- and
   (b) indices: exact argmin of the decoded error over the 8 palette entries,
   keeping per subset the lowest decoded error seen.  After the first round
   only the ``keep`` best candidate shapes of each block continue.
3. The candidate shape with the lowest decoded error wins (ties: lowest id).

So every decision between shapes, indices and endpoint pairs that is kept is
taken on the exactly decoded error; the screening model only limits which
shapes get refined (``refine_top=32, keep=32`` refines all of them: ~8x slower
and 0.2-0.8 dB better on the textures of ``benchmarks/bench_encode.py``).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
import torch

from . import mode10
from .tables import PARTITIONS2, WEIGHTS3
from bcfpipe.pooltrace import trace_pool

__all__ = ["validate_texels", "encode", "encode_params", "Settings", "blocks_from_image", "image_from_blocks", "MAX_UNSIGNED", "MAX_SIGNED"]

MAX_UNSIGNED = 65504.0  # half bits 0x7BFF = (0xFFFF * 31) >> 6
MAX_SIGNED = 65504.0  # half bits 0x7BFF = (0x7FFF * 31) >> 5

#: Index patterns tried per subset in the refinement: the projection parameter
#: tau in [0, 1] is mapped to ``round(3.5 + (tau - 0.5) * 7 * s)``.  (Adding
#: 3/7, indices 2..5, gains ~0.15 dB for ~40 % more time.)
_SCALES = (1.0, 1.0 / 7.0)


# ---------------------------------------------------------------------------
# image <-> blocks
# ---------------------------------------------------------------------------


def validate_texels(texels) -> np.ndarray:
    a = np.asarray(texels)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"texels must have shape (H, W, 3), got {a.shape}")
    h, w, _ = a.shape
    if h == 0 or w == 0 or h % 4 or w % 4:
        raise ValueError(f"H and W must be positive multiples of 4, got {h}x{w}")
    if a.dtype.kind not in "fiub":
        raise ValueError(f"texels must be numeric, got dtype {a.dtype}")
    a = a.astype(np.float32, copy=False)
    if not np.all(np.isfinite(a)):
        raise ValueError("texels contain NaN or infinity")
    return a


def blocks_from_image(img: np.ndarray) -> np.ndarray:
    """(H, W, C) -> (H/4 * W/4, 16, C): blocks row-major, texels row-major within a block."""
    h, w, c = img.shape
    return img.reshape(h // 4, 4, w // 4, 4, c).transpose(0, 2, 1, 3, 4).reshape(-1, 16, c)


def image_from_blocks(blocks: np.ndarray, width: int, height: int) -> np.ndarray:
    """Inverse of :func:`blocks_from_image`."""
    c = blocks.shape[-1]
    return blocks.reshape(height // 4, width // 4, 4, 4, c).transpose(0, 2, 1, 3, 4).reshape(height, width, c)


# ---------------------------------------------------------------------------
# constants
# ---------------------------------------------------------------------------


class EncodeContext:
    """Constant tensors for one (signed, device).

    Endpoints are handled as table positions ``i`` in [0, 63]; the stored code is
    ``i + lo`` (lo = 0 unsigned, -32 signed).
    """

    def __init__(self, signed: bool, device: torch.device):
        self.signed = signed
        self.device = device
        codes, u = mode10.unquantize_table(signed)
        self.lo = int(codes[0])
        self.u = torch.tensor(u, dtype=torch.float32, device=device)
        self.u64 = self.u.double()
        # every decodable channel value: pal_rows[ia * 64 + ib, k]
        ia, ib, k = np.meshgrid(np.arange(64), np.arange(64), np.arange(8), indexing="ij")
        v = mode10.interpolate(u[ia], u[ib], WEIGHTS3[k])
        pal = mode10.half_bits_to_float(mode10.finish_unquantize(v, signed)).astype(np.float32)
        self.pal_rows = torch.tensor(pal.reshape(64 * 64, 8), device=device)
        self.w3 = torch.tensor(WEIGHTS3, dtype=torch.float32, device=device)
        part = torch.tensor(PARTITIONS2, dtype=torch.long, device=device)  # (32, 16)
        self.part = part
        # subset row (2 * shape + subset) of each (shape, texel), flattened (512,)
        self.sub_of = (2 * torch.arange(32, device=device)[:, None] + part).reshape(-1)
        self.flat_sub_texel = self.sub_of * 16 + torch.arange(16, device=device).repeat(32)
        s = torch.zeros(64, 16, dtype=torch.float32, device=device)
        s[0::2] = (part == 0).float()
        s[1::2] = (part == 1).float()
        self.subset_mask = s
        self.subset_bool = s.bool()
        self.subset_cnt = s.sum(1)

    def nearest(self, x: torch.Tensor) -> torch.Tensor:
        """Table position (long) of the endpoint whose unquantized value is nearest ``x``."""
        if not self.signed:
            mid = torch.clamp(torch.round((x - 512.0) * (1.0 / 1024.0)), 1.0, 62.0)
            i = torch.where(x < 768.0, 0.0, torch.where(x > 64767.5, 63.0, mid))
            return i.long()
        a = x.abs()
        mid = torch.clamp(torch.round((a - 512.0) * (1.0 / 1024.0)), 1.0, 30.0)
        c = torch.where(a < 768.0, 0.0, torch.where(a > 31999.5, 31.0, mid))
        return (torch.where(x < 0, -c, c) + 32.0).long()


def _to_q(t: torch.Tensor, signed: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Target values -> (q in the 16-bit interpolation domain, (d value / d q)^2)."""
    a = t.abs() if signed else t
    m, ex = torch.frexp(a)
    exf = ex.to(a.dtype)
    sub = a < 2.0**-14
    y = torch.where(sub, a * 2.0**24, 1024.0 * (exf + 13.0) + 2048.0 * m)
    # slope of the value w.r.t. its half bits: 2^(E-15)/1024 (normal), 2^-24 (subnormal)
    slope = torch.where(sub, torch.full_like(a, 2.0**-24), torch.exp2(exf - 11.0))
    if signed:
        q = torch.sign(t) * (y + 0.5) * (32.0 / 31.0)
        dq = slope * (31.0 / 32.0)
    else:
        q = (y + 0.5) * (64.0 / 31.0)
        dq = slope * (31.0 / 64.0)
    return q, dq * dq


# ---------------------------------------------------------------------------
# stage 1: every shape
# ---------------------------------------------------------------------------


def _pca(ctx: EncodeContext, q: torch.Tensor):
    """Per block and subset row (64): centre (B,64,3), unit axis (B,64,3), projections (B,64,16)
    of all 16 texels, and min / max projection over the subset's texels (B,64)."""
    qm = q.mean(1, keepdim=True)
    qc = q - qm  # centred for numerical stability
    s, cnt = ctx.subset_mask, ctx.subset_cnt[:, None]
    mean = torch.matmul(s, qc) / cnt  # (B, 64, 3)
    x, y, z = qc.unbind(-1)
    prods = torch.stack([x * x, y * y, z * z, x * y, x * z, y * z], dim=-1)
    m2 = torch.matmul(s, prods) / cnt  # (B, 64, 6)
    mx, my, mz = mean.unbind(-1)
    cxx, cyy, czz = m2[..., 0] - mx * mx, m2[..., 1] - my * my, m2[..., 2] - mz * mz
    cxy, cxz, cyz = m2[..., 3] - mx * my, m2[..., 4] - mx * mz, m2[..., 5] - my * mz
    # power iteration from the covariance column of the largest variance
    pick0 = (cxx >= cyy) & (cxx >= czz)
    pick1 = ~pick0 & (cyy >= czz)
    vx = torch.where(pick0, cxx, torch.where(pick1, cxy, cxz))
    vy = torch.where(pick0, cxy, torch.where(pick1, cyy, cyz))
    vz = torch.where(pick0, cxz, torch.where(pick1, cyz, czz))
    for _ in range(3):
        n = torch.maximum(torch.maximum(vx.abs(), vy.abs()), vz.abs()) + 1e-30
        vx, vy, vz = vx / n, vy / n, vz / n
        vx, vy, vz = (cxx * vx + cxy * vy + cxz * vz, cxy * vx + cyy * vy + cyz * vz, cxz * vx + cyz * vy + czz * vz)
    axis = torch.stack([vx, vy, vz], dim=-1)
    norm = axis.norm(dim=-1, keepdim=True)
    ok = norm > 1e-20 * (cxx.abs() + cyy.abs() + czz.abs())[..., None] + 1e-30
    axis = torch.where(ok, axis / torch.where(ok, norm, 1.0), torch.full_like(axis, 3.0**-0.5))
    proj = torch.matmul(axis, qc.transpose(1, 2)) - (mean * axis).sum(-1, keepdim=True)  # (B, 64, 16)
    inside = ctx.subset_bool
    pmin = torch.where(inside, proj, torch.inf).amin(-1)
    pmax = torch.where(inside, proj, -torch.inf).amax(-1)
    # variance off the principal axis (per texel): trace(C) - a^T C a
    ax, ay, az = axis.unbind(-1)
    along = cxx * ax * ax + cyy * ay * ay + czz * az * az + 2.0 * (cxy * ax * ay + cxz * ax * az + cyz * ay * az)
    off_axis = torch.clamp(cxx + cyy + czz - along, min=0.0)
    return mean + qm, axis, proj, pmin, pmax, off_axis


def _shape_scores(ctx: EncodeContext, om, off_axis, pmin, pmax) -> tuple[torch.Tensor, torch.Tensor]:
    """Models of each shape's error, (B, 32) each, used to pick the shapes worth refining.

    Per subset, weighted like the decoded error (sum of the texels' weights):
    ``score`` = variance off the principal axis + the quantization noise of 8
    palette entries spread over the subset's extent along the axis,
    ``(0.2 L)^2 / 12``; ``resid`` = the variance off the axis alone (how far the
    shape is from two exact line segments).
    """
    wsum = torch.matmul(ctx.subset_mask, om.mean(-1, keepdim=True)).squeeze(-1)  # (B, 64)
    ext = pmax - pmin
    res = wsum * off_axis
    sub = res + wsum * (0.2 * ext) ** 2 / 12.0
    return sub[:, 0::2] + sub[:, 1::2], res[:, 0::2] + res[:, 1::2]


# ---------------------------------------------------------------------------
# stage 2: refinement
# ---------------------------------------------------------------------------


def _assign(ctx: EncodeContext, t, ia, ib, member):
    """Exact best index per texel for endpoint positions ia, ib (M, 2, 3); member (M, 16).

    Returns (k (M, 16), per-subset decoded error (M, 2))."""
    m = t.shape[0]
    ab = ia * 64 + ib  # (M, 2, 3)
    ab_t = torch.gather(ab, 1, member[:, :, None].expand(m, 16, 3))  # (M, 16, 3)
    val = ctx.pal_rows.index_select(0, ab_t.reshape(-1)).view(m, 16, 3, 8)  # the 8 palette entries
    e = None
    for ch in range(3):  # per channel: avoids slow broadcasting over the innermost dim
        d = val[:, :, ch, :] - t[:, :, ch : ch + 1]
        e = d * d if e is None else e.addcmul_(d, d)
    emin, k = e.min(-1)  # (M, 16)
    sub_err = torch.zeros(m, 2, dtype=emin.dtype, device=emin.device).scatter_add_(1, member, emin)
    return k, sub_err


def _grid_step(ctx: EncodeContext, qc, c, w, onehot, k, window: int):
    """For fixed indices: per subset & channel the endpoint pair (ia, ib) minimising the
    weighted least-squares surrogate, searching A over a window of codes around the
    continuous optimum and taking the best B for each A in closed form.

    ``qc`` (M,16,3): q minus the per-item offset ``c`` (M,1,3) (keeps float32 exact
    enough); ``w`` (M,16) per-texel weights; ``onehot`` (M,2,16) subset membership.
    """
    alpha = ctx.w3[k] * (1.0 / 64.0)  # (M, 16)
    a1 = 1.0 - alpha
    ow = onehot * w[:, None, :]  # (M, 2, 16)
    owa, owb = ow * a1[:, None, :], ow * alpha[:, None, :]
    scal = torch.bmm(owa, torch.stack([a1, alpha], -1))  # (M, 2, 2): saa, sab
    sbb = torch.bmm(owb, alpha[..., None])  # (M, 2, 1)
    saq, sbq = torch.bmm(owa, qc), torch.bmm(owb, qc)  # (M, 2, 3)
    # contiguous (M, 2, 3) operands: broadcast views take torch's slow paths
    saa, sab, sbb = (v.expand_as(saq).contiguous() for v in (scal[..., 0:1], scal[..., 1:2], sbb))
    c = c.expand_as(saq).contiguous()
    det = saa * sbb - sab * sab
    ok = det > 1e-6 * saa * sbb
    ua_c = (sbb * saq - sab * sbq) / torch.where(ok, det, 1.0)
    stot = saa + 2.0 * sab + sbb
    qbar = (saq + sbq) / torch.where(stot > 0, stot, 1.0)
    centre = ctx.nearest(torch.where(ok, ua_c, qbar) + c)  # (M, 2, 3)
    lo = torch.clamp(centre - window, 0, 63 - 2 * window)
    has_b = sbb > 0
    inv_b = torch.where(has_b, 1.0 / torch.where(has_b, sbb, 1.0), 0.0)
    best = torch.full_like(saq, torch.inf)
    best_a, best_b = lo, lo
    for j in range(2 * window + 1):  # A = lo + j; best B in closed form
        ia = lo + j
        da = ctx.u[ia] - c
        ub_opt = torch.where(has_b, (sbq - da * sab) * inv_b, da)
        ib = ctx.nearest(ub_opt + c)
        db = ctx.u[ib] - c
        err = da * (saa * da + 2.0 * (sab * db - saq)) + db * (sbb * db - 2.0 * sbq)
        better = err < best
        best = torch.where(better, err, best)
        best_a = torch.where(better, ia, best_a)
        best_b = torch.where(better, ib, best_b)
    return best_a, best_b


def _bracket(ctx: EncodeContext, ea, eb):
    """Endpoint positions for a segment ea -> eb (q domain), rounded *outwards* per channel
    so that the quantized segment (and its palette) covers the continuous one."""
    ia, ib = ctx.nearest(ea), ctx.nearest(eb)
    up = ea <= eb
    ua, ub = ctx.u[ia], ctx.u[ib]
    ia = torch.where(up, ia - (ua > ea).long(), ia + (ua < ea).long()).clamp(0, 63)
    ib = torch.where(up, ib + (ub < eb).long(), ib - (ub > eb).long()).clamp(0, 63)
    return ia, ib


class _Starts(NamedTuple):
    """M (block, shape) candidates to refine: their targets ``t``, q values ``q`` and weights ``om``
    (M,16,3); each texel's subset ``member`` and position ``tau`` along its subset's principal
    segment (M,16); the segments' ends ``seg`` (ea, eb), each (M,2,3), in the q domain."""

    t: torch.Tensor
    q: torch.Tensor
    om: torch.Tensor
    member: torch.Tensor
    tau: torch.Tensor
    seg: tuple[torch.Tensor, torch.Tensor]


def _refine(ctx: EncodeContext, starts: _Starts, rounds: int, window: int, per_block: int = 1, keep: int = 1):
    """Refine M (block, shape) candidates, ``per_block`` consecutive ones per block.

    Starts: one per entry of `_SCALES` (index patterns from tau) plus one from the
    outward-rounded segment ends.  After the first round only the ``keep`` best
    candidates of each block go on.  Returns (ia, ib (M',2,3), k (M',16),
    err (M',), items (M',)): the surviving candidates' results and positions.
    """
    t, q, om, member, tau, seg = starts
    m = t.shape[0]
    ns = len(_SCALES) + 1
    k = [torch.clamp(torch.round(3.5 + (tau - 0.5) * (7.0 * s)), 0.0, 7.0).long() for s in _SCALES]
    ia0, ib0 = _bracket(ctx, *seg)
    k0, err0 = _assign(ctx, t, ia0, ib0, member)
    k = torch.stack(k + [k0], 1).reshape(m * ns, 16)
    c = q.mean(1, keepdim=True)
    w = om.mean(-1)  # one weight per texel, shared by the channels
    rep = lambda v: v.repeat_interleave(ns, dim=0)  # noqa: E731
    t, qc, c, w, member = rep(t), rep(q - c), rep(c), rep(w), rep(member)
    onehot = (member[:, None, :] == torch.arange(2, device=t.device)[None, :, None]).to(t.dtype)
    best_err = torch.full((m, ns, 2), torch.inf, device=t.device)
    best_err[:, -1] = err0
    best_err = best_err.reshape(m * ns, 2)
    best_ia = torch.zeros(m, ns, 2, 3, dtype=torch.long, device=t.device)
    best_ia[:, -1] = ia0
    best_ia = best_ia.reshape(m * ns, 2, 3)
    best_ib = torch.zeros(m, ns, 2, 3, dtype=torch.long, device=t.device)
    best_ib[:, -1] = ib0
    best_ib = best_ib.reshape(m * ns, 2, 3)
    best_k = k.clone()
    items = torch.arange(m, device=t.device)
    for r in range(max(1, rounds)):
        ia, ib = _grid_step(ctx, qc, c, w, onehot, k, window)
        k, sub_err = _assign(ctx, t, ia, ib, member)
        better = sub_err < best_err
        best_err = torch.where(better, sub_err, best_err)
        best_ia = torch.where(better[..., None], ia, best_ia)
        best_ib = torch.where(better[..., None], ib, best_ib)
        best_k = torch.where(torch.gather(better, 1, member), k, best_k)
        if r == 0 and rounds > 1 and keep < per_block:
            # continue only with the `keep` most promising candidates of each block
            item_err = best_err.reshape(m, ns, 2).amin(1).sum(1).reshape(-1, per_block)
            order = torch.argsort(item_err, dim=1, stable=True)[:, :keep]
            items = (torch.arange(item_err.shape[0], device=t.device)[:, None] * per_block + order).reshape(-1)
            rows = (items[:, None] * ns + torch.arange(ns, device=t.device)).reshape(-1)
            t, qc, c, w, member, onehot, k = t[rows], qc[rows], c[rows], w[rows], member[rows], onehot[rows], k[rows]
            best_err, best_ia, best_ib, best_k = best_err[rows], best_ia[rows], best_ib[rows], best_k[rows]
            m = items.shape[0]
    return (*_best_start(best_err.reshape(m, ns, 2), best_ia, best_ib, best_k, member.reshape(m, ns, 16)[:, 0]),
            items)


def _best_start(err, best_ia, best_ib, best_k, member0):
    """Per candidate the best start of each subset, independently for the two subsets: (ia, ib
    (m,2,3), k (m,16), err (m,)), from each start's results (``err`` (m,ns,2), the others by row
    ``m * ns``) and the candidates' subsets ``member0`` (m,16)."""
    m, ns, _ = err.shape
    j = err.argmin(1)  # (m, 2)
    rows = torch.arange(m, device=err.device)[:, None] * ns + j  # (m, 2)
    ia = torch.stack([best_ia[rows[:, s], s] for s in range(2)], 1)
    ib = torch.stack([best_ib[rows[:, s], s] for s in range(2)], 1)
    k_rows = torch.gather(rows, 1, member0)  # (m, 16): row of each texel's subset
    kk = best_k[k_rows.reshape(-1), torch.arange(16, device=err.device).repeat(m)].reshape(m, 16)
    return ia, ib, kk, torch.gather(err, 1, j[:, None, :]).squeeze(1).sum(1)


# ---------------------------------------------------------------------------
# driver
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Settings:
    """`encode_params`' keyword arguments: how hard it searches and where it runs.

    ``refine_top``: how many of the best-scoring shapes of the screening are refined, ``keep`` of
    them (per block) beyond the first round (``refine_top=32, keep=32``: every shape fully);
    ``rounds``: endpoint/index alternations per start; ``window``: half-width of the endpoint-A
    search window (clamped to [0, 31]); ``chunk``: blocks per vectorized step (small chunks stay in
    cache); ``device``: torch device (default CPU); ``workers``: CPU threads working on chunks in
    parallel (default ``torch.get_num_threads()``).
    """

    refine_top: int = 4
    keep: int = 2
    rounds: int = 2
    window: int = 4
    chunk: int = 512
    device: str | torch.device | None = None
    workers: int | None = None


def _shortlist(ctx: EncodeContext, om, pca, shapes, refine_top: int) -> torch.Tensor:
    """The shapes to refine per block, (B, kk): the given ``shapes`` (kk = 1), every shape, or the
    ``refine_top`` best-scoring ones, the shape closest to two exact segments always among them."""
    if shapes is not None:
        return shapes[:, None]
    b = om.shape[0]
    kk = max(1, min(int(refine_top), 32))
    if kk == 32:
        return torch.arange(32, device=om.device).repeat(b, 1)
    _, _, _, pmin, pmax, off_axis = pca
    score, resid = _shape_scores(ctx, om, off_axis, pmin, pmax)
    cand = torch.argsort(score, dim=1, stable=True)[:, :kk]  # (B, kk)
    if kk > 1:  # make sure the shape closest to two exact segments is refined too
        line = resid.argmin(1)
        have = (cand == line[:, None]).any(1)
        cand[:, -1] = torch.where(have, cand[:, -1], line)
    return cand


def _starts(ctx: EncodeContext, t, q, om, pca, cand) -> _Starts:
    """The refinement's inputs for every (block, candidate shape) of ``cand`` (B, kk), block-major."""
    b, kk = cand.shape
    centre, axis, proj, pmin, pmax, _ = pca
    shape_m = cand.reshape(b * kk)
    member = ctx.part[shape_m]  # (M, 16)
    blk = torch.arange(b, device=t.device).repeat_interleave(kk)
    rows = 2 * shape_m[:, None] + member  # (M, 16) subset row of each texel
    tex = torch.arange(16, device=t.device)
    p = proj[blk[:, None], rows, tex]  # (M, 16)
    lo, hi = pmin[blk[:, None], rows], pmax[blk[:, None], rows]
    span = hi - lo
    tau = torch.where(span > 0, (p - lo) / torch.where(span > 0, span, 1.0), 0.5)
    srow = 2 * shape_m[:, None] + torch.arange(2, device=t.device)  # (M, 2) subset rows
    cen, ax = centre[blk[:, None], srow], axis[blk[:, None], srow]  # (M, 2, 3)
    seg = (cen + pmin[blk[:, None], srow][..., None] * ax, cen + pmax[blk[:, None], srow][..., None] * ax)
    return _Starts(t[blk], q[blk], om[blk], member, tau, seg)


def _encode_chunk(ctx: EncodeContext, t: torch.Tensor, shapes, s: Settings):
    b = t.shape[0]
    lim = MAX_SIGNED if ctx.signed else MAX_UNSIGNED
    t = t.clamp(-lim if ctx.signed else 0.0, lim)
    q, om = _to_q(t, ctx.signed)
    om = om / om.amax(dim=(1, 2), keepdim=True)  # per-block relative weights
    pca = _pca(ctx, q)
    cand = _shortlist(ctx, om, pca, shapes, s.refine_top)
    kk = cand.shape[1]
    keep = min(kk, max(1, int(s.keep)))
    ia, ib, k, err, items = _refine(ctx, _starts(ctx, t, q, om, pca, cand), s.rounds, s.window, kk, keep)
    kk = items.shape[0] // b
    cand = cand.reshape(-1)[items].reshape(b, kk)
    err = err.reshape(b, kk)
    best = torch.zeros(b, dtype=torch.long, device=t.device)
    best_err, best_shape = err[:, 0], cand[:, 0]
    for j in range(1, kk):
        better = (err[:, j] < best_err) | ((err[:, j] == best_err) & (cand[:, j] < best_shape))
        best = torch.where(better, j, best)
        best_err = torch.where(better, err[:, j], best_err)
        best_shape = torch.where(better, cand[:, j], best_shape)
    sel = torch.arange(b, device=t.device) * kk + best
    ia, ib, k = ia[sel], ib[sel], k[sel]
    endpoints = torch.stack([ia[:, 0], ib[:, 0], ia[:, 1], ib[:, 1]], dim=1) + ctx.lo  # (B, 4, 3)
    return endpoints, k, best_shape


def _fixed_shapes(partitions, n: int) -> np.ndarray | None:
    """``partitions`` (None, an int or an int array (n,)) as one shape per block, or None."""
    if partitions is None:
        return None
    pa = np.asarray(partitions)
    if pa.dtype.kind not in "iu" or pa.ndim > 1:
        raise ValueError("partitions must be an int or an int array of shape (n,)")
    shapes = np.broadcast_to(pa.astype(np.int64), (n,)).copy()
    if shapes.min() < 0 or shapes.max() > 31:
        raise ValueError("partitions must lie in [0, 31]")
    return shapes


def _run_chunks(run, starts: range, device: torch.device, workers: int | None) -> None:
    """``run(start)`` for every chunk: in turn on a GPU; on the CPU in ``workers`` threads, torch's
    intra-op thread count set to 1 meanwhile and restored after."""
    if device.type != "cpu":
        for s in starts:
            run(s)
        return
    if workers is None:
        workers = torch.get_num_threads()
    workers = max(1, min(int(workers), len(starts)))
    # Ops run single-threaded and chunks in parallel Python threads (torch releases
    # the GIL inside ops): cheaper than intra-op threads for these mid-sized tensors
    # and far more robust when the cores are shared with other work (OpenMP
    # threads spin-wait badly on a loaded machine).
    prev = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        if workers == 1:
            for s in starts:
                run(s)
        else:
            trace_pool("bc6h-thread-pool", workers)
            with ThreadPoolExecutor(workers) as pool:
                list(pool.map(run, starts))
    finally:
        torch.set_num_threads(prev)


def encode_params(texels, signed: bool = False, partitions=None, **settings):
    """Fit mode-10 block parameters to an (H, W, 3) float image.

    Returns ``(endpoints int64 (n,4,3), indices int64 (n,16), partition int64 (n,))``,
    ``n = H/4 * W/4`` blocks in row-major order, in the conventions of
    :mod:`bcfpipe.bc6h.mode10` (endpoints in [-32, 31] when ``signed``).  Indices
    are not anchor-canonicalized (:func:`mode10.pack` does that).

    ``partitions``: None (choose per block by minimum decoded error), an int (that
    shape everywhere) or an int array (n,).  ``settings``: the fields of `Settings`
    (``refine_top``, ``keep``, ``rounds``, ``window``, ``chunk``, ``device``, ``workers``).
    """
    s = Settings(**settings)
    img = validate_texels(texels)
    blocks = blocks_from_image(img)
    n = blocks.shape[0]
    dev = torch.device(s.device) if s.device is not None else torch.device("cpu")
    shapes_all = _fixed_shapes(partitions, n)
    s = replace(s, window=int(min(max(s.window, 0), 31)))
    ctx = EncodeContext(signed, dev)
    out_e = np.empty((n, 4, 3), np.int64)
    out_i = np.empty((n, 16), np.int64)
    out_p = np.empty((n,), np.int64)

    def run(start: int) -> None:
        e = min(n, start + s.chunk)
        with torch.no_grad():
            t = torch.from_numpy(np.ascontiguousarray(blocks[start:e])).to(dev)
            shp = None if shapes_all is None else torch.from_numpy(np.ascontiguousarray(shapes_all[start:e])).to(dev)
            ep, ix, pt = _encode_chunk(ctx, t, shp, s)
            out_e[start:e], out_i[start:e], out_p[start:e] = ep.cpu().numpy(), ix.cpu().numpy(), pt.cpu().numpy()

    _run_chunks(run, range(0, n, s.chunk), dev, s.workers)
    return out_e, out_i, out_p


def encode(texels, signed: bool = False, partitions=None, **kwargs) -> np.ndarray:
    """Encode an (H, W, 3) float image (H, W multiples of 4) into mode-10 BC6H blocks.

    Returns uint8 (H/4 * W/4, 16), blocks in row-major order; decode with
    ``bcfpipe.bc6h.decode(blocks, W, H, signed)``.  Keyword arguments: the fields of
    `Settings`.
    """
    return mode10.pack(*encode_params(texels, signed=signed, partitions=partitions, **kwargs), signed=signed)
