"""Classic channel groups: the BC textures an engine ships for a texture set, as candidates for
the channels that neural features lose (issue 31), and their BC7 repacks at the same bytes.

A group is one texture of `bcfpipe.texset.baselines.pack_texture_set` (codec 'bc'): BC1 for a colour
or a packed (ARM-style) file, BC4 for a lone scalar, BC5 for a normal map's slopes (x / z, y / z) / m
(so that a UsdUVTexture reads (s_x, s_y, 1), whose direction is the normal's; issue 57,
bcfpipe.texset.normals), BC6H_UF16 for a colour beyond 1 from a float file (HDR). A colour a UsdUVTexture reads whose source repeats a channel (TextureSet.vectors) is one
BC1 with the channel in each slot it feeds. Its texels store set values v as t, with
v = t * texel_scale + texel_bias: t in [0, 1] (a normal's slope: s = (2t - 1) m), or for BC6H the source's
linear value itself (v = t / value_scale - value_bias / value_scale), so that every map from texel
to source value is affine, as a UsdUVTexture's scale and bias apply it; no classic texture stores
a log curve. Every
mip down to 1×1 is encoded, at the resolution R the material settles on; when R is below the
set's, reference mips above R see level 0 magnified bilinearly, as a GPU samples it.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bcfpipe.config import DEFAULT_ENCODE, EncodePreset
from bcfpipe.formats import dds
from bcfpipe.formats.addressing import address
from bcfpipe.formats.bcn import BLOCK_BYTES, ClassicFormat
from bcfpipe.formats.bcn import DXGI
from bcfpipe.formats.bcn import decode_levels
from bcfpipe.formats.dds import HEADER_BYTES
from bcfpipe.formats.sizes import disk_bytes as zstd_bytes
from bcfpipe.formats.vocabulary import wrap_axes
from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset import baselines as B
from bcfpipe.texset import encoding
from bcfpipe.texset.baselines import NORMAL_SLOPE, USD, pack_texture_set
from bcfpipe.texset.metrics import mse_per_mip
from bcfpipe.texset.normals import angular_stats, rebuild_z, slope_normal, slope_scale
from bcfpipe.texset.parallel import encode_workers
from bcfpipe.texset.texture_set import TextureSet


@dataclass(frozen=True)
class Group:
    """One classic texture: its format and the texture set's channels it stores, in texel order."""

    format: ClassicFormat
    channels: tuple[int, ...]  # a channel twice where a colour's slots repeat it (TextureSet.vectors)
    name: str  # the semantics it holds, e.g. "albedo" or "occlusion+roughness+metallic"
    slope: bool = False  # a normal map as BC5 of its slopes (x / z, y / z) / m (issue 57)

    def texel_map(self, ts: TextureSet) -> tuple[tuple[float, float], ...]:
        """(texel_scale, texel_bias) per stored channel: set value = t * scale + bias (BC6H: t is
        the source value, set value (t - value_bias) / value_scale)."""
        if self.format == ClassicFormat.BC6H:
            return tuple((1.0 / ts.channels[i].value_scale, 0.0 - ts.channels[i].value_bias / ts.channels[i].value_scale)
                         for i in self.channels)
        return tuple((2.0, -1.0) if ts.channels[i].kind == "normal" else (1.0, 0.0) for i in self.channels)


