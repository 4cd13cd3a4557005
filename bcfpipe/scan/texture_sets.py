"""What a scanned material becomes: model channels, texture-set specs and targets, and the
constants its folded channels and fallbacks give (bcfpipe.scan.grouping then groups identical
texture sets into one training job). `bcfpipe scan` and `bcfpipe build` both read the scene through
these modules, so they agree on what is modelled."""
from __future__ import annotations

from dataclasses import dataclass, field
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Sequence

from bcfpipe.formats.vocabulary import ColorSpace, Wrap, wrap_name
from bcfpipe.errors import one_line
from bcfpipe.formats.images import ImageReadError, MissingChannel
from bcfpipe.scan.content import ChannelContent, content_of
from bcfpipe.scan.content import srgb_to_linear
from bcfpipe.scan.content import ChannelContent, sample_at
from bcfpipe.scan.sources import SourceFile, common_resolution, source_file

if TYPE_CHECKING:  # pxr and torch load lazily: `import bcfpipe` stays cheap
    from bcfpipe.scan.results import MaterialScan


_COLOR_SEMANTIC = {"diffuseColor": "albedo", "emissiveColor": "emissiveColor"}
_SCALAR_SEMANTICS = frozenset({"occlusion", "roughness", "metallic", "displacement", "opacity"})


@dataclass(frozen=True)
class ModelChannel:
    """One decoder output before normal z: a file channel, read as a value or a normal component."""

    file: str
    channel: str  # r, g, b or a
    kind: str  # "value" or "normal"


@dataclass(frozen=True)
class FoldedChannel:
    """A source channel that is not a decoder output (issue #18): ``constant`` (``value`` in stored
    units), ``unread`` (st not connected: the texture is read at one point, whose ``value`` replaces
    it), ``no-alpha`` (the ``a`` of a file without alpha: 1, as Hydra reads it) or ``duplicate``
    (its texels are ``same_as``'s, which the decoder outputs instead)."""

    file: str
    channel: str
    reason: str  # constant | unread | duplicate
    value: float | None = None
    same_as: ModelChannel | None = None

    def to_dict(self) -> dict:
        d = {"file": self.file, "channel": self.channel, "reason": self.reason}
        if self.reason != "duplicate":
            d["value"] = self.value
        else:
            d["same_as"] = {"file": self.same_as.file, "channel": self.same_as.channel}
        return d


@dataclass(frozen=True)
class ConstantTarget:
    """A UsdPreviewSurface target whose texture channel is constant: the value the UsdUVTexture
    gives there (colour space decoded as Hydra does, then scale and bias)."""

    target: str
    input: str
    value: float
    file: str
    file_channel: str


@dataclass(frozen=True)
class ChannelTarget:
    """A UsdPreviewSurface target that a model channel feeds: target = scale * decoded + bias (the
    UsdUVTexture's scale and bias, a normal map's 2 v - 1 folded in), read in ``color_space``."""

    target: str  # e.g. diffuseColor.g, roughness
    input: str
    channel: ModelChannel
    scale: float
    bias: float
    color_space: str  # formats.vocabulary.ColorSpace, resolved: raw or sRGB


@dataclass
class MaterialModel:
    """A scanned material's channels, specs and targets (before grouping into jobs)."""

    channels: list[ModelChannel]
    specs: list[tuple[str, str, str]]
    targets: list[ChannelTarget]
    sources: dict[str, SourceFile]
    wrap: tuple[str, str]  # (S, T): repeat, clamp or mirror (`material_wrap`)
    st: tuple[str, tuple[float, float], float, tuple[float, float]]
    warnings: list[str]
    constants: list[ConstantTarget] = field(default_factory=list)
    folded: list[FoldedChannel] = field(default_factory=list)
    density: object = None  # bcfpipe.scan.density.MaterialDensity, with the set's common source size

    @property
    def source_size(self) -> tuple[int, int]:
        """The texture set's common (width, height), as the loader will resample it."""
        sizes = [(s.width, s.height) for s in self.sources.values() if s.width and s.height]
        return common_resolution(sizes) if sizes else (0, 0)


class Canonical:
    """The first modelled channel (or normal x, y pair) seen with each texel content, across every
    material of one grouping: later channels with the same content become duplicates of it."""

    def __init__(self) -> None:
        self.keys: dict[tuple, tuple[ModelChannel, ...]] = {}
        self.sources: dict[str, SourceFile] = {}

    def of(self, content_key: tuple, keys: tuple[ModelChannel, ...], sources: Mapping[str, SourceFile]):
        first = self.keys.setdefault(content_key, keys)
        for k in first:
            if k.file not in self.sources:
                self.sources[k.file] = sources[k.file]
        return first


