"""What each material's shading inputs read, from the USD stage alone.

A *neural* surface comes from the material's ``bcf`` render context (``outputs:bcf:surface`` ->
a ``BcfNeuralMaterial`` shader, docs/build.md): its inputs name the feature textures, lod biases
and the weight record; the material's ``bcf:outputs:*`` say which decoder channel feeds which
UsdPreviewSurface component and how (colour space, scale, bias). An *original* surface is the
universal UsdPreviewSurface network: UsdUVTexture files with their channels, scale, bias,
colour space, wrap modes and UsdTransform2d. Inputs nobody textures keep the surface's constants.

Both reduce to one table, :data:`COMPONENTS`, with a :class:`Component` per entry that the
fragment shader (glsl/bcf_render.frag) evaluates as ``value = decode(texel) * scale + bias``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

from pxr import Sdf, Usd, UsdShade

from bcfpipe.errors import InputError
from bcfpipe.formats.vocabulary import ColorSpace, Wrap, wrap_axes
from bcfpipe.scan.network import scan_input, shader_id, st_source
from bcfpipe.scan.results import PREVIEW_SURFACE_INPUTS, TextureRef, Transform2d
from bcfpipe.scan.values import is_unregistered

__all__ = ["COMPONENTS", "Component", "NeuralFeatures", "OriginalTexture", "Surface", "read_surface",
           "NEURAL_SHADER_ID", "MAX_TEXTURES", "TEXTURE_SOURCE"]

NEURAL_SHADER_ID = "BcfNeuralMaterial"
MAX_TEXTURES = 8  # texture units of the original program
MIN_LAYERS, MAX_LAYERS = 4, 6  # feature layers of a neural material (bcf_decode.glsl's BCF_N_LAYERS)
# In a neural surface, a component source at or above this reads an original texture (source -
# TEXTURE_SOURCE = unit * 4 + slot): a --layout auto material's classic groups keep their
# UsdUVTexture, which the same program samples beside the decoder.
TEXTURE_SOURCE = 1024

#: The shading components, in the order of the shader's uniform arrays.
COMPONENTS = (
    "diffuseColor.r", "diffuseColor.g", "diffuseColor.b",
    "emissiveColor.r", "emissiveColor.g", "emissiveColor.b",
    "specularColor.r", "specularColor.g", "specularColor.b",
    "metallic", "roughness", "opacity",
    "normal.x", "normal.y", "normal.z",
    "occlusion", "ior",
)
_INPUT_OF = {c: c.split(".")[0] for c in COMPONENTS}
_SLOT = {"r": 0, "g": 1, "b": 2, "x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Component:
    """``source`` -1: the constant ``bias``. Else a decoder channel (neural) or texture unit * 4 +
    rgba slot (original), colour-decoded when ``srgb``, then ``* scale + bias``."""

    source: int = -1
    scale: float = 0.0
    bias: float = 0.0
    srgb: bool = False
    # A mip-split material's decoder channel below its split reads the original network instead:
    # its texture source (TEXTURE_SOURCE + unit * 4 + slot; -1: the constant ``below_bias``)
    below: int = -1
    below_scale: float = 0.0
    below_bias: float = 0.0
    below_srgb: bool = False


@dataclass(frozen=True)
class OriginalTexture:
    """One UsdUVTexture file as a texture unit: rgba slots as UsdUVTexture outputs r, g, b, a."""

    path: str  # resolved path (may be inside a package)
    wrap: tuple[str, str]
    transform: Transform2d
    color_space: str  # as authored: auto / raw / sRGB (auto resolved when the file is read)


@dataclass(frozen=True)
class NeuralFeatures:
    """The BcfNeuralMaterial shader's inputs (schemas/shaders/BcfNeuralMaterial.usda)."""

    textures: tuple[str, ...]  # T0..T{n-1}: material.json's layers in order, n = 4 to 6
    lod_biases: tuple[float, ...]
    reference_size: tuple[int, int]
    signed: bool
    wrap: tuple[str, str]  # (S, T): inputs:wrapS / wrapT
    weights: str
    weights_offset: int
    normal_index: int  # decoder channel of normal.x, -1 without a normal
    split: int = 0  # a mip split's first reference mip the decoder serves (bcf:split); 0: none


@dataclass(frozen=True)
class Surface:
    material: str | None
    kind: str  # "neural" or "original"
    components: tuple[Component, ...]
    st_primvar: str = "st"
    st_transform: Transform2d = Transform2d()  # neural: the material's; original: per texture
    textures: tuple[OriginalTexture, ...] = ()
    neural: NeuralFeatures | None = None
    use_specular_workflow: bool = False
    opacity_threshold: float = 0.0
    notes: tuple[str, ...] = field(default=())