@dataclass
class EncodedGroup:
    """A group's blocks per level (largest first) and what they decode to at every reference mip."""

    group: Group
    levels: list[tuple[np.ndarray, int, int]]  # (blocks (n, block bytes) uint8, width, height)
    decoded: list[np.ndarray]  # per reference mip: (H_k, W_k, len(channels)) set values (a slope normal: x, y, z as
    # USD reads it); decide_layout empties it once measured
    disk: object = None  # its file's bytes on disk (`disk_bytes`): an int once measured, a Future while measured aside
    slope: float | None = None  # a slope normal's m: slope = (2t - 1) m
    planned: tuple[tuple[int, int], ...] = ()  # (width, height) per level, for a group not yet encoded

    @property
    def encoded(self) -> bool:
        return bool(self.levels)

    def level_bytes(self) -> list[int]:
        """Each level's block bytes: counted from its blocks, or for a group not yet encoded from its
        `planned` sizes (exact: BC blocks have fixed sizes)."""
        if self.levels:
            return [b.nbytes for b, _, _ in self.levels]
        return [-(-w // 4) * -(-h // 4) * BLOCK_BYTES[self.group.format] for w, h in self.planned]

    def texel_map(self, ts: TextureSet) -> tuple[tuple[float, float], ...]:
        """(texel_scale, texel_bias) per stored channel: the group's, a slope normal's (2m, -m)."""
        if self.slope is not None:
            return tuple((2.0 * self.slope, -self.slope) for _ in self.group.channels)
        return self.group.texel_map(ts)

    @property
    def size_bytes(self) -> int:
        """Its DDS file's bytes (header included), as a layout's other files are counted."""
        return HEADER_BYTES + sum(self.level_bytes())


def groups(ts: TextureSet) -> tuple[Group, ...]:
    """The classic textures of ``ts``, in pack order: BC@R as a UsdUVTexture can read it
    (`baselines.USD`: a normal map as BC5 slopes; a colour in ``ts.vectors`` in its slots' order,
    named by its semantic)."""
    vectors = {tuple(chans): sem for sem, chans in ts.vectors}
    out = []
    for fmt, idx in pack_texture_set(ts, USD):
        names = [vectors[tuple(idx)]] if tuple(idx) in vectors else \
            list(dict.fromkeys(ts.channels[i].semantic for i in idx))
        slope = fmt == NORMAL_SLOPE
        out.append(Group(ClassicFormat.BC5 if slope else ClassicFormat(fmt), tuple(idx), "+".join(names), slope))
    return tuple(out)


def bc_levels(width: int, height: int, resolution: int) -> list[tuple[int, int]]:
    """(width, height) of BC@R's levels: the set's box mip whose larger side is R (the set itself
    when it is no larger), then every mip down to 1×1 (`classic.encode`)."""
    side = max(width, height)
    d = 0
    while (side >> d) > resolution and (side >> d) > 1:
        d += 1
    w, h = max(1, width >> d), max(1, height >> d)
    out = [(w, h)]
    while (w, h) != (1, 1):
        w, h = max(1, w // 2), max(1, h // 2)
        out.append((w, h))
    return out


def named_groups(groups: Sequence[Group | EncodedGroup], semantics: Sequence[str]) -> tuple[str, ...]:
    """The names of the groups that hold one of ``semantics`` (--classic): a packed group goes whole."""
    wanted = set(semantics)
    names = [getattr(g, "group", g).name for g in groups]
    return tuple(n for n in names if wanted & set(n.split("+")))


def planned(ts: TextureSet, group: Group, resolution: int) -> EncodedGroup:
    """``group`` at ``resolution``, not yet encoded: its sizes known, its blocks not (`bcfpipe.layout.estimate`)."""
    return EncodedGroup(group, [], [], planned=tuple(bc_levels(ts.width, ts.height, resolution)))


def encode(ts: TextureSet, resolution: int, ref_mips: Sequence[np.ndarray], wrap: str = "repeat") -> list[EncodedGroup]:
    """Every group of ``ts`` (BC@R) encoded at ``resolution`` with its full mip chain (`encode_group`)."""
    return [encode_group(ts, g, resolution, ref_mips, wrap) for g in groups(ts)]


def encode_group(ts: TextureSet, group: Group, resolution: int, ref_mips: Sequence[np.ndarray],
                 wrap: str = "repeat", enc: EncodePreset = DEFAULT_ENCODE) -> EncodedGroup:
    """One group encoded in full at ``resolution``, every mip, by the encoder and preset that ship
    it (`group_texels`). Reference mips above ``resolution`` see level 0 magnified with the
    material's addressing, as the runtime samples it; a slope normal's m is taken from level 0's
    set values, as `baselines.slope_mips` takes it."""
    d = sum(1 for m in ref_mips if max(m.shape[:2]) > resolution)
    cols = list(group.channels)
    m = None
    if group.slope:
        m = slope_scale(ref_mips[d][..., cols])
    levels: list = []
    decoded = group_texels(ts, group, ref_mips[d:], levels, m, enc)
    if group.slope:  # magnified as texels, then read as a normal
        decoded = usd_normals(levels, [r.shape[:2] for r in ref_mips], wrap, m)
    else:
        decoded = [magnify(decoded[0], *ref_mips[k].shape[:2], wrap) for k in range(d)] + decoded
    return EncodedGroup(group, levels, decoded, slope=m)


def disk_bytes_aside(g: EncodedGroup) -> None:
    """Start measuring ``g``'s bytes on disk in a thread beside what follows (zstd at level 19
    releases the GIL: 1.2 s for a 2048² BC1 file), when the job has a second core: ``g.disk`` is
    then a Future that `disk_bytes` resolves; else nothing (measured when asked)."""
    if encode_workers() < 2 or g.disk is not None:
        return
    global _disk_pool
    if _disk_pool is None:
        _disk_pool = ThreadPoolExecutor(1, thread_name_prefix="bcfpipe-disk-bytes")
        trace_pool("disk-bytes-thread", 1)
    g.disk = _disk_pool.submit(_file_disk_bytes, g.levels, g.group.format)


_disk_pool = None


def _file_disk_bytes(levels, fmt: ClassicFormat) -> int:
    return zstd_bytes([dds.encode(levels, dxgi_format=DXGI[fmt])])


def usd_normals(levels: Sequence[tuple[np.ndarray, int, int]], shapes: Sequence[tuple[int, int]],
                wrap, m: float) -> list[np.ndarray]:
    """A slope normal's (x, y, z) per reference mip as a UsdPreviewSurface reads it: the BC5 texels
    (magnified with ``wrap`` above the texture's resolution, as a GPU samples it) as (s_x, s_y, 1),
    s = (2t - 1) m, normalised (`normals.slope_normal`)."""
    d = len(shapes) - len(levels)
    t = [x[..., :2] for x in decode_levels(ClassicFormat.BC5, levels)]
    return [slope_normal(magnify(t[0], h, w, wrap), m) for h, w in shapes[:d]] + [slope_normal(x, m) for x in t]


# Above this, every repack's BC7 chain takes minutes to encode (one 4096² texture with its mips: 43 s on
# one thread, quicktex's BC1 of BC@R about twice that; 8192²: about 3 minutes each)
MAX_REPACK_SIDE = 4096


@dataclass(frozen=True)
class Repack:
    """BC@R with some groups merged into BC7 textures in the same bytes or fewer: ``groups`` (BC7)
    replace the BC@R groups named in ``replaces``."""

    groups: tuple[Group, ...]
    replaces: tuple[str, ...]
    label: str  # e.g. "albedo+opacity as BC7", "all 8 channels in 2 BC7"


def repacks(groups: Sequence[Group]) -> list[Repack]:
    """The BC7 repacks of BC@R's ``groups`` worth weighing, at no more bytes: each BC1 group with
    each BC4 group in one BC7 texture (RGB + A: 8 bits per texel, as theirs together), and every
    channel in BC7 textures, four per texture, where that takes no more bytes and keeps every colour
    and normal whole at one texture's r, g(, b) (`_whole_inputs`: one UsdUVTexture output then feeds
    its UsdPreviewSurface input, bcfpipe.builder.usd_classic). BC7
    has up to 4-bit indices, 7-bit endpoints and partitions where BC1 has 2-bit indices and 5:6:5
    endpoints (benchmarks/bound_classic_bc7.py measures what that buys). A BC6H (HDR) group is
    never repacked: BC7 is UNORM, and stays as it is beside any repack; nor is a normal: its slopes
    stay BC5 (one index per channel; BC7 shares one across x, y, z, 3° worse at p99 on the brick)."""
    groups = [g for g in groups if g.format != ClassicFormat.BC6H and not g.slope]
    out = [Repack((Group(ClassicFormat.BC7, a.channels + b.channels, f"{a.name}+{b.name}"),), (a.name, b.name),
                  f"{a.name}+{b.name} as BC7")
           for a in groups if a.format == ClassicFormat.BC1 for b in groups if b.format == ClassicFormat.BC4]
    channels = [c for g in groups for c in g.channels]
    n = -(-len(channels) // 4)
    bins = _whole_inputs(groups, n)
    if len(groups) > 1 and 16 * n <= sum(BLOCK_BYTES[g.format] for g in groups) and bins is not None:
        packed = []
        for i, part in enumerate(bins):
            name = "+".join(dict.fromkeys(g.name for g in groups for c in g.channels if c in part))
            packed.append(Group(ClassicFormat.BC7, tuple(part), f"bc7 {i + 1}/{n}: {name}" if n > 1 else name))
        if all(len(r.groups) != len(packed) or r.groups[0].channels != packed[0].channels for r in out):
            out.append(Repack(tuple(packed), tuple(g.name for g in groups),
                              f"all {len(channels)} channels in {n} BC7"))
    return out


def bc7_quality_set(groups: Sequence[Group]) -> Repack | None:
    """The BC7 quality set as a change of BC@R: every BC1 texture (a colour or a packed file) in BC7,
    the same channels in the same slots at twice the bytes; BC5 slope normals, BC4 lone scalars and BC6H
    kept. What quality-focused pipelines ship, and the second set every layout is reported against
    (issue 52). None when BC@R has no BC1 texture: the quality set is then BC@R itself."""
    bc1 = [g for g in groups if g.format == ClassicFormat.BC1]
    if not bc1:
        return None
    return Repack(tuple(Group(ClassicFormat.BC7, g.channels, g.name) for g in bc1), tuple(g.name for g in bc1),
                  "BC7 quality set")


def disk_bytes(g: EncodedGroup, keep: int | None = None) -> int:
    """``g``'s DDS file on disk, zstd-compressed whole as the export writes it (`formats.sizes.disk_bytes`);
    with ``keep``, the file of its first ``keep`` levels (a mip split's). The whole file's is measured once."""
    if keep is not None:
        return _file_disk_bytes(g.levels[:keep], g.group.format)
    if g.disk is None:
        g.disk = _file_disk_bytes(g.levels, g.group.format)
    elif not isinstance(g.disk, int):  # measured aside (`_disk_aside`)
        g.disk = g.disk.result()
    return g.disk


@dataclass(frozen=True, eq=False)
class DiskBytes:
    """``groups``' files on disk, summed when first read (``int()``, `disk_bytes`): the sizes measured
    aside (`disk_bytes_aside`) are waited for where layout.json is written, after the export and the
    final measure, whose single-threaded parts leave the zstd thread a core (the brick at draft
    waited 1 s for it as soon as its repack was encoded)."""

    groups: tuple[EncodedGroup, ...]

    def __int__(self) -> int:
        return sum(disk_bytes(g) for g in self.groups)


def _vector(g: Group) -> bool:
    """A group one vector input reads through a UsdUVTexture's rgb: a normal (BC5) or a colour (BC1
    of one semantic; a packed ARM-style BC1 holds scalars, each its own input)."""
    return g.format == ClassicFormat.BC5 or (g.format == ClassicFormat.BC1 and "+" not in g.name)


def _whole_inputs(groups: Sequence[Group], n: int) -> list[tuple[int, ...]] | None:
    """Every channel of ``groups`` in ``n`` textures of four: each vector group alone at slots r, g(, b)
    of its own texture (in pack order), the scalars after them in order; None when they do not fit."""
    vectors = [g for g in groups if _vector(g)]
    if len(vectors) > n:
        return None
    bins = [list(g.channels) for g in vectors] + [[] for _ in range(n - len(vectors))]
    for c in (c for g in groups if not _vector(g) for c in g.channels):
        free = next((b for b in bins if len(b) < 4), None)
        if free is None:
            return None
        free.append(c)
    return [tuple(b) for b in bins if b]


def encode_bc7(ts: TextureSet, group: Group, resolution: int, ref_mips: Sequence[np.ndarray],
               wrap: str = "repeat") -> EncodedGroup:
    """One BC7 group of ``ts`` at ``resolution`` with every mip (`encode_group`)."""
    return encode_group(ts, group, resolution, ref_mips, wrap)


def group_texels(ts: TextureSet, group: Group, images: Sequence[np.ndarray], blocks: list | None = None,
                 slope_m: float | None = None, enc: EncodePreset = DEFAULT_ENCODE) -> list[np.ndarray]:
    """``group`` encoded and decoded in each of ``images`` (set values, (H, W, channels) each: a
    level, or a mosaic of some of its blocks, `bcfpipe.layout.estimate`), by the encoder and preset
    that ship it: each as set values in the group's slots (a slope normal: its (x, y, z) as USD
    reads it, with the whole level's ``slope_m``). With ``blocks``, each image's (blocks, w, h).
    ``enc``: the quality preset's encoder presets (`config.ENCODE_PRESETS`)."""
    cols = list(group.channels)
    if group.format == ClassicFormat.BC7:
        scale, bias = (np.array(v, np.float32) for v in zip(*group.texel_map(ts)))
        pad = 4 - len(cols)
        stored = [np.concatenate([(m[..., cols] - bias) / scale, np.zeros(m.shape[:2] + (pad,), np.float32)], -1)
                  if pad else (m[..., cols] - bias) / scale for m in images]
        out, _ = B.bc7_mips(stored, blocks, enc.bc7)
        return [o[..., :len(cols)] * scale + bias for o in out]
    if group.slope:
        normals, _, _ = B.slope_mips([m[..., cols] for m in images], blocks, slope_m)
        return normals
    normal = np.array([ts.channels[i].kind == "normal" for i in cols])
    out, _ = B.encode_texture(ts, group.format.value, cols, images, blocks, None, enc.bc1_level)
    return [B.from_storage(o, normal) for o in out]


def measure_repack(ts: TextureSet, bc: Sequence[EncodedGroup], e_bc: np.ndarray, rp: Repack, resolution: int,
                   ref_mips: Sequence[np.ndarray], masks: Sequence[np.ndarray] | None = None,
                   wrap: str = "repeat") -> tuple[list[EncodedGroup], np.ndarray, int]:
    """BC@R (its groups ``bc``, errors ``e_bc``) with ``rp`` applied, measured exactly: (the BC7
    groups, decoded mips kept; (mips, channels) errors of the whole set; its bytes)."""
    enc = [encode_bc7(ts, g, resolution, ref_mips, wrap) for g in rp.groups]
    cols = [c for g in rp.groups for c in g.channels]
    e = e_bc.copy()
    e[:, cols] = channel_errors(ts, enc, ref_mips, masks)[:, cols]
    size = (sum(g.size_bytes for g in bc if g.group.name not in rp.replaces) + sum(g.size_bytes for g in enc))
    return enc, e, size


def _taps(at: np.ndarray, n_out: int, n_in: int, mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two texels of ``n_in`` (addressed with ``mode``) a linear filter reads at the centres of
    target texels ``at`` of ``n_out``, and the second one's weight."""
    x = (np.asarray(at) + 0.5) * n_in / n_out - 0.5
    x0 = np.floor(x).astype(np.int64)
    f = (x - x0).astype(np.float32)
    return address(x0, n_in, mode), address(x0 + 1, n_in, mode), f


def magnify(img: np.ndarray, height: int, width: int, wrap) -> np.ndarray:
    """Bilinear magnification at the target's texel centres (GL's LINEAR filter), with ``wrap``
    (one mode, or the (S, T) pair: S along the width, T along the height)."""
    h, w = img.shape[:2]
    wrap_s, wrap_t = wrap_axes(wrap)
    ya, yb, fy = _taps(np.arange(height), height, h, wrap_t)
    xa, xb, fx = _taps(np.arange(width), width, w, wrap_s)
    out = np.empty((height, width) + img.shape[2:], np.float32)
    band = max(1, (1 << 22) // max(1, width * int(np.prod(img.shape[2:]))))  # 16 MiB temporaries, even at 8K
    for y0 in range(0, height, band):
        y = slice(y0, y0 + band)
        rows = img[ya[y]] * (1 - fy[y])[:, None, None] + img[yb[y]] * fy[y][:, None, None]
        out[y] = rows[:, xa] * (1 - fx)[None, :, None] + rows[:, xb] * fx[None, :, None]
    return out


def channel_errors(ts: TextureSet, groups: Sequence[EncodedGroup], ref_mips: Sequence[np.ndarray],
                   masks: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """(mips, channels) MSE of BC@R, every channel from its group (over ``masks``' texels if given),
    as `mse_per_channel` gives it (an HDR channel in its learnt log domain); channel by channel on
    views, with no decoded set assembled (2.7 GiB at 8192² × 8 channels)."""
    out = np.zeros((len(ref_mips), ts.num_channels))
    for g in groups:
        for j, c in enumerate(g.group.channels):
            if c in g.group.channels[:j]:  # a repeated channel is measured at its first slot
                continue
            gain = np.array([ts.channels[c].log_gain], np.float32)
            out[:, c] = mse_per_mip(encoding.encode_levels([r[..., c:c + 1] for r in ref_mips], gain),
                                    encoding.encode_levels([m[..., j:j + 1] for m in g.decoded], gain),
                                    [ts.channels[c]], None, masks)
        if g.group.slope:
            out[:, list(g.group.channels)] += normal_z_errors(ts, g, ref_mips, masks)[:, None] / 2.0
    return out


def normal_z_errors(ts: TextureSet, g: EncodedGroup, ref_mips: Sequence[np.ndarray],
                    masks: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """Per mip, the MSE of a normal's z as USD reads it (``g.decoded``'s third column) against the
    reference's rebuilt z, at the normal's peak: half of it is added to x's and half to y's, so the
    normal's channels sum the whole vector's error (issue 57: the error counts z as USD reads it)."""
    x = ts.channels[g.group.channels[0]]
    return np.array(mse_per_mip([rebuild_z(r[..., list(g.group.channels)])[..., 2:] for r in ref_mips],
                                [m[..., 2:3] for m in g.decoded], [x], None, masks))


def angular_errors(ts: TextureSet, g: EncodedGroup, ref_mips: Sequence[np.ndarray], mip: int = 0,
                   mask: np.ndarray | None = None) -> tuple[float, float]:
    """(mean, p99) angle in degrees at reference mip ``mip`` between a slope normal as USD reads it
    and the reference (x, y and rebuilt z)."""
    return angular_stats(rebuild_z(ref_mips[mip][..., list(g.group.channels)]), g.decoded[mip], mask)


def split_levels(split: int, resolution: int, reference_side: int) -> int:
    """How many of BC@R's levels serve the reference mips below ``split``: level j serves mip j + d,
    where d counts the reference mips larger than R (level 0 magnified for those), at least one."""
    d = sum(1 for k in range(reference_side.bit_length()) if max(1, reference_side >> k) > resolution)
    return max(1, split - d)
