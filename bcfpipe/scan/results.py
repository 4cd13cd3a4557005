"""What a stage scan reports: per-material decisions with reason codes, the inputs and
textures each material reads, and the stage facts (bcfpipe.scan.stage fills them in)."""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any


from bcfpipe.formats.vocabulary import Decision, Wrap
from bcfpipe.errors import InputError


#: UsdPreviewSurface inputs and their spec defaults (UsdPreviewSurface spec 2.5).
PREVIEW_SURFACE_INPUTS: dict[str, Any] = {
    "diffuseColor": (0.18, 0.18, 0.18),
    "emissiveColor": (0.0, 0.0, 0.0),
    "useSpecularWorkflow": 0,
    "specularColor": (0.0, 0.0, 0.0),
    "metallic": 0.0,
    "roughness": 0.5,
    "clearcoat": 0.0,
    "clearcoatRoughness": 0.01,
    "opacity": 1.0,
    "opacityThreshold": 0.0,
    "ior": 1.5,
    "normal": (0.0, 0.0, 1.0),
    "displacement": 0.0,
    "occlusion": 1.0,
}



#: TextureRef problem codes for which the UsdUVTexture gives its ``fallback`` value.
FALLBACK_PROBLEMS = frozenset({"no-file", "missing"})


class ScanError(InputError):
    """The stage cannot be scanned at all (missing, unreadable, bad variant request)."""


@dataclass(frozen=True)
class Transform2d:
    """A UsdTransform2d on the st path: ``st * scale * rotate(rotation°) + translation``."""

    scale: tuple[float, float] = (1.0, 1.0)
    rotation: float = 0.0
    translation: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class StSource:
    """Where a texture's st comes from.

    kind: ``primvar`` (a UsdPrimvarReader_float2, ``varname``), ``transform2d``
    (a UsdTransform2d fed by a primvar reader: ``varname`` and ``transform``),
    ``constant`` (st not connected: the texture is sampled at ``value``) or
    ``other`` (anything else; ``detail`` says what).
    """

    kind: str
    varname: str | None = None
    transform: Transform2d | None = None
    value: tuple[float, float] | None = None
    detail: str = ""


@dataclass(frozen=True)
class TextureRef:
    """One UsdUVTexture output feeding a UsdPreviewSurface input.

    ``asset_path`` is the file as authored; ``resolved_path`` is what Ar resolved
    (``pkg.usdz[inner/path.png]`` inside packages; empty when unresolved).
    ``problem`` is None when the file is usable, else a short message, with
    ``problem_code`` one of ``no-file``, ``missing``, ``udim``, ``time-sampled``,
    ``bad-channel``. Without a file, or with one that does not resolve, the node gives its
    ``fallback`` (as Hydra does): see :attr:`uses_fallback`.
    """

    shader: str
    channel: str
    asset_path: str
    resolved_path: str
    scale: tuple[float, float, float, float]
    bias: tuple[float, float, float, float]
    fallback: tuple[float, float, float, float]
    source_color_space: str
    wrap_s: str
    wrap_t: str
    st: StSource
    problem: str | None = None
    problem_code: str | None = None
    animated_file: bool = False

    @property
    def ok(self) -> bool:
        """True when the file resolved and can be read by the trainer."""
        return self.problem is None

    @property
    def uses_fallback(self) -> bool:
        """True when the node outputs its ``fallback`` instead of texels: no file authored, or a
        file that does not resolve (Hydra draws the fallback there; a UDIM pattern or a
        time-sampled path is a different problem, which skips the material)."""
        return self.problem_code in FALLBACK_PROBLEMS

    def fallback_value(self, channel: str) -> float:
        """The fallback's component for an output channel letter (r, g, b, a)."""
        return float(self.fallback["rgba".index(channel)])

    @property
    def effective_wrap(self) -> tuple[str, str]:
        """(wrapS, wrapT) with ``useMetadata`` read as ``repeat``."""
        def effective(wrap: str) -> str:
            return Wrap.REPEAT if wrap == "useMetadata" else wrap

        return effective(self.wrap_s), effective(self.wrap_t)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (adds ``ok`` and ``effective_wrap``)."""
        d = asdict(self)
        d["ok"] = self.ok
        d["uses_fallback"] = self.uses_fallback
        d["effective_wrap"] = list(self.effective_wrap)
        return d


@dataclass(frozen=True)
class InputScan:
    """One UsdPreviewSurface input.

    kind: ``constant`` (``value`` authored or the spec default; ``authored`` says
    which), ``texture`` (``texture``), ``primvar`` (read per vertex through a
    UsdPrimvarReader; ``detail`` names it) or ``unsupported`` (connected to a
    node this scanner does not understand; ``detail``).
    """

    name: str
    kind: str
    value: Any = None
    authored: bool = False
    texture: TextureRef | None = None
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict."""
        d = {k: v for k, v in asdict(self).items() if k != "texture"}
        d["texture"] = self.texture.to_dict() if self.texture else None
        return d