#: the content digest of an ``a`` read from a file without alpha, which Hydra reads as 1
NO_ALPHA = "no-alpha"


def _content(path: str, letter: str, cache: dict, warnings: list[str], file_hash: str = "", facts=None):
    """The channel's content; alpha = 1 for the ``a`` of a file without alpha (as Hydra reads it);
    for a file whose texels cannot be read, a content that is neither constant nor a duplicate of
    anything (training will report the file)."""
    try:
        return content_of(path, letter, cache, file_hash, facts)
    except MissingChannel:
        if letter != "a":
            raise
        return ChannelContent(1.0, 1.0, 1.0, NO_ALPHA, True)
    except ImageReadError:
        raise  # a damaged file is the user's to fix: the material cannot be modelled from it
    except (OSError, ValueError) as exc:
        warnings.append(f"{Path(path).name}: texels not checked for constants or duplicates ({one_line(exc)})")
        return ChannelContent(0.0, 0.0, 0.0, f"unread:{path}:{letter}", False)


def _at(path: str, letter: str, st, wraps, cache: dict, warnings: list[str], content):
    """A constant content holding the texture's value at ``st`` (the ``unread`` fold), or
    ``content`` unchanged when the texels cannot be read."""
    try:
        v = sample_at(path, letter, tuple(st), modelled_wrap(wraps), cache)
    except ImageReadError:
        raise
    except (OSError, ValueError) as exc:
        warnings.append(f"{Path(path).name}: texels not read ({one_line(exc)})")
        return content
    return ChannelContent(v, v, v, content.digest, True)


def modelled_wrap(wraps: Sequence[str]) -> tuple[Wrap, Wrap]:
    """A UsdUVTexture's effective (wrapS, wrapT) as a neural material samples it: repeat, clamp
    and mirror as they are; black as clamp (the texels inside agree; the border is not black); a
    mode USD does not know (the scan notes it) as repeat, USD's default."""
    def one(w: str) -> Wrap:
        return Wrap.CLAMP if w == "black" else Wrap(w) if w in {m.value for m in Wrap} else Wrap.REPEAT

    return one(wraps[0]), one(wraps[1])


def material_wrap(wraps: Sequence[tuple[str, tuple[Wrap, Wrap]]]) -> tuple[tuple[Wrap, Wrap], str | None]:
    """The (S, T) addressing of a material whose texture inputs are addressed ``wraps`` ((input,
    (S, T)) in input order), and a warning when they disagree: per axis the mode most inputs use
    (the first input's on a tie), the warning naming each input's modes and what was chosen."""
    if not wraps:
        return (Wrap.REPEAT, Wrap.REPEAT), None
    chosen = []
    for axis in (0, 1):
        modes = [w[axis] for _, w in wraps]
        chosen.append(max(dict.fromkeys(modes), key=modes.count))
    pair = (chosen[0], chosen[1])
    if len({w for _, w in wraps}) == 1:
        return pair, None
    said = ", ".join(f"{name} {wrap_name(w)}" for name, w in dict(wraps).items())
    return pair, (f"inputs disagree on wrap ({said}); the neural features sample {wrap_name(pair)}, "
                  f"the mode most inputs use per axis")


def _decode(value: float, color_space: str) -> float:
    return srgb_to_linear(value) if color_space == ColorSpace.SRGB else value


