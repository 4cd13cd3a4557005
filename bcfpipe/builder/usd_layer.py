"""The USD side of a build: a root layer over the input stage, and an overrides layer that applies
``BcfNeuralMaterialAPI`` to every modelled Material.

``<OUT>/<scene>.bcf.usda`` (the stage to open)::

    #usda 1.0
    (
        defaultPrim, upAxis, metersPerUnit (and time-code metadata) copied from the input
        subLayers = [@./overrides.usda@, @../<scene>.usda@]   # relative: moves with OUT + input
    )

``<OUT>/overrides.usda`` holds only ``over`` opinions: the variant selections the build was made
with (so the output composes the variant that was modelled), and per modelled Material::

    over "Mat" (prepend apiSchemas = ["BcfNeuralMaterialAPI"]) {
        uniform asset[] bcf:featureTextures = [@./materials/Mat/T0.dds@, ...]
        ... every schema attribute authored explicitly (see schemas/schema.usda) ...
        rel bcf:fallbackSurface = </.../PreviewSurface>
        token outputs:bcf:surface.connect = </.../Mat/BcfSurface.outputs:surface>
        def Shader "BcfSurface" { uniform token info:id = "BcfNeuralMaterial" ... }  # the Sdr node
        def Shader "BcfStReader" { ... UsdPrimvarReader_float2 of bcf:st:primvar }
        (def Shader "BcfStTransform", a UsdTransform2d, when the st transform is not identity)
    }

Every attribute is authored with its schema type and variability, so the layers read back
identically with or without the schema plugin registered. The input stage is never written.

A layout's classic textures (BC@R, a repack, a mixed layout's classic groups) reach the universal
context too: bcfpipe.builder.usd_classic points their UsdUVTexture nodes at the shipped DDS.

A UsdPreviewSurface input whose texture is constant (issue #18) gets its value instead, and its
connection is blocked, in the same layer::

    over "PreviewSurface" {
        color3f inputs:diffuseColor = (0.497, 0.036, 0.044)
        color3f inputs:diffuseColor.connect = None
    }
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

from pxr import Gf, Sdf, Usd, Vt

from bcfpipe.builder.usd_classic import author_classic
from bcfpipe.formats.material import Mlp
from bcfpipe.formats.usd_schema import component_index

__all__ = ["SCHEMA", "ConstantInput", "NeuralMaterialOverride", "relative_asset", "write_overrides_layer",
           "write_root_layer", "read_override"]

SCHEMA = "BcfNeuralMaterialAPI"
_T = Sdf.ValueTypeNames
_U = Sdf.VariabilityUniform

# Stage metadata copied from the input's root layer to the output root layer when authored there.
_COPIED_METADATA = ("startTimeCode", "endTimeCode", "timeCodesPerSecond", "framesPerSecond")


def relative_asset(target: str | os.PathLike, layer_dir: str | os.PathLike) -> str:
    """An asset path to `target` relative to `layer_dir` (``./x`` or ``../x``), POSIX separators;
    absolute when no relative path exists (another drive)."""
    try:
        rel = os.path.relpath(os.fspath(target), os.fspath(layer_dir))
    except ValueError:
        return Path(target).resolve().as_posix()
    rel = rel.replace(os.sep, "/")
    return rel if rel.startswith("../") else f"./{rel}"


@dataclass(frozen=True)
class NeuralMaterialOverride:
    """Every value of one Material's BcfNeuralMaterialAPI (asset paths relative to the overrides
    layer's folder)."""

    material: str
    feature_textures: tuple[str, ...]
    feature_resolutions: tuple[int, ...]
    feature_mip_counts: tuple[int, ...]
    feature_lod_biases: tuple[float, ...]
    feature_signed: bool
    wrap: tuple[str, str]  # (S, T): bcf:wrapS / bcf:wrapT
    reference_resolution: tuple[int, int]
    st_primvar: str
    st_scale: tuple[float, float]
    st_rotation: float
    st_translation: tuple[float, float]
    weights: str
    weights_offset: int
    weights_size: int
    weights_index: int
    mlp: Mlp  # the material.json record; its weights/offset are superseded by the combined buffer's
    decoder: str
    targets: tuple[str, ...]
    channels: tuple[int, ...]
    scale: tuple[float, ...]
    bias: tuple[float, ...]
    color_spaces: tuple[str, ...]
    fallback_surface: str | None
    version: str
    split: int = 0  # material.json "split": the first reference mip the decoder serves (0: every mip)

    def attributes(self) -> list[tuple[str, Sdf.ValueTypeName, object]]:
        """(name, type, value) of every attribute, in schema order."""
        return [
            ("bcf:featureTextures", _T.AssetArray,
             Sdf.AssetPathArray([Sdf.AssetPath(p) for p in self.feature_textures])),
            ("bcf:featureResolutions", _T.IntArray, Vt.IntArray([int(v) for v in self.feature_resolutions])),
            ("bcf:featureMipCounts", _T.IntArray, Vt.IntArray([int(v) for v in self.feature_mip_counts])),
            ("bcf:featureLodBiases", _T.FloatArray, Vt.FloatArray([float(b) for b in self.feature_lod_biases])),
            ("bcf:featureSigned", _T.Bool, bool(self.feature_signed)),
            ("bcf:wrapS", _T.Token, self.wrap[0]),
            ("bcf:wrapT", _T.Token, self.wrap[1]),
            ("bcf:referenceResolution", _T.Int2, Gf.Vec2i(*(int(v) for v in self.reference_resolution))),
            *([("bcf:split", _T.Int, int(self.split))] if self.split else []),
            ("bcf:st:primvar", _T.Token, self.st_primvar),
            ("bcf:st:scale", _T.Float2, Gf.Vec2f(*(float(v) for v in self.st_scale))),
            ("bcf:st:rotation", _T.Float, float(self.st_rotation)),
            ("bcf:st:translation", _T.Float2, Gf.Vec2f(*(float(v) for v in self.st_translation))),
            ("bcf:weights", _T.Asset, Sdf.AssetPath(self.weights)),
            ("bcf:weightsOffset", _T.Int, int(self.weights_offset)),
            ("bcf:weightsSize", _T.Int, int(self.weights_size)),
            ("bcf:weightsIndex", _T.Int, int(self.weights_index)),
            ("bcf:mlp:inputs", _T.Int, self.mlp.n_in),
            ("bcf:mlp:hidden", _T.Int, self.mlp.n_hidden),
            ("bcf:mlp:outputs", _T.Int, self.mlp.n_out),
            ("bcf:mlp:precision", _T.Token, self.mlp.precision),
            ("bcf:mlp:activation", _T.Token, self.mlp.activation),
            ("bcf:decoder", _T.Asset, Sdf.AssetPath(self.decoder)),
            ("bcf:outputs:targets", _T.TokenArray, Vt.TokenArray(list(self.targets))),
            ("bcf:outputs:channels", _T.IntArray, Vt.IntArray([int(c) for c in self.channels])),
            ("bcf:outputs:scale", _T.FloatArray, Vt.FloatArray([float(v) for v in self.scale])),
            ("bcf:outputs:bias", _T.FloatArray, Vt.FloatArray([float(v) for v in self.bias])),
            ("bcf:outputs:colorSpaces", _T.TokenArray, Vt.TokenArray(list(self.color_spaces))),
            ("bcf:version", _T.String, self.version),
        ]


