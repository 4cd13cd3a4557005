"""Scan a USD stage for the UsdPreviewSurface materials a neural model must replace.

`bcfpipe build` models only what the scene needs: the textured UsdPreviewSurface
materials that are bound to geometry that is actually rendered.  This module
composes the stage (with optional variant selections), reads every material's
shading network and decides, per material, ``model`` or ``skip`` with a reason
code.  It never modifies the input: variant selections go to the session layer.

Decisions (the first that applies wins):

=====================  ====================================================
reason                 when
=====================  ====================================================
``materialx-only``     no universal ``outputs:surface`` but ``outputs:mtlx:surface``,
                       or the universal surface is a MaterialX ``ND_*`` node
``not-preview-surface`` the universal surface is not a UsdPreviewSurface (or none)
``unbound``            no rendered geometry binds it (ignored with ``all_materials``)
``no-textures``        every UsdPreviewSurface input is a constant (or a primvar)
``unresolvable-file``  some texture's file is missing, unauthored, a ``<UDIM>``
                       pattern or time-sampled without a default (or the texture
                       output used is not r/g/b/a/rgb).  One bad texture
                       skips the whole material: a neural material replaces all of
                       its textures at once, so a partial set cannot be trained.
``scan-error``         anything unexpected while reading that one material
=====================  ====================================================

Choices worth knowing:

* Variants: ``SET=VALUE`` is applied on every prim that has a variant set ``SET``
  offering ``VALUE`` (prims whose set of that name lacks the value are left
  alone, so a name reused at several levels — the Vehicles kit's ``wheels`` —
  does what one means).  Selecting a variant can reveal nested variant sets, so
  selections are re-applied until nothing changes.  Variant sets inside
  instance prototypes cannot be edited and are not searched.
* Binding: a material is bound if a rendered Gprim (or one of its
  ``materialBind`` GeomSubsets) resolves to it under the ``preview`` purpose
  (what a real-time renderer uses; falls back to all-purpose bindings) or the
  ``full`` purpose.  Rendered = reachable through active, loaded, defined prims
  (instance proxies included), not under ``visibility = invisible`` nor under
  ``purpose`` ``proxy``/``guide`` (default-time values; animated visibility
  counts as visible), nor under a model drawn as cards/bounds/origin
  (``model:drawMode``, as UsdImaging applies it).
* Instancing: a material inside an instance is reported once per prototype
  material, at the first instance-proxy path; the other paths are ``aliases``.
* ``wrapS``/``wrapT`` default to ``useMetadata`` (UsdPreviewSurface spec), which
  renderers treat as ``repeat`` when the file carries no wrap metadata; the
  ``effective_wrap`` property applies that.
"""
from __future__ import annotations


import math
import os
import struct
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

from pxr import Sdf, Tf, Usd, UsdGeom, UsdShade, UsdUtils

from bcfpipe.errors import InputError

__all__ = [
    "ScanError",
    "StSource",
    "Transform2d",
    "TextureRef",
    "InputScan",
    "ChannelUse",
    "MaterialScan",
    "StageScan",
    "PREVIEW_SURFACE_INPUTS",
    "scan_stage",
    "parse_variant",
]

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
_COLOR_INPUTS = frozenset({"diffuseColor", "emissiveColor", "specularColor"})

#: UsdUVTexture defaults.
_TEXTURE_DEFAULTS = {
    "scale": (1.0, 1.0, 1.0, 1.0),
    "bias": (0.0, 0.0, 0.0, 0.0),
    "fallback": (0.0, 0.0, 0.0, 1.0),
    "sourceColorSpace": "auto",
    "wrapS": "useMetadata",
    "wrapT": "useMetadata",
    "st": (0.0, 0.0),
}
_TEXTURE_CHANNELS = ("r", "g", "b", "a", "rgb")
_WRAP_MODES = frozenset({"black", "clamp", "repeat", "mirror", "useMetadata"})

DECISION_MODEL, DECISION_SKIP = "model", "skip"
REASONS = (
    "materialx-only",
    "not-preview-surface",
    "unbound",
    "no-textures",
    "unresolvable-file",
    "scan-error",
)
_MAX_VARIANT_PASSES = 16


class ScanError(InputError):
    """The stage cannot be scanned at all (missing, unreadable, bad variant request)."""