def _constant_components(values: dict[str, object]) -> list[Component]:
    out = []
    for c in COMPONENTS:
        name, _, part = c.partition(".")
        v = values[name]
        if isinstance(v, (tuple, list)):
            v = v[_SLOT[part]] if part and len(v) > _SLOT[part] else v[0]
        out.append(Component(-1, 0.0, float(v)))
    return out


def _constants(surface: UsdShade.Shader | None) -> tuple[dict[str, object], dict[str, TextureRef], list[str]]:
    """(every input's constant value or default, texture inputs, notes) of a UsdPreviewSurface."""
    values = dict(PREVIEW_SURFACE_INPUTS)
    textures: dict[str, TextureRef] = {}
    notes = []
    if surface is None:
        return values, textures, notes
    for name in PREVIEW_SURFACE_INPUTS:
        scan = scan_input(surface, name)
        if scan.kind == "constant":
            values[name] = scan.value
        elif scan.kind == "texture" and scan.texture.ok:
            textures[name] = scan.texture
        elif name != "displacement":
            notes.append(f"{name}: {scan.detail or (scan.texture and scan.texture.problem)}; default used")
    return values, textures, notes


def _preview_surface(material: UsdShade.Material) -> UsdShade.Shader | None:
    shader, _, _ = material.ComputeSurfaceSource("")
    return shader if shader and shader_id(shader.GetPrim()) == "UsdPreviewSurface" else None


def _original(path: str, material: UsdShade.Material | None, display_color) -> Surface:
    surface = _preview_surface(material) if material else None
    values, refs, notes = _constants(surface)
    if surface is None:
        values["diffuseColor"] = display_color
        if material:
            notes.append("no UsdPreviewSurface: displayColor used")
    comps = _constant_components(values)
    units: list[tuple] = []
    textures: list[OriginalTexture] = []
    st = None
    for name, ref in refs.items():
        if name == "displacement":
            continue
        if ref.st.kind not in ("primvar", "transform2d"):
            notes.append(f"{name}: st {ref.st.kind} ({ref.st.detail}) is not drawn; default used")
            continue
        if st is None:
            st = ref.st
        elif ref.st.varname != st.varname:
            notes.append(f"{name}: st primvar {ref.st.varname!r} differs from {st.varname!r}; drawn with the first")
        key = (ref.resolved_path, ref.effective_wrap, ref.st.transform or Transform2d(), ref.source_color_space)
        if key not in units:
            if len(units) == MAX_TEXTURES:
                notes.append(f"{name}: more than {MAX_TEXTURES} textures; default used")
                continue
            units.append(key)
            textures.append(OriginalTexture(*key))
        unit = units.index(key)
        for i, c in enumerate(COMPONENTS):
            if _INPUT_OF[c] != name:
                continue
            slot = "rgba".index(ref.channel) if ref.channel != "rgb" else _SLOT[c.split(".")[1]]
            comps[i] = Component(unit * 4 + slot, ref.scale[slot], ref.bias[slot], srgb=slot < 3)
    return Surface(path, "original", tuple(comps), st_primvar=(st.varname if st else "st") or "st",
                   textures=tuple(textures), use_specular_workflow=bool(values["useSpecularWorkflow"]),
                   opacity_threshold=float(values["opacityThreshold"]), notes=tuple(notes))


def _checked(value, where: str):
    """A value of the build's own: one of a type USD does not know means a damaged layer."""
    if is_unregistered(value):
        raise InputError(f"{where}: a value of a type USD does not know; a damaged build (build it again)")
    return value


def _input(shader: UsdShade.Shader, name: str, default=None):
    inp = shader.GetInput(name)
    v = _checked(inp.Get(), f"{shader.GetPath()}.inputs:{name}") if inp else None
    return default if v is None else v


def _wrap(shader: UsdShade.Shader) -> tuple[str, str]:
    """(S, T) addressing of the features: inputs:wrapS / wrapT (a layer from before issue 57 has
    one inputs:addressing for both axes)."""
    both = str(_input(shader, "addressing", Wrap.REPEAT))
    wrap = (str(_input(shader, "wrapS", both)), str(_input(shader, "wrapT", both)))
    try:
        return tuple(str(w) for w in wrap_axes(wrap))  # type: ignore[return-value]
    except ValueError as exc:
        raise InputError(f"{shader.GetPath()}: {exc}") from None


