"""The universal (UsdPreviewSurface) side of a layout's classic textures: the overrides layer points
the UsdUVTexture nodes of every output that ships as a classic BC texture at its DDS in OUT.

A classic output's value is ``v = texel * texel_scale + texel_bias`` (material.json; normals 2t - 1),
then the source's value map ``f = v * value_scale + value_bias``; the UsdPreviewSurface input the
source network fed was ``cs(f) * s + b`` (the build's target: scale, bias and colour space, normals
already folded to v). A UsdUVTexture computes ``cs(t) * scale + bias`` per rgba slot, so:

* raw: ``scale = s * texel_scale * value_scale``, ``bias = s * (texel_bias * value_scale + value_bias) + b``;
* sRGB: only when ``f = t`` (colour textures store the source file's encoded values, texel map 1, 0):
  ``sourceColorSpace = "sRGB"`` (rgb slots only; alpha is always linear), scale ``s``, bias ``b``;
* a constant component of an input: scale 0, bias its value;
* a normal: a layout's classic normal is BC5 of its slopes (material.json: encoding "slope", x's and
  y's texel_scale 2m, texel_bias -m give s = (x / z, y / z)), which a UsdUVTexture cannot turn back
  into (x, y, sqrt(1 - x² - y²)); but UsdPreviewSurface normalises its tangent-space normal (Storm
  does), and (s_x, s_y, 1) normalised is (x, y, z). So r and g read s / M (scale 2m / M, bias -m / M)
  and b the constant 1 / M (scale 0: BC5's b, 0 as Storm and OpenImageIO read a two-channel texture,
  is not used), with M = max(m, 1) so that every component stays in the normal's documented
  [-1, 1] (issue 57; docs/benchmarks.md measures the angle). A normal stored as x, y without an
  encoding (an older build's BC5) reads z as 1: scale 0, bias 1, ``(x, y, 1)``.
* a colour whose source repeats a channel (its b equals its g, a grey file) keeps it in each slot
  a UsdUVTexture's rgb reads: material.json's ``slots`` says which output each texel channel holds.

An input is wired only when one UsdUVTexture output can give it: a vector input (colour, normal)
needs its components in slots r, g, b (x, y) of one texture, a scalar any one slot. Otherwise it
keeps its source texture, and the build table says so. Nodes: the source node is overridden when
every reader of it moves to the same DDS; otherwise new UsdUVTexture prims ``<node>_C<i>`` are
defined beside it (same st connection, wrap modes and fallback) and the inputs re-pointed.

Inputs of the decoder (neural outputs) keep the universal network on their sources: their values
come from the ``bcf`` render context. A mip split's DDS holds only the levels below its split; a
UsdUVTexture reading it would clamp far views to its coarsest kept level, so split outputs keep
their sources in the universal context too (the decoder serves them in ``bcf``).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterable, Sequence

from pxr import Gf, Sdf, Usd, UsdShade

from bcfpipe.formats import material as mf
from bcfpipe.formats.vocabulary import ColorSpace, Source
from bcfpipe.scan.network import COLOR_INPUTS
from bcfpipe.scan.network import scan_input

__all__ = ["Wiring", "ClassicMaterial", "wire_material", "author_classic", "open_source_stage", "usd_notes",
           "NOTE_KEY", "UNTOUCHED"]

_T = Sdf.ValueTypeNames
_U = Sdf.VariabilityUniform
_SLOT = {"r": 0, "g": 1, "b": 2, "x": 0, "y": 1, "z": 2}
_VECTOR_COMPONENTS = {"normal": ("normal.x", "normal.y", "normal.z")}
NOTE_KEY = "bcfpipeUsd"  # customData on a material's over: what the layer did to its universal network
_EPS = 1e-9
ALL = "*"  # a ClassicMaterial.kept entry for the whole universal network
SPLIT_WHY = "mip split: its DDS hold only the levels below the split"


@dataclass(frozen=True)
class Wiring:
    """One UsdPreviewSurface input read from one classic texture through one UsdUVTexture output."""

    input: str
    type_name: str  # the input's Sdf type (color3f, normal3f, float)
    node: str  # the UsdUVTexture the source network reads it from
    texture: int  # index into material.json classic
    file: str  # the DDS, an asset path relative to the overrides layer
    output: str  # rgb, r, g, b or a
    slots: tuple[tuple[int, float, float], ...]  # (rgba slot, scale, bias)
    srgb: bool  # the rgb slots decode from sRGB


@dataclass(frozen=True)
class ClassicMaterial:
    """What the universal network of one material gets: its wired inputs, and the inputs with
    classic outputs kept on their sources (name, why)."""

    material: str
    surface: str
    wired: tuple[Wiring, ...]
    kept: tuple[tuple[str, str], ...] = ()
    neural: bool = False  # the material also has a bcf render context


@dataclass
class _Node:
    path: str
    source: str  # the source node it replaces for its inputs
    reuse: bool
    texture: int
    file: str
    srgb: bool = False
    slots: dict[int, tuple[float, float]] = field(default_factory=dict)
    inputs: list[Wiring] = field(default_factory=list)


def open_source_stage(scene: str, variant_selections: Sequence[tuple[str, str, str]]) -> Usd.Stage:
    """The input stage with the build's variant selections in its session layer (what was modelled)."""
    stage = Usd.Stage.Open(str(scene), Usd.Stage.LoadAll)
    session = stage.GetSessionLayer()
    for prim, vset, value in variant_selections:
        Sdf.CreatePrimInLayer(session, Sdf.Path(prim)).variantSelections[vset] = value
    return stage