# ---------------------------------------------------------------------------
# Result types
# ---------------------------------------------------------------------------


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
    ``bad-channel``.
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
    def effective_wrap(self) -> tuple[str, str]:
        """(wrapS, wrapT) with ``useMetadata`` read as ``repeat``."""
        def effective(wrap: str) -> str:
            return "repeat" if wrap == "useMetadata" else wrap

        return effective(self.wrap_s), effective(self.wrap_t)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (adds ``ok`` and ``effective_wrap``)."""
        d = asdict(self)
        d["ok"] = self.ok
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

    @property
    def to_model(self) -> tuple[MaterialScan, ...]:
        """Materials decided ``model``."""
        return tuple(m for m in self.materials if m.decision == DECISION_MODEL)

    @property
    def skipped(self) -> tuple[MaterialScan, ...]:
        """Materials decided ``skip``."""
        return tuple(m for m in self.materials if m.decision == DECISION_SKIP)

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
            "summary": {
                "materials": len(self.materials),
                "model": len(self.to_model),
                "skip": len(self.skipped),
            },
        }


# ---------------------------------------------------------------------------
# Opening and variants
# ---------------------------------------------------------------------------


def parse_variant(text: str) -> tuple[str, str]:
    """Split ``SET=VALUE`` (both non-empty) into (set, value)."""
    name, sep, value = text.partition("=")
    name, value = name.strip(), value.strip()
    if not sep or not name or not value:
        raise ScanError(f"bad variant {text!r}: expected SET=VALUE, e.g. modelVariant=Fancy")
    return name, value


def _first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception message (pxr errors are verbose)."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    text = lines[0] if lines else type(exc).__name__
    # Tf errors read "Error in '...' at line N in file F : 'the message'"
    if " : " in text and text.startswith("Error in"):
        text = text.split(" : ", 1)[1].strip("'")
    return text


def open_stage(path: str | os.PathLike[str]) -> Usd.Stage:
    """Open a stage with all payloads loaded; ScanError if missing or unparsable."""
    p = Path(path)
    if not p.exists():
        raise ScanError(f"no such file: {p}")
    if p.is_dir():
        raise ScanError(f"not a USD file (a directory): {p}")
    try:
        stage = Usd.Stage.Open(str(p), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise ScanError(f"cannot read stage {p}: {_first_line(exc)}") from None
    if stage is None:
        raise ScanError(f"cannot read stage {p}")
    return stage


def _variant_requests(
    stage: Usd.Stage, variants: Mapping[str, str]
) -> tuple[list[tuple[Usd.Prim, str, str]], dict[str, set[str]]]:
    """Selections still to author, and for each requested set the values seen on the stage."""
    todo: list[tuple[Usd.Prim, str, str]] = []
    offered: dict[str, set[str]] = {}
    for prim in stage.Traverse():
        vsets = prim.GetVariantSets()
        for name, value in variants.items():
            if not vsets.HasVariantSet(name):
                continue
            vset = vsets.GetVariantSet(name)
            names = set(vset.GetVariantNames())
            offered.setdefault(name, set()).update(names)
            if value in names and vset.GetVariantSelection() != value:
                todo.append((prim, name, value))
    return todo, offered


def apply_variants(stage: Usd.Stage, variants: Mapping[str, str]) -> tuple[tuple[str, str, str], ...]:
    """Select ``variants`` in the session layer on every prim offering them.

    Returns the (prim path, set, value) selections authored (a selection already
    in effect is not repeated).  Raises ScanError when
    a requested set/value exists nowhere on the composed stage.
    """
    applied: dict[tuple[str, str], str] = {}
    offered_all: dict[str, set[str]] = {}
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for _ in range(_MAX_VARIANT_PASSES):
            todo, offered = _variant_requests(stage, variants)
            for name, values in offered.items():
                offered_all.setdefault(name, set()).update(values)
            if not todo:
                break
            for prim, name, value in todo:
                prim.GetVariantSets().GetVariantSet(name).SetVariantSelection(value)
                applied[(str(prim.GetPath()), name)] = value
    for name, value in variants.items():
        values = offered_all.get(name)
        if not values:
            raise ScanError(f"variant set {name!r} not found on any prim")
        if value not in values:
            raise ScanError(
                f"variant {name}={value} not found: {name!r} offers {', '.join(sorted(values))}"
            )
    return tuple(sorted((p, s, v) for (p, s), v in applied.items()))


# ---------------------------------------------------------------------------
# Rendered geometry and bindings
# ---------------------------------------------------------------------------

_HIDDEN_PURPOSES = frozenset({UsdGeom.Tokens.proxy, UsdGeom.Tokens.guide})


def _draws_stand_in(prim: Usd.Prim) -> bool:
    """True when a model is drawn as cards/bounds/origin instead of its geometry.

    Mirrors UsdImaging: a non-default (inherited) ``model:drawMode`` applies on
    component models and on models with ``model:applyDrawMode = true``.
    """
    if not prim.IsModel():
        return False
    api = UsdGeom.ModelAPI(prim)
    if api.ComputeModelDrawMode() == UsdGeom.Tokens.default_:
        return False
    return bool(api.GetModelApplyDrawModeAttr().Get()) or Usd.ModelAPI(prim).IsKind("component")


def _hides_subtree(prim: Usd.Prim) -> bool:
    """True when `prim` hides itself and its descendants (invisible, proxy/guide purpose, draw mode)."""
    if not prim.IsA(UsdGeom.Imageable):
        return False
    img = UsdGeom.Imageable(prim)
    if img.GetVisibilityAttr().Get() == UsdGeom.Tokens.invisible:
        return True
    if img.GetPurposeAttr().Get() in _HIDDEN_PURPOSES:
        return True
    return _draws_stand_in(prim)


def rendered_gprims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Gprims a renderer draws (default/render purpose, visible), instance proxies included."""
    found: list[Usd.Prim] = []
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        if _hides_subtree(prim):
            it.PruneChildren()
            continue
        if prim.IsA(UsdGeom.Gprim):
            found.append(prim)
    return found