@dataclass
class _Model:
    """What `material_model` gathers over a material's texture inputs."""

    channels: list[ModelChannel] = field(default_factory=list)
    specs: list[tuple[str, str, str]] = field(default_factory=list)
    targets: list[ChannelTarget] = field(default_factory=list)
    constants: list[ConstantTarget] = field(default_factory=list)
    folded: list[FoldedChannel] = field(default_factory=list)
    sources: dict[str, SourceFile] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _fold(inp, tex, src: SourceFile, raw: list[ModelChannel], m: _Model, file_cache: dict, canonical: Canonical,
          facts) -> tuple[list[ModelChannel | None], list]:
    """Per raw channel the key the decoder outputs (itself or its canonical twin), or None for a
    constant one; and the channels' contents. Records what was folded, and why, in ``m``."""
    is_normal = inp.name == "normal" and tex.channel == "rgb"
    kind = "normal" if is_normal else "value"
    contents = [_content(k.file, k.channel, file_cache, m.warnings, src.xxh3_128, facts) for k in raw]
    unread = tex.st.kind == "constant" and tex.st.value is not None
    if unread:  # st not connected: the texture is read at one point; that value replaces it
        contents = [c if c.digest == NO_ALPHA else
                    _at(k.file, k.channel, tex.st.value, tex.effective_wrap, file_cache, m.warnings, c)
                    for k, c in zip(raw, contents)]
    if is_normal:
        z = (_content(src.path, "b", file_cache, m.warnings, src.xxh3_128, facts)
             if len(raw) == 2 and src.channels >= 3 else None)
        if unread and z is not None:
            z = _at(src.path, "b", tex.st.value, tex.effective_wrap, file_cache, m.warnings, z)
        if z is not None and all(c.constant for c in contents) and z.constant:
            keys: list[ModelChannel | None] = [None, None]
            m.constants.append(ConstantTarget("normal.z", inp.name, float(tex.scale[2]) * z.mean + float(tex.bias[2]),
                                              src.path, "b"))
        else:
            keys = list(canonical.of(("normal",) + tuple(c.digest for c in contents), tuple(raw), m.sources))
    else:
        keys = [None if c.constant else canonical.of((c.digest, kind), (k,), m.sources)[0]
                for k, c in zip(raw, contents)]
    for k, key, c in zip(raw, keys, contents):
        if key is None:
            reason = "no-alpha" if c.digest == NO_ALPHA else "unread" if unread else "constant"
            m.folded.append(FoldedChannel(k.file, k.channel, reason, value=c.mean))
        elif key != k:
            m.folded.append(FoldedChannel(k.file, k.channel, "duplicate", same_as=key))
            m.sources.setdefault(key.file, canonical.sources[key.file])
    return keys, contents


def _add_specs(inp, tex, raw: list[ModelChannel], keys: list[ModelChannel | None], m: _Model) -> None:
    """The texset specs of the channels this input adds: a semantic when the file's channels map
    onto one (normal xy, a colour's rgb, a scalar), else generic channels."""
    is_normal = inp.name == "normal" and tex.channel == "rgb"
    new = [k for k in dict.fromkeys(k for k in keys if k is not None) if k not in m.channels]
    if not new:
        return
    letters = "".join(k.channel for k in new)
    files = {k.file for k in new}
    if is_normal and len(new) == 2 and len(files) == 1:
        m.specs.append(("normal", new[0].file, "xy"))
    elif inp.name in _COLOR_SEMANTIC and tex.channel == "rgb" and len(new) == 3 and len(files) == 1:
        m.specs.append((_COLOR_SEMANTIC[inp.name], new[0].file, letters))
    elif inp.name in _SCALAR_SEMANTICS and len(new) == 1 and len(raw) == 1:
        m.specs.append((inp.name, new[0].file, letters))
    else:
        m.specs.extend(("generic", k.file, k.channel) for k in new)
    m.channels.extend(new)


def _add_targets(inp, tex, src: SourceFile, uses, keys: list[ModelChannel | None], contents, m: _Model) -> None:
    """Each use of the input's channels: a target of its model channel, or, folded, a constant."""
    is_normal = inp.name == "normal" and tex.channel == "rgb"
    if tex.source_color_space not in (ColorSpace.AUTO, ColorSpace.RAW, ColorSpace.SRGB):
        m.warnings.append(f"{inp.name}: unknown sourceColorSpace {tex.source_color_space!r}, read as raw")
    if is_normal and src.channels < 3:  # Hydra reads r, g and b of a grey file as the one channel
        m.warnings.append(f"{inp.name}: {Path(src.path).name} is a single-channel (greyscale) image: the normal's "
                          "x, y and z all read its one channel; is it the right file?")
    for i, (u, key) in enumerate(zip(uses, keys)):
        comp = "rgba".index(u.channel)
        s, b = float(tex.scale[comp]), float(tex.bias[comp])
        cs = src.resolved_color_space if u.channel != "a" else ColorSpace.RAW
        if is_normal:
            if cs == ColorSpace.SRGB:
                m.warnings.append(f"{inp.name}: normal map colour space resolves to sRGB; modelled as raw")
            cs = ColorSpace.RAW
        elif cs == ColorSpace.SRGB and inp.name not in ("diffuseColor", "emissiveColor", "specularColor") \
                and tex.source_color_space == ColorSpace.AUTO:
            m.warnings.append(f"{inp.name}: sourceColorSpace auto resolves to sRGB for this 8-bit file "
                              "(as in Hydra); the renderer decodes it as sRGB")
        if key is None:
            m.constants.append(ConstantTarget(u.target, inp.name, s * _decode(contents[i].mean, cs) + b,
                                              u.file, u.channel))
            continue
        if is_normal:
            s, b = s / 2.0, s / 2.0 + b  # the model stores 2 v - 1
        m.targets.append(ChannelTarget(u.target, inp.name, key, s, b, cs))