def _components(name: str, channel: str) -> list[tuple[str, int]]:
    """(target, slot) of an input read through UsdUVTexture output ``channel``."""
    if channel == "rgb" and name in _VECTOR_COMPONENTS:
        return [(t, _SLOT[t.split(".")[1]]) for t in _VECTOR_COMPONENTS[name]]
    if channel == "rgb" and name in COLOR_INPUTS:
        return [(f"{name}.{c}", _SLOT[c]) for c in "rgb"]
    return [(name, 0)]


def _slot_map(t, o: mf.Output) -> tuple[float, float] | str:
    """(scale, bias) of a UsdUVTexture slot that gives target ``t`` from classic output ``o``, or why not."""
    if o.log_gain is not None:
        return f"{o.name} has a log curve"
    ts, tb = float(o.texel_scale), float(o.texel_bias)
    vs, vb = float(o.value_scale), float(o.value_bias)
    if t.color_space == ColorSpace.SRGB:
        if abs(ts * vs - 1.0) > _EPS or abs(tb * vs + vb) > _EPS:
            return f"{o.name} is sRGB behind a value map"
        return float(t.scale), float(t.bias)
    return float(t.scale) * ts * vs, float(t.scale) * (tb * vs + vb) + float(t.bias)


def _slope_norm(outs: Sequence[mf.Output], o: mf.Output) -> float:
    """M = max(m, 1) of the slope normal that output ``o`` (x, y or z) belongs to; 1 for a normal
    without an encoding (its z reads 1)."""
    x = next((p for p in outs if p.semantic == o.semantic and p.encoding == mf.SLOPE and not p.reconstructed), None)
    return max(float(x.texel_scale) / 2.0, 1.0) if x is not None else 1.0


def _wire_input(name: str, ref, type_name: str, targets: dict, desc: mf.MaterialFile,
                folder: str) -> Wiring | str | None:
    """The wiring of one input, why it cannot be wired (a str), or None when it is not classic."""
    comps = _components(name, ref.channel)
    outs = desc.outputs
    used = [(targets[t], slot) for t, slot in comps if t in targets]
    sources = {outs[t.channel].source for t, _ in used if t.channel >= 0}
    if not used or not sources or Source.CLASSIC not in sources:
        return None
    if sources != {Source.CLASSIC}:
        return "split across the decoder and a classic texture" if Source.SPLIT not in sources else None
    vector = len(comps) > 1
    textures = {outs[t.channel].texture for t, _ in used if t.channel >= 0}
    if len(textures) != 1:
        return f"its channels lie in {len(textures)} DDS files"
    tex = textures.pop()
    slots: list[tuple[int, float, float]] = []
    srgb = False
    for t, slot in used:
        if t.channel < 0:  # a constant component
            slots.append((slot, 0.0, float(t.bias)))
            continue
        o = outs[t.channel]
        if o.reconstructed and o.texel_channel is None:  # normal z: not stored; see the module's note
            slots.append((slot, 0.0, 1.0 / _slope_norm(outs, o)))
            continue
        texel = int(o.texel_channel)
        held = desc.classic[tex].slots
        if vector and texel != slot and held is not None and slot < len(held) and held[slot] == t.channel:
            texel = slot  # the colour's repeated channel, stored again in the slot USD reads
        if vector and texel != slot:
            return f"{o.name} is in slot {'rgba'[texel]} of C{tex}, not {'rgba'[slot]}"
        m = _slot_map(t, o)
        if isinstance(m, str):
            return m
        if o.encoding == mf.SLOPE:  # s / M; see the module's note
            m = (m[0] / _slope_norm(outs, o), m[1] / _slope_norm(outs, o))
        if t.color_space == ColorSpace.SRGB:
            if texel == 3:
                return f"{o.name} is sRGB in an alpha slot"
            srgb = True
        slots.append((texel, *m))
    raw_rgb = [t for t, slot in used if slot < 3 and t.channel >= 0 and outs[t.channel].texel_channel is not None
               and t.color_space != ColorSpace.SRGB]
    if srgb and raw_rgb:
        return "sRGB and raw components in one node"
    output = "rgb" if vector else "rgba"[slots[0][0]]
    return Wiring(name, type_name, ref.shader, tex, f"{folder}/{desc.classic[tex].file}", output, tuple(slots), srgb)