def _definition_path(prim: Usd.Prim) -> str:
    """The path identifying a prim's definition: its prototype prim for instance proxies."""
    if prim.IsInstanceProxy():
        return str(prim.GetPrimInPrototype().GetPath())
    return str(prim.GetPath())


def _binding_prims(gprims: Iterable[Usd.Prim]) -> list[Usd.Prim]:
    """The gprims plus their ``materialBind`` GeomSubsets."""
    prims: list[Usd.Prim] = []
    for g in gprims:
        prims.append(g)
        prims.extend(s.GetPrim() for s in UsdShade.MaterialBindingAPI(g).GetMaterialBindSubsets())
    return prims


def _binding_target(rel: Usd.Relationship) -> str | None:
    """The material path a binding relationship names (last target; collections list two)."""
    targets = rel.GetTargets() if rel else []
    return str(targets[-1]) if targets else None


def bound_materials(stage: Usd.Stage, gprims: list[Usd.Prim]) -> tuple[dict[str, set[str]], set[str]]:
    """Map definition path of each bound material to the purposes binding it; and dangling targets."""
    prims = _binding_prims(gprims)
    bound: dict[str, set[str]] = {}
    dangling: set[str] = set()
    if not prims:
        return bound, dangling
    for purpose in (UsdShade.Tokens.preview, UsdShade.Tokens.full):
        materials, rels = UsdShade.MaterialBindingAPI.ComputeBoundMaterials(prims, purpose)
        for mat, rel in zip(materials, rels):
            if mat:
                bound.setdefault(_definition_path(mat.GetPrim()), set()).add(str(purpose))
            elif rel:
                target = _binding_target(rel)
                if target and not stage.GetPrimAtPath(target):
                    dangling.add(target)
    return bound, dangling


# ---------------------------------------------------------------------------
# Shading network reading
# ---------------------------------------------------------------------------


def _as_f32(x: float) -> float:
    """`x` as float32, written with the fewest digits that round-trip (0.3, not 0.30000001192)."""
    bits = struct.pack("<f", x)
    for digits in range(6, 10):
        short = float(f"{x:.{digits}g}")
        if struct.pack("<f", short) == bits:
            return short
    return struct.unpack("<f", bits)[0]


def _plain(value: Any, f32: bool = False) -> Any:
    """A JSON-friendly copy of a USD value (vectors → tuples of float, tokens → str).

    With `f32` (the attribute is float-typed), floats are shown as float32 values.
    """
    if value is None or isinstance(value, (bool, int, str)):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            return str(value)
        return _as_f32(value) if f32 else value
    if isinstance(value, Sdf.AssetPath):
        return value.path
    if hasattr(value, "__len__") and hasattr(value, "__getitem__"):
        return tuple(_plain(v, f32) for v in value)
    return str(value)