_INPUT_TYPES = {"diffuseColor": _T.Color3f, "emissiveColor": _T.Color3f, "specularColor": _T.Color3f,
                "normal": _T.Normal3f}
@dataclass(frozen=True)
class ConstantInput:
    """A UsdPreviewSurface input set to the constant its texture gives: ``values`` by target
    (``diffuseColor.r`` ..., or the input's own name for a scalar)."""

    shader: str
    input: str
    values: tuple[tuple[str, float], ...]

    def typed_value(self) -> tuple[Sdf.ValueTypeName, object]:
        type_name = _INPUT_TYPES.get(self.input, _T.Float)
        if type_name == _T.Float:
            return type_name, float(self.values[0][1])
        vec = [0.0, 0.0, 0.0]
        for target, v in self.values:
            k = component_index(target)
            if k is not None:
                vec[k] = float(v)
            else:  # a vector input fed from one texture channel: the value in every component
                vec = [float(v)] * 3
        return type_name, Gf.Vec3f(*vec)


def _author_constant(layer: Sdf.Layer, c: ConstantInput) -> None:
    spec = _over(layer, c.shader)
    type_name, value = c.typed_value()
    attr = Sdf.AttributeSpec(spec, f"inputs:{c.input}", type_name)
    attr.default = value
    attr.connectionPathList.ClearEditsAndMakeExplicit()