@dataclass(frozen=True)
class ChannelUse:
    """One texture channel the model must reproduce and what it means.

    ``target`` is the UsdPreviewSurface semantic: ``diffuseColor.r``,
    ``roughness``, ``normal.x`` (normal maps keep x, y; z is reconstructed),
    or the bare input name when one channel drives a whole colour.
    """

    file: str
    channel: str
    target: str
    input: str
    color_space: str

    @property
    def key(self) -> tuple[str, str, str, str]:
        """(file, channel, target, color_space): what identifies the training data."""
        return (self.file, self.channel, self.target, self.color_space)


@dataclass(frozen=True)
class MaterialScan:
    """What the scanner found for one UsdShade.Material and what to do with it."""

    path: str
    decision: str
    reason: str | None
    message: str
    bound: bool
    bound_purposes: tuple[str, ...] = ()
    aliases: tuple[str, ...] = ()
    surface_shader: str | None = None
    shader_id: str | None = None
    inputs: tuple[InputScan, ...] = ()
    channel_uses: tuple[ChannelUse, ...] = ()
    warnings: tuple[str, ...] = ()
    density: Any = None  # bcfpipe.scan.density.MaterialDensity of a modelled material (source size unset)

    @property
    def texture_inputs(self) -> tuple[InputScan, ...]:
        """The inputs driven by a UsdUVTexture."""
        return tuple(i for i in self.inputs if i.kind == "texture")

    @property
    def channels(self) -> tuple[tuple[str, str], ...]:
        """Distinct (resolved file, channel) pairs the model needs, sorted."""
        return tuple(sorted({(u.file, u.channel) for u in self.channel_uses}))

    @property
    def texture_set_key(self) -> tuple[tuple[str, str, str, str], ...]:
        """Sorted (file, channel, target, color_space) tuples: equal keys train once."""
        return tuple(sorted({u.key for u in self.channel_uses}))

    def input(self, name: str) -> InputScan:
        """The scan of UsdPreviewSurface input `name`."""
        for i in self.inputs:
            if i.name == name:
                return i
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (adds ``channels`` and ``texture_set_key``)."""
        return {
            "path": self.path,
            "decision": self.decision,
            "reason": self.reason,
            "message": self.message,
            "bound": self.bound,
            "bound_purposes": list(self.bound_purposes),
            "aliases": list(self.aliases),
            "surface_shader": self.surface_shader,
            "shader_id": self.shader_id,
            "inputs": [i.to_dict() for i in self.inputs],
            "channel_uses": [asdict(u) for u in self.channel_uses],
            "channels": [list(c) for c in self.channels],
            "texture_set_key": [list(k) for k in self.texture_set_key],
            "warnings": list(self.warnings),
        }


@dataclass(frozen=True)
class StageScan:
    """The scan of one stage: stage metrics and one MaterialScan per material."""

    path: str
    root_layer: str
    up_axis: str
    meters_per_unit: float
    default_prim: str | None
    variant_selections: tuple[tuple[str, str, str], ...]
    all_materials: bool
    rendered_gprims: int
    materials: tuple[MaterialScan, ...]
    dangling_bindings: tuple[str, ...] = ()
    composition_errors: tuple[str, ...] = ()
    diagnostics: tuple[str, ...] = ()
    layers: tuple[str, ...] = ()  # files of every composed layer (a packaged layer: its .usdz)
    #: (set, value, materials): variant selections that bind materials these selections leave unbound
    binding_variants: tuple[tuple[str, str, tuple[str, ...]], ...] = ()
    variants_untried: int = 0  # variant choices past the trial limit, not checked

    @property
    def to_model(self) -> tuple[MaterialScan, ...]:
        """Materials decided ``model``."""
        return tuple(m for m in self.materials if m.decision == Decision.MODEL)

    @property
    def skipped(self) -> tuple[MaterialScan, ...]:
        """Materials decided ``skip``."""
        return tuple(m for m in self.materials if m.decision == Decision.SKIP)

    def material(self, path: str) -> MaterialScan:
        """The scan of the material at `path` (or one of its aliases)."""
        for m in self.materials:
            if m.path == path or path in m.aliases:
                return m
        raise KeyError(path)

    def to_dict(self) -> dict[str, Any]:
        """JSON-serialisable dict of the whole scan."""
        return {
            "path": self.path,
            "root_layer": self.root_layer,
            "up_axis": self.up_axis,
            "meters_per_unit": self.meters_per_unit,
            "default_prim": self.default_prim,
            "variant_selections": [
                {"prim": p, "set": s, "value": v} for p, s, v in self.variant_selections
            ],
            "all_materials": self.all_materials,
            "rendered_gprims": self.rendered_gprims,
            "materials": [m.to_dict() for m in self.materials],
            "dangling_bindings": list(self.dangling_bindings),
            "composition_errors": list(self.composition_errors),
            "diagnostics": list(self.diagnostics),
            "layers": list(self.layers),
            "binding_variants": [{"set": s, "value": v, "materials": list(m)} for s, v, m in self.binding_variants],
            "variants_untried": self.variants_untried,
            "summary": {
                "materials": len(self.materials),
                "model": len(self.to_model),
                "skip": len(self.skipped),
            },
        }