_F32_TYPES = frozenset({"float", "GfVec2f", "GfVec3f", "GfVec4f"})


def _is_f32(attr: Usd.Attribute) -> bool:
    """True for float/float2/float3/float4/color3f/... attributes (single precision)."""
    return attr.GetTypeName().scalarType.cppTypeName in _F32_TYPES


def _source_attr(shader: UsdShade.Shader, name: str) -> Usd.Attribute | None:
    """The attribute producing input `name`'s value: an upstream output, an interface input, or itself."""
    inp = shader.GetInput(name)
    if not inp:
        return None
    attrs = inp.GetValueProducingAttributes(False)
    if attrs:
        return attrs[0]
    return None if inp.HasConnectedSource() else inp.GetAttr()


def _input_value(shader: UsdShade.Shader, name: str, default: Any) -> tuple[Any, bool]:
    """(value, authored) of a non-connected input, following interface connections."""
    attr = _source_attr(shader, name)
    if attr is None or UsdShade.Output.IsOutput(attr):
        return default, False
    value = attr.Get()
    if value is None:
        return default, False
    return _plain(value, _is_f32(attr)), True


def _floats(value: Any, pad: tuple[float, ...]) -> list[float]:
    """`value` (scalar or vector) as len(pad) floats, missing components from `pad`."""
    size = len(pad)
    values = [float(value)] * size if isinstance(value, (int, float)) else [float(v) for v in value][:size]
    return values + list(pad[len(values):])


def _vec2(value: Any, pad: tuple[float, float]) -> tuple[float, float]:
    """A float2 value."""
    x, y = _floats(value, pad)
    return x, y