def _add_fallback(inp, tex, m: _Model) -> None:
    """The constants of an input whose UsdUVTexture gives its fallback (no file, or one that does
    not resolve): the fallback's components, unscaled, as Hydra outputs them."""
    from bcfpipe.scan.network import texture_targets  # network loads pxr: `import bcfpipe` stays cheap - lazy: start-up

    for channel, target in texture_targets(inp.name, tex.channel):
        m.constants.append(ConstantTarget(target, inp.name, tex.fallback_value(channel), "", channel))
    if inp.name == "normal" and tex.channel == "rgb":
        m.constants.append(ConstantTarget("normal.z", inp.name, tex.fallback_value("b"), "", "b"))


def material_model(ms: MaterialScan, file_cache: dict, digest: bool = True, canonical: Canonical | None = None,
                   fold: bool = True, facts=None) -> MaterialModel:
    """Map a scanned material's texture inputs to model channels, texset specs and targets.
    With ``fold``, constant channels become ``constants`` and channels whose texels repeat a channel
    already modelled (in ``canonical``, shared across the materials of a scan) map onto it."""
    canonical = canonical if canonical is not None else Canonical()
    m = _Model(warnings=list(ms.warnings))
    wraps: list[tuple[str, tuple[Wrap, Wrap]]] = []
    sts: list[tuple[str, tuple[float, float], float, tuple[float, float]]] = []
    for inp in ms.texture_inputs:
        tex = inp.texture
        assert tex is not None
        if tex.uses_fallback:
            _add_fallback(inp, tex, m)
            continue
        src = source_file(tex.resolved_path, tex.asset_path, tex.source_color_space, file_cache, digest)
        m.sources[src.path] = src
        uses = [u for u in ms.channel_uses if u.input == inp.name]
        if not uses:
            continue
        kind = "normal" if inp.name == "normal" and tex.channel == "rgb" else "value"
        raw = [ModelChannel(u.file, u.channel, kind) for u in uses]
        keys, contents = _fold(inp, tex, src, raw, m, file_cache, canonical, facts) if fold else (list(raw), [])
        _add_specs(inp, tex, raw, keys, m)
        _add_targets(inp, tex, src, uses, keys, contents, m)
        if "black" in tex.effective_wrap:
            m.warnings.append(f"{inp.name}: wrap mode 'black' modelled as clamp (the border is not black)")
        wraps.append((inp.name, modelled_wrap(tex.effective_wrap)))
        st = tex.st
        xf = st.transform
        sts.append((st.varname or "st", xf.scale if xf else (1.0, 1.0), xf.rotation if xf else 0.0,
                    xf.translation if xf else (0.0, 0.0)))
    wrap, disagree = material_wrap(wraps)
    if disagree:
        m.warnings.append(disagree)
    if len(set(sts)) > 1:
        m.warnings.append("textures use different st primvars or transforms; the model uses the first texture's")
    st = sts[0] if sts else ("st", (1.0, 1.0), 0.0, (0.0, 0.0))
    mm = MaterialModel(m.channels, m.specs, m.targets, m.sources, (str(wrap[0]), str(wrap[1])), st, list(dict.fromkeys(m.warnings)),
                       m.constants, m.folded)
    if ms.density is not None:
        mm.density = replace(ms.density, source_size=mm.source_size)
    return mm


def decoder_index(channels: Sequence[ModelChannel]) -> tuple[dict[ModelChannel, int], int | None]:
    """Decoder output index of every model channel (normal z inserted after normal y), and z's."""
    normal = [i for i, c in enumerate(channels) if c.kind == "normal"]
    ny = normal[1] if len(normal) == 2 else None
    index = {c: i + (1 if ny is not None and i > ny else 0) for i, c in enumerate(channels)}
    return index, (ny + 1 if ny is not None else None)