def _over(layer: Sdf.Layer, path: str) -> Sdf.PrimSpec:
    """The prim spec at `path` (``over``s created for it and its ancestors)."""
    return Sdf.CreatePrimInLayer(layer, Sdf.Path(path))


def _author(layer: Sdf.Layer, ov: NeuralMaterialOverride) -> None:
    spec = _over(layer, ov.material)
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=[SCHEMA]))
    for name, type_name, value in ov.attributes():
        attr = Sdf.AttributeSpec(spec, name, type_name, _U)
        attr.default = value
    if ov.fallback_surface:
        rel = Sdf.RelationshipSpec(spec, "bcf:fallbackSurface", False, _U)
        rel.targetPathList.explicitItems = [Sdf.Path(ov.fallback_surface)]
    _author_surface(layer, spec, ov)


SURFACE_SHADER, ST_READER, ST_TRANSFORM = "BcfSurface", "BcfStReader", "BcfStTransform"


def _shader(layer: Sdf.Layer, path: str, shader_id: str) -> Sdf.PrimSpec:
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path))
    spec.specifier = Sdf.SpecifierDef
    spec.typeName = "Shader"
    Sdf.AttributeSpec(spec, "info:id", _T.Token, _U).default = shader_id
    return spec


def _input(spec: Sdf.PrimSpec, name: str, type_name: Sdf.ValueTypeName, value=None,
           source: str | None = None) -> None:
    attr = Sdf.AttributeSpec(spec, f"inputs:{name}", type_name)
    if value is not None:
        attr.default = value
    if source is not None:
        attr.connectionPathList.explicitItems = [Sdf.Path(source)]


def _author_surface(layer: Sdf.Layer, material: Sdf.PrimSpec, ov: NeuralMaterialOverride) -> None:
    """The ``bcf`` render context: ``outputs:bcf:surface`` of the material connected to a
    BcfNeuralMaterial shader (schemas/shaders/BcfNeuralMaterial.usda) fed with the schema's values, its
    st read from the material's primvar through its UsdTransform2d. Every other render context
    keeps the untouched UsdPreviewSurface network."""
    base = ov.material
    reader = _shader(layer, f"{base}/{ST_READER}", "UsdPrimvarReader_float2")
    _input(reader, "varname", _T.String, ov.st_primvar)
    Sdf.AttributeSpec(reader, "outputs:result", _T.Float2)
    st = f"{base}/{ST_READER}.outputs:result"
    if tuple(ov.st_scale) != (1.0, 1.0) or ov.st_rotation != 0.0 or tuple(ov.st_translation) != (0.0, 0.0):
        xf = _shader(layer, f"{base}/{ST_TRANSFORM}", "UsdTransform2d")
        _input(xf, "in", _T.Float2, source=st)
        _input(xf, "scale", _T.Float2, Gf.Vec2f(*(float(v) for v in ov.st_scale)))
        _input(xf, "rotation", _T.Float, float(ov.st_rotation))
        _input(xf, "translation", _T.Float2, Gf.Vec2f(*(float(v) for v in ov.st_translation)))
        Sdf.AttributeSpec(xf, "outputs:result", _T.Float2)
        st = f"{base}/{ST_TRANSFORM}.outputs:result"
    sh = _shader(layer, f"{base}/{SURFACE_SHADER}", "BcfNeuralMaterial")
    _input(sh, "st", _T.Float2, source=st)
    for i, path in enumerate(ov.feature_textures):
        _input(sh, f"T{i}", _T.Asset, Sdf.AssetPath(path))
    for i, b in enumerate(ov.feature_lod_biases):
        _input(sh, f"lodBias{i}", _T.Float, float(b))
    _input(sh, "referenceResolution", _T.Int2, Gf.Vec2i(*(int(v) for v in ov.reference_resolution)))
    _input(sh, "featureSigned", _T.Int, int(bool(ov.feature_signed)))
    _input(sh, "wrapS", _T.Token, ov.wrap[0])
    _input(sh, "wrapT", _T.Token, ov.wrap[1])
    _input(sh, "weights", _T.Asset, Sdf.AssetPath(ov.weights))
    _input(sh, "weightsOffset", _T.Int, int(ov.weights_offset))
    if ov.split:
        _input(sh, "split", _T.Int, int(ov.split))
    Sdf.AttributeSpec(sh, "outputs:surface", _T.Token)
    out = Sdf.AttributeSpec(material, "outputs:bcf:surface", _T.Token)
    out.connectionPathList.explicitItems = [Sdf.Path(f"{base}/{SURFACE_SHADER}.outputs:surface")]