def _vec4(value: Any, pad: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """A float4 value; float3 values get their 4th component from `pad` (fallback alpha 1)."""
    x, y, z, w = _floats(value, pad)
    return x, y, z, w


def _shader_id(prim: Usd.Prim) -> str | None:
    """info:id of a shader prim (None for non-shaders or sourceAsset shaders)."""
    if not prim.IsA(UsdShade.Shader):
        return None
    sid = UsdShade.Shader(prim).GetShaderId()
    return str(sid) if sid else None


def _transform2d(shader: UsdShade.Shader) -> Transform2d:
    """The parameters of a UsdTransform2d."""
    scale, _ = _input_value(shader, "scale", (1.0, 1.0))
    rotation, _ = _input_value(shader, "rotation", 0.0)
    translation, _ = _input_value(shader, "translation", (0.0, 0.0))
    return Transform2d(_vec2(scale, (1.0, 1.0)), float(rotation), _vec2(translation, (0.0, 0.0)))


def _primvar_varname(shader: UsdShade.Shader) -> str | None:
    """The varname of a UsdPrimvarReader (string or token, possibly via an interface input)."""
    value, _ = _input_value(shader, "varname", None)
    return str(value) if value else None


def _st_source(texture: UsdShade.Shader) -> StSource:
    """Describe where a UsdUVTexture's st comes from."""
    attr = _source_attr(texture, "st")
    if attr is None or not UsdShade.Output.IsOutput(attr):
        value, _ = _input_value(texture, "st", _TEXTURE_DEFAULTS["st"])
        return StSource("constant", value=_vec2(value, (0.0, 0.0)), detail="st not connected")
    node = UsdShade.Shader(attr.GetPrim())
    sid = _shader_id(node.GetPrim())
    if sid == "UsdPrimvarReader_float2":
        return StSource("primvar", varname=_primvar_varname(node))
    if sid == "UsdTransform2d":
        xform = _transform2d(node)
        upstream = _source_attr(node, "in")
        if upstream is not None and UsdShade.Output.IsOutput(upstream):
            reader = UsdShade.Shader(upstream.GetPrim())
            if _shader_id(reader.GetPrim()) == "UsdPrimvarReader_float2":
                return StSource("transform2d", varname=_primvar_varname(reader), transform=xform)
            feeder = _shader_id(reader.GetPrim()) or reader.GetPath()
            return StSource("other", transform=xform, detail=f"UsdTransform2d fed by {feeder}")
        return StSource("other", transform=xform, detail="UsdTransform2d input 'in' not connected")
    return StSource("other", detail=f"st from {sid or node.GetPath()}")


def _file_problem(
    asset_path: str, resolved: str, time_sampled: bool, has_default: bool
) -> tuple[str | None, str | None]:
    """(problem_code, message) for a texture file, or (None, None) when usable."""
    if not has_default and time_sampled:
        return "time-sampled", "file is time-sampled with no default value"
    if not asset_path:
        return "no-file", "no file authored"
    if "<UDIM>" in asset_path.upper():
        return "udim", f"UDIM file {asset_path!r} is not supported"
    if not resolved:
        return "missing", f"file {asset_path!r} not found"
    return None, None


def _texture_ref(texture: UsdShade.Shader, channel: str) -> TextureRef:
    """Read one UsdUVTexture (file, channel, scale/bias, colour space, wrap, st)."""
    file_attr = _source_attr(texture, "file")
    value = None
    time_sampled = False
    if file_attr is not None and not UsdShade.Output.IsOutput(file_attr):
        value = file_attr.Get()
        time_sampled = file_attr.GetNumTimeSamples() > 0
    asset_path = value.path if isinstance(value, Sdf.AssetPath) else ""
    resolved = value.resolvedPath if isinstance(value, Sdf.AssetPath) else ""
    code, problem = _file_problem(asset_path, resolved, time_sampled, value is not None)
    if code is None and channel not in _TEXTURE_CHANNELS:
        code, problem = "bad-channel", f"texture output {channel!r} is not one of r, g, b, a, rgb"
    d = _TEXTURE_DEFAULTS
    scale, _ = _input_value(texture, "scale", d["scale"])
    bias, _ = _input_value(texture, "bias", d["bias"])
    fallback, _ = _input_value(texture, "fallback", d["fallback"])
    color_space, _ = _input_value(texture, "sourceColorSpace", d["sourceColorSpace"])
    wrap_s, _ = _input_value(texture, "wrapS", d["wrapS"])
    wrap_t, _ = _input_value(texture, "wrapT", d["wrapT"])
    return TextureRef(
        shader=str(texture.GetPath()),
        channel=channel,
        asset_path=asset_path,
        resolved_path=resolved,
        scale=_vec4(scale, d["scale"]),
        bias=_vec4(bias, d["bias"]),
        fallback=_vec4(fallback, d["fallback"]),
        source_color_space=str(color_space),
        wrap_s=str(wrap_s),
        wrap_t=str(wrap_t),
        st=_st_source(texture),
        problem=problem,
        problem_code=code,
        animated_file=time_sampled,
    )


def scan_input(surface: UsdShade.Shader, name: str) -> InputScan:
    """Classify one UsdPreviewSurface input as constant, texture, primvar or unsupported."""
    default = PREVIEW_SURFACE_INPUTS[name]
    attr = _source_attr(surface, name)
    if attr is None or not UsdShade.Output.IsOutput(attr):
        value, authored = _input_value(surface, name, default)
        return InputScan(name, "constant", value=value, authored=authored)
    node = UsdShade.Shader(attr.GetPrim())
    sid = _shader_id(node.GetPrim())
    output = UsdShade.Output(attr).GetBaseName()
    if sid == "UsdUVTexture":
        return InputScan(name, "texture", texture=_texture_ref(node, output))
    if sid and sid.startswith("UsdPrimvarReader"):
        return InputScan(name, "primvar", detail=f"primvar {_primvar_varname(node)!r} via {sid}")
    source = f"{sid or 'shader'} {node.GetPath()}.outputs:{output}"
    return InputScan(name, "unsupported", detail=f"connected to {source}")


# ---------------------------------------------------------------------------
# Channel summary and decisions
# ---------------------------------------------------------------------------


def _targets(name: str, channel: str) -> list[tuple[str, str]]:
    """(texture channel, UsdPreviewSurface target) pairs for `name` read through `channel`."""
    if channel == "rgb":
        if name == "normal":
            return [("r", "normal.x"), ("g", "normal.y")]
        if name in _COLOR_INPUTS:
            return [(c, f"{name}.{c}") for c in "rgb"]
        return [("r", name)]  # a scalar fed from rgb reads the first component
    return [(channel, name)]


def channel_uses(inputs: Iterable[InputScan]) -> tuple[ChannelUse, ...]:
    """The texture channels a model needs, one per (input, component), for usable textures."""
    uses: list[ChannelUse] = []
    for inp in inputs:
        tex = inp.texture
        if inp.kind != "texture" or tex is None or not tex.ok:
            continue
        for channel, target in _targets(inp.name, tex.channel):
            uses.append(ChannelUse(tex.resolved_path, channel, target, inp.name, tex.source_color_space))
    return tuple(uses)


def input_warnings(inputs: Iterable[InputScan]) -> tuple[str, ...]:
    """Notes about inputs a model will not reproduce exactly."""
    notes: list[str] = []
    for inp in inputs:
        tex = inp.texture
        if inp.kind in ("primvar", "unsupported"):
            notes.append(f"{inp.name}: {inp.detail} (not modelled)")
        if tex is None:
            continue
        if tex.st.kind == "constant":
            notes.append(f"{inp.name}: st not connected, texture sampled at {tex.st.value}")
        elif tex.st.kind == "other":
            notes.append(f"{inp.name}: unusual st source ({tex.st.detail})")
        if tex.animated_file and tex.ok:
            notes.append(f"{inp.name}: file is time-sampled; using its default value")
        if inp.name not in _COLOR_INPUTS and inp.name != "normal" and tex.channel == "rgb":
            notes.append(f"{inp.name}: scalar input fed from rgb; reading .r")
        if inp.name not in _COLOR_INPUTS and tex.channel != "a" and tex.source_color_space == "sRGB":
            notes.append(f"{inp.name}: non-colour data read from a texture tagged sRGB")
        for wrap in (tex.wrap_s, tex.wrap_t):
            if wrap not in _WRAP_MODES:
                notes.append(f"{inp.name}: unknown wrap mode {wrap!r}")
    return tuple(notes)


def decide(
    surface_problem: tuple[str, str] | None,
    bound: bool,
    all_materials: bool,
    inputs: tuple[InputScan, ...],
) -> tuple[str, str | None, str]:
    """(decision, reason, message) for a material from its facts (first rule that applies)."""
    if surface_problem is not None:
        return DECISION_SKIP, surface_problem[0], surface_problem[1]
    if not bound and not all_materials:
        return DECISION_SKIP, "unbound", "not bound to any rendered geometry"
    textured = [i for i in inputs if i.kind == "texture"]
    if not textured:
        others = [i.name for i in inputs if i.kind != "constant"]
        tail = f"; {', '.join(others)} from primvars/other nodes" if others else ""
        return DECISION_SKIP, "no-textures", f"no texture inputs (constants{tail})"
    bad = [i for i in textured if i.texture is not None and not i.texture.ok]
    if bad:
        detail = "; ".join(f"{i.name}: {i.texture.problem}" for i in bad)  # type: ignore[union-attr]
        return DECISION_SKIP, "unresolvable-file", detail
    names = ", ".join(i.name for i in textured)
    return DECISION_MODEL, None, f"{len(textured)} textured input(s): {names}"


def _surface(material: UsdShade.Material) -> tuple[UsdShade.Shader | None, tuple[str, str] | None]:
    """The universal surface shader and, if it is not a usable UsdPreviewSurface, (reason, message)."""
    shader, _, _ = material.ComputeSurfaceSource("")
    if not shader:
        names = [o.GetBaseName() for o in material.GetSurfaceOutputs() if o.HasConnectedSource()]
        contexts = sorted({n.split(":")[0] for n in names if ":" in n})
        if "mtlx" in contexts:
            return None, ("materialx-only", "only a MaterialX surface (outputs:mtlx:surface)")
        if contexts:
            return None, ("not-preview-surface", f"only render-context surfaces: {', '.join(contexts)}")
        return None, ("not-preview-surface", "no surface shader")
    sid = _shader_id(shader.GetPrim())
    if sid == "UsdPreviewSurface":
        return shader, None
    if sid and sid.startswith("ND_"):
        return shader, ("materialx-only", f"surface is the MaterialX node {sid}")
    return shader, ("not-preview-surface", f"surface shader is {sid or 'not identified by info:id'}")


def scan_material(
    material: UsdShade.Material,
    bound_purposes: tuple[str, ...],
    all_materials: bool,
    aliases: tuple[str, ...] = (),
) -> MaterialScan:
    """Read one material's UsdPreviewSurface network and decide model/skip."""
    path = str(material.GetPath())
    bound = bool(bound_purposes)
    shader, problem = _surface(material)
    sid = _shader_id(shader.GetPrim()) if shader else None
    inputs: tuple[InputScan, ...] = ()
    if shader is not None and problem is None:
        inputs = tuple(scan_input(shader, name) for name in PREVIEW_SURFACE_INPUTS)
    decision, reason, message = decide(problem, bound, all_materials, inputs)
    return MaterialScan(
        path=path,
        decision=decision,
        reason=reason,
        message=message,
        bound=bound,
        bound_purposes=bound_purposes,
        aliases=aliases,
        surface_shader=str(shader.GetPath()) if shader else None,
        shader_id=sid,
        inputs=inputs,
        channel_uses=channel_uses(inputs) if decision == DECISION_MODEL else (),
        warnings=input_warnings(inputs),
    )


def _error_scan(
    path: str, exc: BaseException, bound_purposes: tuple[str, ...], aliases: tuple[str, ...]
) -> MaterialScan:
    """A skip for a material whose scan raised."""
    return MaterialScan(
        path=path,
        decision=DECISION_SKIP,
        reason="scan-error",
        message=f"scan-error: {_first_line(exc)}",
        bound=bool(bound_purposes),
        bound_purposes=bound_purposes,
        aliases=aliases,
    )


def material_prims(stage: Usd.Stage) -> dict[str, list[Usd.Prim]]:
    """Material prims by definition path (instance proxies of one prototype grouped), in traversal order."""
    groups: dict[str, list[Usd.Prim]] = {}
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdShade.Material):
            groups.setdefault(_definition_path(prim), []).append(prim)
    return groups


