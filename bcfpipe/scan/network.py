"""Reading one UsdPreviewSurface input: constants, UsdUVTexture files, channels, wrap modes,
st sources and UsdTransform2d (UsdPreviewSurface spec 2.5)."""
from __future__ import annotations

import math
import struct
from typing import Any

from pxr import Sdf, Usd, UsdShade

from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.scan.results import InputScan, PREVIEW_SURFACE_INPUTS, StSource, TextureRef, Transform2d
from bcfpipe.scan.values import is_unregistered


COLOR_INPUTS = frozenset({"diffuseColor", "emissiveColor", "specularColor"})

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
WRAP_MODES = frozenset({"black", Wrap.CLAMP, Wrap.REPEAT, "mirror", "useMetadata"})


def texture_targets(name: str, channel: str) -> list[tuple[str, str]]:
    """(texture channel, UsdPreviewSurface target) pairs for `name` read through `channel`."""
    if channel == "rgb":
        if name == "normal":
            return [("r", "normal.x"), ("g", "normal.y")]
        if name in COLOR_INPUTS:
            return [(c, f"{name}.{c}") for c in "rgb"]
        return [("r", name)]  # a scalar fed from rgb reads the first component
    return [(channel, name)]


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
    if value is None or is_unregistered(value):
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


def shader_id(prim: Usd.Prim) -> str | None:
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


def st_source(texture: UsdShade.Shader) -> StSource:
    """Describe where a UsdUVTexture's st comes from."""
    attr = _source_attr(texture, "st")
    if attr is None or not UsdShade.Output.IsOutput(attr):
        value, _ = _input_value(texture, "st", _TEXTURE_DEFAULTS["st"])
        return StSource("constant", value=_vec2(value, (0.0, 0.0)), detail="st not connected")
    node = UsdShade.Shader(attr.GetPrim())
    sid = shader_id(node.GetPrim())
    if sid == "UsdPrimvarReader_float2":
        return StSource("primvar", varname=_primvar_varname(node))
    if sid == "UsdTransform2d":
        xform = _transform2d(node)
        upstream = _source_attr(node, "in")
        if upstream is not None and UsdShade.Output.IsOutput(upstream):
            reader = UsdShade.Shader(upstream.GetPrim())
            if shader_id(reader.GetPrim()) == "UsdPrimvarReader_float2":
                return StSource("transform2d", varname=_primvar_varname(reader), transform=xform)
            feeder = shader_id(reader.GetPrim()) or reader.GetPath()
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
        st=st_source(texture),
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
        unknown = attr is not None and is_unregistered(attr.Get())
        return InputScan(name, "constant", value=value, authored=authored,
                         detail="its value has a type USD does not know; the default is used" if unknown else "")
    node = UsdShade.Shader(attr.GetPrim())
    sid = shader_id(node.GetPrim())
    output = UsdShade.Output(attr).GetBaseName()
    if sid == "UsdUVTexture":
        return InputScan(name, "texture", texture=_texture_ref(node, output))
    if sid and sid.startswith("UsdPrimvarReader"):
        return InputScan(name, "primvar", detail=f"primvar {_primvar_varname(node)!r} via {sid}")
    source = f"{sid or 'shader'} {node.GetPath()}.outputs:{output}"
    return InputScan(name, "unsupported", detail=f"connected to {source}")
