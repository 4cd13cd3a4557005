"""What `--layout auto` will weigh for a texture set, known before anything is encoded or trained
(issue 50): the resolution R, the profiles, the probe's, BC@R's bytes and its repacks' (exact, from
block counts), and the sizes the build can ship. `decide_layout` takes its probe profile and BC@R's
bytes from here, and `scan` and `plan` print the same figures, so the two cannot drift.

What ships is decided by training, so a size is a range: under the default objective every
candidate that may ship is at most BC@R's bytes (BC@R itself always qualifies) and at least the
smallest candidate's files (a repack's bytes, or the feature textures of the smallest profile or
mip split, which a model's files exceed). With ``--layout neural`` and no ``--classic`` the size
is exact: the feature textures and the weight record (`formats.sizes.neural_bytes`, the one byte
estimator, which also sizes the profiles the probe is chosen from).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from bcfpipe.config import PROFILES
from bcfpipe.config import LAYER_CHANNELS_OF, N_LAYERS, resolve_profile
from bcfpipe.config import DEFAULT_T0, max_t0_layers
from bcfpipe.formats import weights as W
from bcfpipe.formats.display import bytes_range
from bcfpipe.formats.display import bytes_text
from bcfpipe.formats.sizes import feature_bytes, neural_bytes, texture_bytes, widened, widened_inputs
from bcfpipe.formats.vocabulary import T0, FeatureFormat, Layout
from bcfpipe.layout.classic import bc_levels, named_groups
from bcfpipe.layout.classic import MAX_REPACK_SIDE, bc7_quality_set, repacks, split_levels
from bcfpipe.layout.classic import groups as classic_groups
from bcfpipe.texset.texture_set import Channel, TextureSet, semantic_info
from bcfpipe.train.gains import CPU_PROFILES, GPU_PROFILES


def candidate_profiles(asked: str, device: str) -> list[str]:
    """Paper profiles no larger than ``asked``, largest first; a small source's own profile
    (``auto-N``) alone."""
    if asked not in PROFILES:
        return [asked]
    pool = GPU_PROFILES if device.startswith("cuda") else CPU_PROFILES
    top = PROFILES[asked][0]
    return sorted((p for p in pool if PROFILES[p][0] <= top), key=lambda p: -PROFILES[p][0]) or [asked]


def uses_layout(options, semantics) -> bool:
    """Whether a material is fitted here rather than trained all neural: ``--layout auto``, or
    ``--classic`` naming one of its ``semantics`` (``options``: TrainingOptions or a job's Options)."""
    return options.layout == Layout.AUTO or bool(set(options.classic or ()) & set(semantics))


def bc_resolution(side: int, profile: str) -> int:
    """R: the T_0 of the profile asked for (1k -> 1024), or the set's larger ``side`` for auto."""
    return PROFILES[profile][0] if profile in PROFILES else side


@dataclass(frozen=True)
class LayoutPrediction:
    """What a material's build will weigh and the bytes it can ship."""

    layout: str  # auto | neural
    resolution: int  # R: BC@R's level 0 side
    profile: str  # the profile asked, resolved (what --layout neural trains)
    profiles: tuple[str, ...]  # the profiles auto weighs, largest first
    probe: str | None  # auto's probe p0: the largest profile within BC@R's bytes, else the smallest; None: no probe
    bc_bytes: int  # BC@R, exact
    repack_bytes: tuple[int, ...]  # its BC7 repacks, exact (weighed up to R = 4096)
    min_bytes: int
    max_bytes: int
    t0_layers: tuple[int, ...] = (1,)  # the T_0 widths weighed (--layout neural: the one trained)
    probe_t0_layers: int = 1  # the probe's T_0 width: the narrowest weighed
    neural: tuple[tuple[str, int, int], ...] = ()  # every all-neural candidate weighed: (profile, T_0 width, bytes)
    bc7_bytes: int = 0  # the BC7 quality set at R (reported against, not shipped); 0: not measured
    probe_fits: bool = False  # the probe's bytes are within BC@R's (else it is the smallest profile)

    @property
    def exact(self) -> bool:
        return self.min_bytes == self.max_bytes

    def to_json(self) -> dict:
        return {"layout": self.layout, "resolution": self.resolution, "profile": self.profile,
                "profiles": list(self.profiles), "probe": self.probe, "bc_bytes": self.bc_bytes,
                "repack_bytes": list(self.repack_bytes), "min_bytes": self.min_bytes, "max_bytes": self.max_bytes,
                "exact": self.exact, "t0_layers": list(self.t0_layers),
                "neural_bytes": [{"profile": p, "t0_layers": w, "size_bytes": b} for p, w, b in self.neural],
                "bc7_quality_bytes": self.bc7_bytes or None, "probe_fits": self.probe_fits}

    def size_text(self) -> str:
        """``X MiB`` when exact, else ``X–Y MiB`` (KiB for small sets: `display.bytes_range`)."""
        return bytes_range(self.min_bytes, self.max_bytes)

    def probe_text(self) -> str:
        """What the probe is and why, as scan and plan say it: the largest profile within BC@R's
        bytes, the smallest when none is (it then measures the neural part of a mip split or a
        mixed layout), or no probe at all when nothing neural can fit."""
        bc = bytes_text(self.bc_bytes)
        if self.probe is None:
            return (f"no probe: nothing neural fits within BC@R's {bc} (not even the smallest features), "
                    "so nothing trains")
        if self.probe_fits:
            return f"a probe at {self.probe} (the largest profile within BC@R's {bc})"
        return (f"a probe at {self.probe} (the smallest profile; none fits within BC@R's {bc}, so the probe "
                "only measures what a mip split or a mixed layout can hold)")


def probe_profile(profiles: Sequence[str], sizes: dict[str, int], bc_bytes: int) -> str:
    """p0: the largest profile whose bytes fit within BC@R's, else the smallest."""
    return next((p for p in profiles if sizes[p] <= bc_bytes), profiles[-1])


@dataclass(frozen=True)
class Query:
    """What `predict` reads: a set of ``width``×``height`` with ``n_channels`` channels (``n_out``
    decoder outputs) whose classic groups are ``groups`` (`classic.Group`), at BC resolution
    ``resolution``, profile ``asked`` (resolved; its feature ``asked_resolutions``), on ``device``,
    ``dims`` = (MLP inputs, hidden). ``classic``: the group names ``--classic`` keeps."""

    groups: tuple
    width: int
    height: int
    n_channels: int
    n_out: int
    asked: str
    asked_resolutions: tuple[int, ...]
    resolution: int
    device: str
    dims: tuple[int, int]
    layout: str = Layout.AUTO
    match_bc: bool = False
    classic: tuple[str, ...] = ()
    widths: tuple[int, ...] = (1,)  # the T_0 widths weighed (`widths_of`); --layout neural: the one trained


def predict(q: Query) -> LayoutPrediction:
    """The prediction for the set and job ``q`` describes."""
    groups, asked, asked_resolutions, resolution, layout = q.groups, q.asked, q.asked_resolutions, q.resolution, q.layout
    levels = bc_levels(q.width, q.height, resolution)
    by_group = {g.name: texture_bytes(g.format, levels) for g in groups}
    bc = sum(by_group.values())
    n_in, hidden = q.dims
    profiles = tuple(candidate_profiles(asked, q.device))
    res_of = {p: (PROFILES[p] if p in PROFILES else tuple(asked_resolutions)) for p in profiles}
    w0 = q.widths[0]

    def model(res, w, n_out):
        return neural_bytes(widened(res, w), widened_inputs(n_in, w), hidden, n_out)

    exact_neural = model(asked_resolutions, w0, q.n_out)
    forced = set(q.classic)
    forced_bytes = sum(b for name, b in by_group.items() if name in forced)
    if layout == Layout.NEURAL:
        if not forced:
            return LayoutPrediction(str(layout), resolution, asked, (asked,), None, bc, (), exact_neural, exact_neural,
                                    q.widths, w0)
        if forced >= set(by_group):
            return LayoutPrediction(str(layout), resolution, asked, (asked,), None, bc, (), bc, bc)
        return LayoutPrediction(str(layout), resolution, asked, (asked,), None, bc, (),
                                forced_bytes + feature_bytes(widened(asked_resolutions, w0)), forced_bytes + exact_neural,
                                q.widths, w0)
    sizes = {p: model(res_of[p], w0, q.n_channels) for p in profiles}
    p0 = probe_profile(profiles, sizes, bc)
    packs = []
    if resolution <= MAX_REPACK_SIDE:
        for rp in repacks(groups):
            if forced & set(rp.replaces):
                continue
            packs.append(sum(b for name, b in by_group.items() if name not in rp.replaces)
                         + sum(texture_bytes(g.format, levels) for g in rp.groups))
    side = max(q.width, q.height)
    split_floor = [texture_bytes(g.format, levels[:split_levels(1, resolution, side)]) for g in groups]
    neural_lows = [forced_bytes + min(feature_bytes(res_of[p]) for p in profiles)]
    if not forced:
        neural_lows.append(sum(split_floor) + feature_bytes((8, 8, 8, 4), headers=True))
    if not q.match_bc and min(neural_lows) > bc:  # no neural layout can ship within BC@R's bytes: no probe
        p0, neural_lows = None, []
    low = min([bc, *packs, *neural_lows])
    if q.match_bc:  # any size: a mixed layout may hold every group but one and the largest model
        high = max(bc, *packs, bc + max(model(res_of[p], w, q.n_out) for p in profiles for w in q.widths))
    else:
        high = bc
    neural = tuple((p, w, model(res_of[p], w, q.n_channels)) for p in profiles for w in q.widths)
    quality = bc7_quality_set(groups)
    bc7 = bc if quality is None else bc + sum(texture_bytes(g.format, levels) - by_group[g.name] for g in quality.groups)
    return LayoutPrediction(str(layout), resolution, asked, profiles, p0, bc, tuple(packs), low, high, q.widths, w0,
                            neural, bc7 if resolution <= MAX_REPACK_SIDE else 0,
                            p0 is not None and sizes[p0] <= bc)


def spec_texture_set(specs: Sequence[tuple[str, str, str]], width: int, height: int,
                     hdr_files: Sequence[str] = (), vectors: Sequence = ()) -> TextureSet:
    """A texture set of ``specs`` ((semantic, file, channels)) with no texels (a broadcast zero):
    enough for `classic.groups`. A colour read from one of ``hdr_files`` counts as HDR (BC6H);
    ``vectors``: the job's colours kept in their slots (TextureSet.vectors)."""
    chans = []
    for sem, path, letters in specs:
        info = semantic_info(sem)
        for i, letter in enumerate(letters):
            comp = "rgb"[i] if info.kind == "color" else "xy"[i] if info.kind == "normal" else letter
            hdr = info.kind == "color" and path in hdr_files
            chans.append(Channel(info.name, comp, info.kind, path, i, log_gain=1.0 if hdr else 0.0))
    data = np.broadcast_to(np.zeros((1, 1, len(chans)), np.float32), (height, width, len(chans)))
    return TextureSet(data, tuple(chans), width, height, tuple(vectors))


def predict_specs(specs: Sequence[tuple[str, str, str]], float_files: Sequence[str], width: int, height: int,
                  options, vectors: Sequence = ()) -> LayoutPrediction | None:
    """The prediction for a job of ``specs`` at ``width``×``height`` with ``options`` (a job's
    manifest.Options or TrainingOptions): None under ``--target-psnr`` (rate control sizes it). A
    colour from one of ``float_files`` may be HDR (BC6H, twice BC1's bytes) or not, which only its
    texels say: the prediction then spans both."""
    if options.target_psnr is not None or not width:
        return None
    side = max(width, height)
    asked, res = resolve_profile(options.profile, side)
    dims = (N_LAYERS * LAYER_CHANNELS_OF[FeatureFormat(options.features or FeatureFormat.BC7)], options.hidden)
    layout = options.layout if uses_layout(options, [s for s, _, _ in specs]) else Layout.NEURAL
    n = sum(len(ch) for _, _, ch in specs)
    device = options.device or "cpu"
    hdr_colours = [p for s, p, _ in specs if p in float_files]

    out = []
    for hdr in ((), tuple(hdr_colours)) if hdr_colours else ((),):
        groups = classic_groups(spec_texture_set(specs, width, height, hdr, vectors))
        out.append(predict(Query(groups, width, height, n, n, asked, tuple(res), bc_resolution(side, options.profile),
                                 device, dims, layout, bool(options.match_bc),
                                 named_groups(groups, options.classic or ()), widths_of(options, layout, n))))
    return merge(out)


def widths_of(options, layout: str, n_channels: int) -> tuple[int, ...]:
    """The T_0 widths a job of ``n_channels`` weighs (``layout`` auto) or trains: --t0-layers alone
    when given (capped at the set's components), one layer for --layout neural or a trained T_0,
    else every width from 1 to as many layers as the set has components (`config.max_t0_layers`).
    ``options``: a TrainingOptions or a manifest's Options."""
    features = FeatureFormat(options.features or FeatureFormat.BC7)
    top = max_t0_layers(n_channels, features)
    if T0(options.t0 or DEFAULT_T0[features]) != T0.PCA:
        return (1,)
    asked = getattr(options, "t0_layers", None)
    if asked is not None:
        return (min(int(asked), top),)
    return tuple(range(1, top + 1)) if layout == Layout.AUTO else (1,)


def merge(preds: Sequence[LayoutPrediction]) -> LayoutPrediction:
    """One prediction spanning ``preds`` (the same set, a colour HDR or not)."""
    a = preds[0]
    if len(preds) == 1:
        return a
    probes = list(dict.fromkeys(p.probe for p in preds if p.probe))
    return LayoutPrediction(a.layout, a.resolution, a.profile, a.profiles, " or ".join(probes) or None,
                            max(p.bc_bytes for p in preds), tuple(sorted({b for p in preds for b in p.repack_bytes})),
                            min(p.min_bytes for p in preds), max(p.max_bytes for p in preds), a.t0_layers,
                            a.probe_t0_layers, a.neural, max(p.bc7_bytes for p in preds),
                            all(p.probe_fits for p in preds))


def build_range(preds: Sequence[LayoutPrediction]) -> tuple[int, int]:
    """The bytes a build of these jobs writes, as its manifest totals them: every job's range and
    weights.bin's header, table and record alignment (bcfpipe.formats.weights.pack)."""
    n = len(preds)
    low = sum(p.min_bytes for p in preds) + W.align_up(W.HEADER.size)
    high = sum(p.max_bytes for p in preds) + W.align_up(W.HEADER.size + W.ENTRY.size * n) + n * (W.ALIGN - 1)
    return low, high