# ---------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------


def _stage_facts(stage: Usd.Stage) -> dict[str, Any]:
    """upAxis, metersPerUnit, defaultPrim and root layer of a stage."""
    default_prim = stage.GetDefaultPrim()
    layer = stage.GetRootLayer()
    return {
        "root_layer": layer.realPath or layer.identifier,
        "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
        "meters_per_unit": float(UsdGeom.GetStageMetersPerUnit(stage)),
        "default_prim": str(default_prim.GetPath()) if default_prim else None,
    }


def _composition_errors(stage: Usd.Stage) -> tuple[str, ...]:
    """One line per composition error (missing layers, bad references, ...)."""
    try:
        errors = stage.GetCompositionErrors()
    except Exception:  # noqa: BLE001 - older pxr without the API
        return ()
    return tuple(_first_line(Exception(str(e))) for e in errors)


@contextmanager
def _captured_diagnostics() -> Iterator[list[str]]:
    """Collect USD warnings/statuses (one line each) instead of letting them print to stderr."""
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    found: list[str] = []
    try:
        yield found
    finally:
        found.extend(_first_line(Exception(d.commentary)) for d in delegate.TakeUncoalescedDiagnostics())
        del delegate


def _new_diagnostics(found: Iterable[str], known: tuple[str, ...]) -> tuple[str, ...]:
    """Unique diagnostics that do not repeat a composition error."""
    unique = dict.fromkeys(d for d in found if not any(k in d for k in known))
    return tuple(unique)