def wire_material(stage: Usd.Stage, material: str, surface: str, targets: Iterable, desc: mf.MaterialFile,
                  folder: str) -> ClassicMaterial | None:
    """How ``material``'s UsdPreviewSurface at ``surface`` reads the classic textures of ``desc``
    (``targets``: the build's TargetMap list, channels indexing desc.outputs; ``folder``: the
    material folder relative to the overrides layer). None without classic outputs."""
    if desc.split is not None:  # see the module's note
        return ClassicMaterial(material, surface, (), ((ALL, SPLIT_WHY),), desc.neural)
    if not any(o.source == Source.CLASSIC for o in desc.outputs):
        return None
    shader = UsdShade.Shader(stage.GetPrimAtPath(surface))
    if not shader:
        return ClassicMaterial(material, surface, (), ((ALL, f"no UsdPreviewSurface at {surface}"),), desc.neural)
    by_target = {t.target: t for t in targets}
    wired, kept = [], []
    for name in dict.fromkeys(t.input for t in targets):
        scan = scan_input(shader, name)
        if scan.kind != "texture" or scan.texture is None:
            continue
        type_name = str(shader.GetInput(name).GetAttr().GetTypeName())
        w = _wire_input(name, scan.texture, type_name, by_target, desc, folder)
        if isinstance(w, Wiring):
            wired.append(w)
        elif isinstance(w, str):
            kept.append((name, w))
    return ClassicMaterial(material, surface, tuple(wired), tuple(kept), desc.neural)


def _fits(node: _Node, w: Wiring) -> bool:
    if node.texture != w.texture or any(abs(node.slots[s][0] - a) > _EPS or abs(node.slots[s][1] - b) > _EPS
                                        for s, a, b in w.slots if s in node.slots):
        return False
    rgb_node = any(s < 3 for s in node.slots) or not node.inputs
    rgb_w = any(s < 3 for s, _, _ in w.slots)
    return not (rgb_node and rgb_w and node.inputs and node.srgb != w.srgb)


def _readers(stage: Usd.Stage, material: str, node: str) -> set[str]:
    """Every attribute under ``material`` connected to an output of ``node``."""
    out = set()
    for prim in Usd.PrimRange(stage.GetPrimAtPath(material)):
        for attr in prim.GetAttributes():
            if any(p.GetPrimPath() == Sdf.Path(node) for p in attr.GetConnections()):
                out.add(str(attr.GetPath()))
    return out


def _nodes(stage: Usd.Stage, cm: ClassicMaterial) -> list[_Node]:
    """The UsdUVTexture nodes of ``cm``'s wired inputs: per source node, inputs sharing a DDS and
    compatible slots share a node; the source node itself is reused when all its readers move to it."""
    nodes: list[_Node] = []
    taken = {str(p.GetPath()) for p in Usd.PrimRange(stage.GetPrimAtPath(cm.material))}
    for source in dict.fromkeys(w.node for w in cm.wired):
        mine: list[_Node] = []
        for w in (w for w in cm.wired if w.node == source):
            node = next((n for n in mine if _fits(n, w)), None)
            if node is None:
                node = _Node("", source, False, w.texture, w.file, w.srgb)
                mine.append(node)
            node.inputs.append(w)
            node.srgb = node.srgb or w.srgb
            node.slots.update({s: (a, b) for s, a, b in w.slots})
        readers = _readers(stage, cm.material, source)
        for i, node in enumerate(mine):
            wired = {f"{cm.surface}.inputs:{w.input}" for w in node.inputs}
            if i == 0 and readers <= wired:
                node.reuse, node.path = True, source
                continue
            stem = f"{source}_C{node.texture}"
            path, k = stem, 1
            while path in taken:
                k += 1
                path = f"{stem}_{k}"
            taken.add(path)
            node.path = path
        nodes += mine
    return nodes