def feature_layer_count(shader: UsdShade.Shader) -> int:
    """How many feature layers the BcfNeuralMaterial shader names: T0..T3 always (a missing one is
    reported when read), and T4, T5 where authored (a T_0 of several layers, issue 52)."""
    n = MIN_LAYERS
    while n < MAX_LAYERS and shader.GetInput(f"T{n}"):
        n += 1
    return n


def _asset(shader: UsdShade.Shader, name: str, material: str) -> str:
    v = _input(shader, name)
    resolved = v.resolvedPath if isinstance(v, Sdf.AssetPath) else ""
    if not resolved:
        raise InputError(f"{material}: {shader.GetPath()}.inputs:{name} "
                         f"{(v.path if isinstance(v, Sdf.AssetPath) else 'is not authored')!r} does not resolve")
    return resolved


def _neural(path: str, material: UsdShade.Material, shader: UsdShade.Shader, display_color) -> Surface:
    base = _original(path, material, display_color)
    prim = material.GetPrim()

    def attr(name, default):
        v = _checked(prim.GetAttribute(name).Get(), f"{prim.GetPath()}.{name}") if prim.HasAttribute(name) else None
        return default if v is None else list(v)

    targets = [str(t) for t in attr("bcf:outputs:targets", [])]
    channels = attr("bcf:outputs:channels", [])
    scale, bias = attr("bcf:outputs:scale", []), attr("bcf:outputs:bias", [])
    spaces = [str(t) for t in attr("bcf:outputs:colorSpaces", [])]
    if not targets or not all(len(x) == len(targets) for x in (channels, scale, bias, spaces)):
        raise InputError(f"{path}: bcf:outputs:* are missing or of different lengths; not a bcfpipe build?")
    comps = list(base.components)
    driven = set()
    for t, c, s, b, cs in zip(targets, channels, scale, bias, spaces):
        if t in COMPONENTS:  # bare "diffuseColor": one channel drives the colour
            names = [t]
        else:
            names = [x for x in COMPONENTS if _INPUT_OF[x] == t]
        for n in names:
            comps[COMPONENTS.index(n)] = Component(int(c), float(s), float(b), cs == ColorSpace.SRGB)
            driven.add(n)
    split = int(_input(shader, "split", 0))
    for k, name in enumerate(COMPONENTS):
        o = base.components[k]
        if name not in driven and o.source >= 0:  # what the decoder does not drive keeps its texture
            comps[k] = replace(o, source=o.source + TEXTURE_SOURCE)
        elif name in driven and split > 0:  # below the split, the original network's value
            comps[k] = replace(comps[k], below=o.source + TEXTURE_SOURCE if o.source >= 0 else -1,
                               below_scale=o.scale, below_bias=o.bias, below_srgb=o.srgb)
    st = st_source(shader)
    res = _input(shader, "referenceResolution", (0, 0))
    n = feature_layer_count(shader)
    feats = NeuralFeatures(
        textures=tuple(_asset(shader, f"T{i}", path) for i in range(n)),
        lod_biases=tuple(float(_input(shader, f"lodBias{i}", 0.0)) for i in range(n)),
        reference_size=(int(res[0]), int(res[1])),
        signed=bool(_input(shader, "featureSigned", 0)),
        wrap=_wrap(shader),
        weights=_asset(shader, "weights", path),
        weights_offset=int(_input(shader, "weightsOffset", 0)),
        normal_index=int(channels[targets.index("normal.x")]) if "normal.x" in targets else -1,
        split=split)
    modelled = {t.split(".")[0] for t in targets}
    notes = [n for n in base.notes if n.split(":")[0] not in modelled]
    if st.kind not in ("primvar", "transform2d"):
        notes.append(f"st {st.kind} ({st.detail}); primvar 'st' used")
    return replace(base, kind="neural", components=tuple(comps), st_primvar=st.varname or "st",
                   st_transform=st.transform or Transform2d(), neural=feats, notes=tuple(notes))


def read_surface(stage: Usd.Stage, path: str | None, neural: bool,
                 display_color=(0.18, 0.18, 0.18)) -> Surface:
    """The surface drawn for material ``path``: its ``bcf`` context when ``neural`` and present,
    else its UsdPreviewSurface (``path`` None: an unbound mesh, drawn with its displayColor)."""
    material = UsdShade.Material(stage.GetPrimAtPath(path)) if path else None
    if material and neural:
        shader, _, _ = material.ComputeSurfaceSource("bcf")
        if shader and shader_id(shader.GetPrim()) == NEURAL_SHADER_ID:
            return _neural(path, material, shader, display_color)
    return _original(path, material, display_color)