def write_overrides_layer(path: str | os.PathLike, overrides: Iterable[NeuralMaterialOverride],
                          variant_selections: Sequence[tuple[str, str, str]] = (), comment: str = "",
                          constants: Iterable[ConstantInput] = (), classic: Sequence = (),
                          source_stage: Usd.Stage | None = None) -> Path:
    """Write the overrides layer: variant selections (prim, set, value), then one API-schema
    ``over`` per material (in the order given), then the constant inputs, then the UsdUVTexture
    nodes of the classic textures (``classic``: bcfpipe.builder.usd_classic.ClassicMaterial, read
    from ``source_stage``)."""
    path = Path(path)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    if comment:
        layer.comment = comment
    for prim, vset, value in variant_selections:
        _over(layer, prim).variantSelections[vset] = value
    for ov in overrides:
        _author(layer, ov)
    for c in constants:
        _author_constant(layer, c)
    if classic:
        author_classic(layer, source_stage, classic)
    layer.Export(str(path))
    return path


def write_root_layer(path: str | os.PathLike, sublayers: Sequence[str], up_axis: str, meters_per_unit: float,
                     default_prim: str | None, source_root_layer: str | None = None, comment: str = "") -> Path:
    """Write the root layer: `sublayers` (strongest first, already relative), the stage metrics,
    and time-code metadata copied from `source_root_layer` when authored there."""
    path = Path(path)
    layer = Sdf.Layer.CreateAnonymous(".usda")
    if comment:
        layer.comment = comment
    layer.subLayerPaths = list(sublayers)
    root = layer.pseudoRoot
    root.SetInfo("upAxis", up_axis)
    root.SetInfo("metersPerUnit", float(meters_per_unit))
    if default_prim:
        dp = default_prim[1:] if default_prim.startswith("/") and default_prim.count("/") == 1 else default_prim
        layer.defaultPrim = dp
    if source_root_layer:
        src = Sdf.Layer.FindOrOpen(source_root_layer)
        if src is not None:
            for key in _COPIED_METADATA:
                if src.pseudoRoot.HasInfo(key):
                    root.SetInfo(key, src.pseudoRoot.GetInfo(key))
    layer.Export(str(path))
    return path


def read_override(prim: Usd.Prim) -> dict[str, object]:
    """Every authored ``bcf:`` property of a prim, by name (works without the schema plugin)."""
    out: dict[str, object] = {}
    for prop in prim.GetAuthoredProperties():
        name = prop.GetName()
        if not name.startswith("bcf:"):
            continue
        if isinstance(prop, Usd.Relationship):
            out[name] = [str(t) for t in prop.GetTargets()]
        else:
            out[name] = prop.Get()
    return out
