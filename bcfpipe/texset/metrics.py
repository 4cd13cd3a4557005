"""Evaluation metrics (paper §6.1): PSNR over mips, SSIM and FLIP at mip 0.

Inputs are the reference mips and the decoded mips, lists of (H_k, W_k, c) float arrays of the
same shapes, and the `Channel` tuple of the texture set they came from.

PSNR (all values in dB, +inf for a perfect match):

* Every channel's error is measured relative to its nominal range, the *peak*: 1 for colour and
  scalar data in [0, 1], 2 for normals in [-1, 1]. So a normal error counts as its error in the
  stored [0, 1] encoding and channels of both kinds can be averaged.
* MSE_k of mip k = mean over all texels and all channels of (ref - dec)^2 / peak^2.
* Headline ``psnr`` = 10 log10(1 / mean_k MSE_k): the MSE averaged over mips (each mip weighs the
  same, as in NTC), then converted; mips whose smaller side is below `min_size` (default 4, i.e.
  the 2x2 and 1x1 tail whose few texels would weigh as much as a full level) are left out of the
  mean (all mips are used when none is that large).
* ``psnr_per_mip[k]`` = 10 log10(1 / MSE_k) for every mip; ``psnr_per_group[semantic]`` is the
  headline formula restricted to that semantic's channels.
* With a coverage mask (the texels the scene's meshes read, bcfpipe.scan.coverage),
  ``psnr_covered`` and ``psnr_per_mip_covered`` are the same formulas over covered texels only, and
  ``covered_fraction`` is mip 0's covered share.

SSIM: skimage's ``structural_similarity`` per channel group at mip 0 (Wang et al. settings: 11-tap
Gaussian window, sigma 1.5, population covariance; data_range = the group's peak), computed by
`texset.ssim` (the same values, in bands of rows over the job's cores; skimage itself below
11x11); ``ssim`` is the unweighted mean over groups. FLIP: LDR-FLIP at mip 0 on colour groups
(albedo, emissiveColor), values clipped to [0, 1] and treated as sRGB-encoded (as stored colour
textures are), 67 pixels per degree, computed by `texset.flip` (``flip_evaluator``'s error map);
``flip`` is the mean over colour groups, or None when the set has none.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from bcfpipe.formats.manifest import Quality as Metrics
from bcfpipe.texset.texture_set import Channel
from bcfpipe.texset import encoding

__all__ = ["Metrics", "compute_metrics", "metrics_from_mse", "psnr_from_mse", "mse_per_mip", "mse_per_channel", "ssim_group", "flip_group"]

COLOR_KIND = "color"
BAND_VALUES = 1 << 22  # values per band when a metric walks a large mip in bands of rows


def psnr_from_mse(mse: float, peak: float = 1.0) -> float:
    """10 log10(peak^2 / mse); +inf when mse is 0."""
    if mse < 0 or not math.isfinite(mse):
        raise ValueError(f"MSE must be finite and >= 0, got {mse}")
    return math.inf if mse == 0 else 10.0 * math.log10(peak * peak / mse)


def _check(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray], channels: Sequence[Channel]) -> None:
    if not ref_mips:
        raise ValueError("no reference mips given")
    if len(ref_mips) != len(dec_mips):
        raise ValueError(f"{len(ref_mips)} reference mips but {len(dec_mips)} decoded mips")
    for k, (r, d) in enumerate(zip(ref_mips, dec_mips)):
        if np.shape(r) != np.shape(d):
            raise ValueError(f"mip {k}: reference shape {np.shape(r)} != decoded shape {np.shape(d)}")
        if np.ndim(r) != 3 or np.shape(r)[2] != len(channels):
            raise ValueError(f"mip {k}: shape {np.shape(r)} does not match {len(channels)} channels")
        if not np.all(np.isfinite(d)):
            raise ValueError(f"decoded mip {k} contains NaN or inf")


def _squared_errors(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray], channels: Sequence[Channel],
                    cols: Sequence[int], masks: Sequence[np.ndarray] | None, gains: np.ndarray | None) -> np.ndarray:
    """(mips, len(cols)) peak-normalised MSE of the channels ``cols``, over the ``masks``' texels when
    given, the channels with a gain in their log domain (``gains``, per channel of ``channels``). One
    pass over each mip, in bands of rows: float64 temporaries stay small at 8K."""
    cols = list(cols)
    inv_peak2 = np.array([1.0 / channels[i].peak ** 2 for i in cols])
    g = None if gains is None or not np.any(gains[cols] > 0) else gains[cols]
    out = np.zeros((len(ref_mips), len(cols)))
    for k, (r, d) in enumerate(zip(ref_mips, dec_mips)):
        r, d = np.asarray(r), np.asarray(d)
        rows = max(1, BAND_VALUES // max(1, r.shape[1] * len(cols)))
        total, count = np.zeros(len(cols)), 0
        whole = cols == list(range(r.shape[2]))
        for y in range(0, r.shape[0], rows):
            rb = r[y:y + rows] if whole else r[y:y + rows, :, cols]
            db = d[y:y + rows] if whole else d[y:y + rows, :, cols]
            if g is not None:
                rb, db = encoding.encode_levels([rb], g)[0], encoding.encode_levels([db], g)[0]
            diff = db.astype(np.float64) - rb
            err = diff * diff
            if masks is not None:
                keep = masks[k][y:y + rows]
                err, count = err[keep], count + int(keep.sum())
            total += err.reshape(-1, len(cols)).sum(0)
        n = r.shape[0] * r.shape[1] if masks is None else count
        out[k] = total * inv_peak2 / n if n else 0.0
    return out


def mse_per_mip(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray],
                channels: Sequence[Channel], select: Sequence[int] | None = None,
                masks: Sequence[np.ndarray] | None = None) -> list[float]:
    """Peak-normalised MSE of each mip over the channels in `select` (default all), and with
    ``masks`` ((H_k, W_k) bool per mip) over the texels they cover only."""
    sel = range(len(channels)) if select is None else select
    return [float(m) for m in _squared_errors(ref_mips, dec_mips, channels, sel, masks, None).mean(1)]


def mse_per_channel(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray],
                    channels: Sequence[Channel], masks: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """(mips, channels) peak-normalised MSE (over the ``masks``' texels when given), an HDR channel
    in its log domain as `compute_metrics` measures it: the terms whose mean over channels is
    compute_metrics' per-mip MSE, so a layout's figures (bcfpipe.layout) are the ones its export
    measures."""
    channels = tuple(channels)
    return _squared_errors(ref_mips, dec_mips, channels, range(len(channels)), masks, encoding.gains(channels))


def _mean_psnr(mses: Sequence[float], use: Sequence[int]) -> float:
    return psnr_from_mse(float(np.mean([mses[k] for k in use])))


def ssim_group(ref: np.ndarray, dec: np.ndarray, peak: float) -> float | None:
    """SSIM of one (H, W, g) group; None when the image is smaller than 3x3. From 11x11 up
    skimage's Gaussian SSIM (`texset.ssim`, in bands over the job's cores); below, skimage's
    uniform window as wide as the image allows."""
    h, w = ref.shape[:2]
    if min(h, w) >= 11:
        from bcfpipe.texset.ssim import mean_ssim  # lazy: start-up (numba)

        return mean_ssim(ref, dec, peak)
    if min(h, w) < 3:
        return None
    from skimage.metrics import structural_similarity  # lazy: start-up

    kw = dict(data_range=peak, win_size=min(h, w) - (1 - min(h, w) % 2))
    r, d = np.asarray(ref, np.float32), np.asarray(dec, np.float32)  # skimage filters in the input's float type
    if r.shape[2] == 1:
        return float(structural_similarity(r[..., 0], d[..., 0], **kw))
    return float(structural_similarity(r, d, channel_axis=-1, **kw))


def flip_group(ref: np.ndarray, dec: np.ndarray) -> float:
    """Mean LDR FLIP of one (H, W, 3) sRGB-encoded colour group, values clipped to [0, 1]
    (`texset.flip`: flip_evaluator's map, in bands over the job's cores)."""
    from bcfpipe.texset.flip import mean_flip  # lazy: start-up (numba)

    return mean_flip(ref, dec)


def metrics_from_mse(mse: np.ndarray, channels: Sequence[Channel], shapes: Sequence[tuple[int, int]],
                     min_size: int = 4) -> Metrics:
    """The PSNR part of :func:`compute_metrics` (no SSIM, FLIP or coverage) from each mip's squared
    error per channel, ``mse`` (mips, channels), measured where compute_metrics measures (HDR
    channels in their learnt domain); ``shapes``: each mip's (H, W)."""
    channels = tuple(channels)
    inv_peak2 = np.array([1.0 / ch.peak ** 2 for ch in channels])
    norm = np.asarray(mse, np.float64) * inv_peak2
    use = [k for k, s in enumerate(shapes) if min(s) >= min_size] or list(range(len(shapes)))
    groups: dict[str, list[int]] = {}
    for i, ch in enumerate(channels):
        groups.setdefault(ch.semantic, []).append(i)
    mses = norm.mean(1)
    return Metrics(psnr=_mean_psnr(mses, use), psnr_per_mip=tuple(psnr_from_mse(m) for m in mses),
                   psnr_per_group={g: _mean_psnr(norm[:, idx].mean(1), use) for g, idx in groups.items()},
                   ssim=None, ssim_per_group={}, flip=None, flip_per_group={}, mips_in_mean=len(use))