def scan_stage(
    path: str | os.PathLike[str],
    variants: Mapping[str, str] | None = None,
    all_materials: bool = False,
) -> StageScan:
    """Compose the stage at `path`, apply `variants`, and decide model/skip for every material.

    Raises ScanError only for stage-level problems (missing or unparsable file,
    unknown variant); per-material problems become skips.
    """
    with _captured_diagnostics() as found:
        stage = open_stage(path)
        selections = apply_variants(stage, variants) if variants else ()
        gprims = rendered_gprims(stage)
        bound, dangling = bound_materials(stage, gprims)
        scans: list[MaterialScan] = []
        for key, prims in material_prims(stage).items():
            purposes = tuple(sorted(bound.get(key, ())))
            aliases = tuple(str(p.GetPath()) for p in prims[1:])
            try:
                scans.append(scan_material(UsdShade.Material(prims[0]), purposes, all_materials, aliases))
            except Exception as exc:  # noqa: BLE001 - one bad material must not stop the scan
                scans.append(_error_scan(str(prims[0].GetPath()), exc, purposes, aliases))
    composition_errors = _composition_errors(stage)
    return StageScan(
        path=str(Path(path).resolve()),
        variant_selections=selections,
        all_materials=all_materials,
        rendered_gprims=len(gprims),
        materials=tuple(scans),
        dangling_bindings=tuple(sorted(dangling)),
        composition_errors=composition_errors,
        diagnostics=_new_diagnostics(found, composition_errors),
        **_stage_facts(stage),
    )
