"""One call from a USD file to rendered frames: open the stage, read its meshes and the view,
read each bound material's surface, draw (neural and/or original), read back. The neural (built)
frame reads the stage as built; the original frame reads its source (`source_stage`)."""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
from pxr import Sdf, Usd

from bcfpipe.errors import InputError
from bcfpipe.render.raster import Lighting, Renderer
from bcfpipe.render.scene import Batch, View, framing_view, read_batches, usd_camera_view
from bcfpipe.render.surfaces import Surface, read_surface
from bcfpipe.scan.composition import captured_diagnostics, composition_errors, new_diagnostics, open_stage
from bcfpipe.verify.glsl import open_runtime

__all__ = ["Frame", "Scene", "load_scene", "render_frames", "NEURAL", "ORIGINAL"]

NEURAL, ORIGINAL = "neural", "original"


@dataclass
class Scene:
    """What a frame needs from the stage: batches, the view, and per kind each material's surface."""

    path: str
    batches: list[Batch]
    view: View
    surfaces: dict[str, dict[str | None, Surface]] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)  # gprims not drawn
    diagnostics: list[str] = field(default_factory=list)  # USD's composition errors and warnings

    def surface(self, kind: str, batch: Batch) -> Surface:
        return self.surfaces[kind][batch.material]

    @property
    def triangles(self) -> int:
        return sum(b.triangles for b in self.batches)

    def neural_materials(self) -> list[str]:
        return sorted(m for m, s in self.surfaces.get(NEURAL, {}).items() if s.kind == NEURAL and m)

    def notes(self, kind: str) -> list[str]:
        return self.diagnostics + self.skipped + [f"{m}: {n}" for m, s in sorted(self.surfaces[kind].items(), key=lambda x: x[0] or "")
                               for n in s.notes]


@dataclass
class Frame:
    kind: str
    image: np.ndarray  # (height, width, 4) float32: linear rgb, coverage; row 0 at the top


def load_scene(path: str | os.PathLike, width: int, height: int, camera: str | None = None,
               zoom: float = 1.0, kinds: tuple[str, ...] = (NEURAL,)) -> Scene:
    """The stage at ``path`` read for a ``width`` x ``height`` frame; USD's warnings become notes."""
    with captured_diagnostics() as found:
        stage = open_stage(path)
        batches, skipped = read_batches(stage)
        if not batches:
            raise InputError(f"{path}: no visible mesh to render")
        aspect = width / height
        if camera:
            view = usd_camera_view(stage, camera, aspect)
        else:
            view = framing_view(stage, batches, aspect, zoom)
        colours = {b.material: b.display_color for b in batches}
        source = source_stage(stage) if ORIGINAL in kinds else stage
        surfaces = {kind: {m: read_surface(stage if kind == NEURAL else source, m, kind == NEURAL, c)
                           for m, c in colours.items()} for kind in kinds}
    errors = composition_errors(stage)
    return Scene(str(path), batches, view, surfaces, skipped, [*errors, *new_diagnostics(found, errors)])


OVERRIDES_LAYER = "overrides.usda"  # bcfpipe.builder.plan.OVERRIDES: a build's root layer sublayers it first


def source_stage(stage: Usd.Stage) -> Usd.Stage:
    """What a build was made from: the layers its root layer sublayers after ``overrides.usda``,
    composed with only the overrides layer's variant selections (the variant that was modelled).
    Any other stage is its own source. The original frame draws this, so that it shows the input
    scene whatever the build changed (the bcf context, constant inputs, the UsdUVTexture nodes of a
    layout's classic textures)."""
    root = stage.GetRootLayer()
    subs = list(root.subLayerPaths)
    if len(subs) < 2 or subs[0].replace("\\", "/").rsplit("/", 1)[-1] != OVERRIDES_LAYER:
        return stage
    overrides = Sdf.Layer.FindOrOpenRelativeToLayer(root, subs[0])
    session = Sdf.Layer.CreateAnonymous("bcfpipe-variants.usda")
    if overrides is not None:
        def copy(path: Sdf.Path) -> None:
            spec = overrides.GetPrimAtPath(path) if path.IsPrimPath() else None
            if spec is not None and spec.variantSelections:
                dst = Sdf.CreatePrimInLayer(session, path)
                for vset, value in spec.variantSelections.items():
                    dst.variantSelections[vset] = value

        overrides.Traverse(Sdf.Path.absoluteRootPath, copy)
    src_root = Sdf.Layer.CreateAnonymous("bcfpipe-source.usda")
    src_root.subLayerPaths = [root.ComputeAbsolutePath(p) for p in subs[1:]]
    return Usd.Stage.Open(src_root, session, Usd.Stage.LoadAll)


def renderer_for(runtime, scene: Scene, kind: str, width: int, height: int,
                 lighting: Lighting = Lighting()) -> Renderer:
    r = Renderer(runtime, width, height, lighting)
    try:
        for b in scene.batches:
            r.add(b, scene.surface(kind, b))
    except BaseException:
        r.release()
        raise
    return r


def render_frames(scene: Scene, width: int, height: int, runtime=None,
                  lighting: Lighting = Lighting()) -> dict[str, Frame]:
    """Render ``scene`` once per kind it holds surfaces for."""
    rt = runtime or open_runtime()
    try:
        frames = {}
        for kind in scene.surfaces:
            r = renderer_for(rt, scene, kind, width, height, lighting)
            try:
                frames[kind] = Frame(kind, r.render(scene.view))
            finally:
                r.release()
        return frames
    finally:
        if runtime is None:
            rt.release()