def compute_metrics(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray],
                    channels: Sequence[Channel], *, min_size: int = 4,
                    ssim: bool = True, flip: bool = True, masks: Sequence[np.ndarray] | None = None) -> Metrics:
    """PSNR (headline, per mip, per group), SSIM and FLIP of decoded mips against the reference;
    with coverage ``masks`` (one (H_k, W_k) bool per mip) also the PSNR over covered texels.
    An HDR channel (``log_gain`` > 0) is measured in its log domain (bcfpipe.texset.encoding),
    where equal errors are equal ratios: against the linear peak, every texel below a few
    percent of it would count for nothing."""
    return metrics_and_errors(ref_mips, dec_mips, channels, min_size=min_size, ssim=ssim, flip=flip, masks=masks)[0]


def metrics_and_errors(ref_mips: Sequence[np.ndarray], dec_mips: Sequence[np.ndarray],
            channels: Sequence[Channel], *, min_size: int = 4,
            ssim: bool = True, flip: bool = True, masks: Sequence[np.ndarray] | None = None) -> tuple[Metrics, np.ndarray]:
    """`compute_metrics`, and the (mips, channels) errors its PSNRs come from (`mse_per_channel`,
    over the ``masks``' texels when given): each texel's error is taken once per channel, and every
    mean (all channels, a group's, the covered texels') is a mean of those."""
    channels = tuple(channels)
    _check(ref_mips, dec_mips, channels)
    use = [k for k, m in enumerate(ref_mips) if min(m.shape[:2]) >= min_size] or list(range(len(ref_mips)))

    groups: dict[str, list[int]] = {}
    for i, ch in enumerate(channels):
        groups.setdefault(ch.semantic, []).append(i)

    per_channel = mse_per_channel(ref_mips, dec_mips, channels)
    mses = per_channel.mean(1)
    psnr_per_group = {g: _mean_psnr(per_channel[:, idx].mean(1), use) for g, idx in groups.items()}

    r0, d0 = np.asarray(ref_mips[0]), np.asarray(dec_mips[0])
    gains = encoding.gains(channels)
    if (ssim or flip) and np.any(gains > 0):
        r0, d0 = (encoding.encode_levels([x], gains)[0] for x in (r0, d0))
    flip_groups = [g for g, idx in groups.items() if flip and channels[idx[0]].kind == COLOR_KIND and len(idx) == 3]

    # each group's SSIM and FLIP run in bands of rows over the job's cores
    ssim_per_group: dict[str, float] = {}
    if ssim:
        values = [ssim_group(r0[..., idx], d0[..., idx], channels[idx[0]].peak) for idx in groups.values()]
        ssim_per_group = {g: v for g, v in zip(groups, values) if v is not None}
    flip_per_group = {g: flip_group(r0[..., groups[g]], d0[..., groups[g]]) for g in flip_groups}

    covered, errors = {}, per_channel
    if masks is not None:
        errors = mse_per_channel(ref_mips, dec_mips, channels, masks)
        covered = {"covered_fraction": float(np.asarray(masks[0]).mean()),
                   "psnr_covered": _mean_psnr(errors.mean(1), use),
                   "psnr_per_mip_covered": tuple(psnr_from_mse(m) for m in errors.mean(1))}
    metrics = Metrics(
        psnr=_mean_psnr(mses, use),
        psnr_per_mip=tuple(psnr_from_mse(m) for m in mses),
        psnr_per_group=psnr_per_group,
        ssim=float(np.mean(list(ssim_per_group.values()))) if ssim_per_group else None,
        ssim_per_group=ssim_per_group,
        flip=float(np.mean(list(flip_per_group.values()))) if flip_per_group else None,
        flip_per_group=flip_per_group,
        mips_in_mean=len(use),
        **covered,
    )
    return metrics, errors