def _author_node(layer: Sdf.Layer, stage: Usd.Stage, node: _Node) -> None:
    spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(node.path))
    if not node.reuse:
        spec.specifier = Sdf.SpecifierDef
        spec.typeName = "Shader"
        Sdf.AttributeSpec(spec, "info:id", _T.Token, _U).default = "UsdUVTexture"
        src = stage.GetPrimAtPath(node.source)
        st = src.GetAttribute("inputs:st")
        attr = Sdf.AttributeSpec(spec, "inputs:st", _T.Float2)
        if st and st.GetConnections():
            attr.connectionPathList.explicitItems = list(st.GetConnections())
        elif st and st.Get() is not None:
            attr.default = st.Get()
        for name in ("wrapS", "wrapT", "fallback"):
            a = src.GetAttribute(f"inputs:{name}")
            if a and a.Get() is not None:
                Sdf.AttributeSpec(spec, f"inputs:{name}", a.GetTypeName()).default = a.Get()
    prim = stage.GetPrimAtPath(node.source) if node.reuse else None

    def attr(name: str, type_name: Sdf.ValueTypeName) -> Sdf.AttributeSpec:
        """A spec of ``name``, typed as the source node already declares it (one type across layers)."""
        have = prim.GetAttribute(name) if prim is not None else None
        return Sdf.AttributeSpec(spec, name, have.GetTypeName() if have else type_name)

    attr("inputs:file", _T.Asset).default = Sdf.AssetPath(node.file)
    attr("inputs:sourceColorSpace", _T.Token).default = ColorSpace.SRGB.value if node.srgb else ColorSpace.RAW.value
    scale = [node.slots.get(s, (1.0, 0.0))[0] for s in range(4)]
    bias = [node.slots.get(s, (1.0, 0.0))[1] for s in range(4)]
    attr("inputs:scale", _T.Float4).default = Gf.Vec4f(*scale)
    attr("inputs:bias", _T.Float4).default = Gf.Vec4f(*bias)
    for out in dict.fromkeys(w.output for w in node.inputs):  # declared where the source does not
        if not (prim is not None and prim.GetAttribute(f"outputs:{out}")):
            Sdf.AttributeSpec(spec, f"outputs:{out}", _T.Float3 if out == "rgb" else _T.Float)


def _note(cm: ClassicMaterial, nodes: Sequence[_Node]) -> str:
    files = sorted({n.file.rsplit("/", 1)[-1] for n in nodes})
    parts = ["neural (bcf context)"] if cm.neural else []
    if nodes:
        parts.append(f"{len(nodes)} UsdUVTexture → {', '.join(files)}")
    every = [why for n, why in cm.kept if n == ALL]
    if every:
        parts.append(f"universal context on its sources ({'; '.join(every)})")
    if len(every) < len(cm.kept):
        parts.append("kept on sources: " + ", ".join(f"{n} ({why})" for n, why in cm.kept if n != ALL))
    if not nodes and not cm.neural:
        parts.insert(0, UNTOUCHED.removeprefix("USD: "))
    return "USD: " + "; ".join(parts)


def author_classic(layer: Sdf.Layer, stage: Usd.Stage, materials: Iterable[ClassicMaterial]) -> None:
    """Author every material's UsdUVTexture overrides and new nodes, the re-pointed surface inputs,
    and a note on the material (customData ``bcfpipeUsd``) that the build table reads back."""
    for cm in materials:
        nodes = _nodes(stage, cm)
        for node in nodes:
            _author_node(layer, stage, node)
            surface = Sdf.CreatePrimInLayer(layer, Sdf.Path(cm.surface))
            for w in node.inputs:
                attr = Sdf.AttributeSpec(surface, f"inputs:{w.input}", Sdf.ValueTypeNames.Find(w.type_name))
                attr.connectionPathList.explicitItems = [Sdf.Path(f"{node.path}.outputs:{w.output}")]
        Sdf.CreatePrimInLayer(layer, Sdf.Path(cm.material)).customData[NOTE_KEY] = _note(cm, nodes)


UNTOUCHED = "USD: untouched sources"


def usd_notes(overrides_layer: str) -> dict[str, str] | None:
    """What the overrides layer did per material path: its ``bcfpipeUsd`` note, else "USD: neural
    (bcf context)" for a material with the BcfNeuralMaterialAPI; read back from the layer itself
    (a built material it does not name kept its sources: `UNTOUCHED`). None when it cannot be read."""
    if not os.path.isfile(str(overrides_layer)):
        return None
    layer = Sdf.Layer.FindOrOpen(str(overrides_layer))
    out: dict[str, str] = {}
    if layer is None:
        return None

    def visit(path: Sdf.Path) -> None:
        spec = layer.GetPrimAtPath(path)
        if spec is None:
            return
        note = spec.customData.get(NOTE_KEY)
        if note:
            out[str(path)] = str(note)
        elif "apiSchemas" in spec.ListInfoKeys() and "BcfNeuralMaterialAPI" in \
                spec.GetInfo("apiSchemas").GetAddedOrExplicitItems():
            out[str(path)] = "USD: neural (bcf context)"

    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: visit(p) if p.IsPrimPath() else None)
    return out
