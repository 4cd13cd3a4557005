"""Texel density from the meshes (issue #18, item 3): how many source texels per metre each
material's rendered meshes show, and what resolution a requested density needs.

For a material read through the ``st`` primvar ``varname``, over the rendered meshes bound to it
(preview purpose, GeomSubsets included, instance proxies each with their own transform):

- world area A: the faces' area after the local-to-world transform, in m² (``metersPerUnit``²);
- uv area a: the same faces' area in st space, after the texture's UsdTransform2d;
- density of a W x H source: sqrt(W H a / A) px/m. A 1024² texture over a 2 m x 1 m quad with
  uvs over [0, 1]² shows 1024 / sqrt(2) = 724 px/m.

Polygons are fan-triangulated (exact for the convex faces that meshes are made of). Meshes without
the primvar, with zero uv or world area, or with time-sampled points get a note and take no part.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import replace
from typing import TYPE_CHECKING, Iterable

import numpy as np

from bcfpipe.config import PROFILES
from bcfpipe.scan.values import numbers

if TYPE_CHECKING:
    from bcfpipe.config import JobOptions as Options
    from bcfpipe.scan.sources import SourceFile

__all__ = ["MeshDensity", "MaterialDensity", "mesh_areas", "material_density", "required_resolution"]


@dataclass(frozen=True, eq=False)
class MeshDensity:
    """One bound mesh (or GeomSubset): its world and uv areas, and its uv triangles (T, 3, 2) in
    st space after the texture's UsdTransform2d (for the coverage mask)."""

    mesh: str
    world_area_m2: float
    uv_area: float
    uv_triangles: np.ndarray | None = None


@dataclass(frozen=True)
class MaterialDensity:
    """A material's meshes and its source's texel density on them."""

    meshes: tuple[MeshDensity, ...] = ()
    notes: tuple[str, ...] = ()
    source_size: tuple[int, int] = (0, 0)

    @property
    def world_area_m2(self) -> float:
        return sum(m.world_area_m2 for m in self.meshes)

    @property
    def uv_area(self) -> float:
        return sum(m.uv_area for m in self.meshes)

    def density(self, mesh: MeshDensity | None = None) -> float | None:
        """px/m of the source over all meshes (area-weighted), or over one mesh."""
        w, h = self.source_size
        world, uv = (mesh.world_area_m2, mesh.uv_area) if mesh else (self.world_area_m2, self.uv_area)
        if world <= 0 or uv <= 0 or w * h == 0:
            return None
        return math.sqrt(w * h * uv / world)

    @property
    def lowest_density(self) -> float | None:
        """The density on the most demanding mesh: the one with the fewest source texels per metre."""
        d = [x for x in (self.density(m) for m in self.meshes) if x]
        return min(d) if d else None

    def to_dict(self) -> dict:
        return {"world_area_m2": self.world_area_m2, "uv_area": self.uv_area,
                "source_size": list(self.source_size), "texel_density": self.density(),
                "lowest_mesh_density": self.lowest_density, "meshes": len(self.meshes), "notes": list(self.notes)}


def _fan(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fan triangles of faces with ``counts`` vertices: (face, a, b, c), a..c face-vertex ordinals."""
    n_tri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), n_tri)
    first = (np.cumsum(counts) - counts)[face]
    k = np.arange(len(face)) - (np.cumsum(n_tri) - n_tri)[face]
    return face, first, first + k + 1, first + k + 2


def _area3(p: np.ndarray, a, b, c) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(p[b] - p[a], p[c] - p[a]), axis=1)


def _area2(q: np.ndarray, a, b, c) -> np.ndarray:
    u, v = q[b] - q[a], q[c] - q[a]
    return 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])


def _transform2d(st: np.ndarray, xf) -> np.ndarray:
    """UsdTransform2d: scale, then rotate (degrees, counter-clockwise), then translate."""
    if xf is None:
        return st
    r = math.radians(xf.rotation)
    rot = np.array([[math.cos(r), math.sin(r)], [-math.sin(r), math.cos(r)]])
    return (st * np.asarray(xf.scale)) @ rot + np.asarray(xf.translation)


def mesh_areas(prim, varname: str, faces: np.ndarray | None, meters_per_unit: float,
               transform=None) -> tuple[MeshDensity | None, str | None]:
    """(areas, None) of a mesh prim's faces (all, or the GeomSubset's ``faces``), or (None, note)."""
    from pxr import Usd, UsdGeom  # lazy: start-up

    mesh = UsdGeom.Mesh(prim)
    path = str(prim.GetPath())
    if not mesh:
        return None, f"{path}: not a Mesh ({prim.GetTypeName()}), no texel density"
    points_attr = mesh.GetPointsAttr()
    if points_attr.GetNumTimeSamples() > 1:
        return None, f"{path}: time-sampled points, no texel density"
    points = numbers(points_attr.Get(Usd.TimeCode.EarliestTime()), np.float64, 3)
    counts = numbers(mesh.GetFaceVertexCountsAttr().Get(), np.int64)
    fvi = numbers(mesh.GetFaceVertexIndicesAttr().Get(), np.int64)
    if len(points) == 0 or len(counts) == 0 or (counts < 0).any() or counts.sum() != len(fvi) or \
            (fvi < 0).any() or (fvi >= len(points)).any():
        return None, f"{path}: no valid faces, no texel density"
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(varname)
    if not pv or not pv.HasValue():
        return None, f"{path}: no {varname!r} primvar, no texel density"
    st = numbers(pv.ComputeFlattened(Usd.TimeCode.EarliestTime()), np.float64, 2)
    interp = pv.GetInterpolation()
    tri_face, a, b, c = _fan(counts)
    if faces is not None:
        keep = np.isin(tri_face, faces)
        a, b, c, tri_face = a[keep], b[keep], c[keep], tri_face[keep]
    if interp in ("vertex", "varying") and len(st) == len(points):
        uv_a, uv_b, uv_c = fvi[a], fvi[b], fvi[c]
    elif interp == "faceVarying" and len(st) == len(fvi):
        uv_a, uv_b, uv_c = a, b, c
    else:
        return None, f"{path}: {varname!r} is {interp} with {len(st)} values: degenerate uvs, no texel density"
    xf = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), np.float64)
    world = np.c_[points, np.ones(len(points))] @ xf
    world = world[:, :3] / world[:, 3:4] * meters_per_unit
    area = float(_area3(world, fvi[a], fvi[b], fvi[c]).sum())
    st = _transform2d(st, transform)
    uv = float(_area2(st, uv_a, uv_b, uv_c).sum())
    if area <= 0 or uv <= 0:
        return None, f"{path}: zero {'world' if area <= 0 else 'uv'} area, no texel density"
    return MeshDensity(path, area, uv, np.stack([st[uv_a], st[uv_b], st[uv_c]], 1)), None


def material_density(bindings: list[tuple[object, np.ndarray | None]], varname: str, meters_per_unit: float,
                     source_size: tuple[int, int], transform=None) -> MaterialDensity:
    """Density of one material over its bound (prim, faces) pairs (``transform``: the texture's
    UsdTransform2d, or None)."""
    meshes, notes = [], []
    for prim, faces in bindings:
        m, note = mesh_areas(prim, varname, faces, meters_per_unit, transform)
        if m is not None:
            meshes.append(m)
        if note:
            notes.append(note)
    return MaterialDensity(tuple(meshes), tuple(dict.fromkeys(notes)), source_size)


def required_resolution(md: MaterialDensity, texel_density: float) -> int | None:
    """The power-of-two size (of the source's larger side) that gives at least ``texel_density``
    px/m on the most demanding mesh; None without a density figure or when the source is needed."""
    low = md.lowest_density
    if not low:
        return None
    size = max(md.source_size)
    need = size * texel_density / low
    r = 1 << max(0, math.ceil(math.log2(max(need, 1.0))))
    return r if r < size else None


def material_bindings(stage, gprims) -> dict[str, list[tuple[object, np.ndarray | None]]]:
    """Definition path of each material -> the rendered (mesh prim, faces or None) bound to it
    (preview purpose, which falls back to all-purpose bindings; materialBind GeomSubsets first)."""
    from pxr import UsdShade  # lazy: start-up

    from bcfpipe.scan.composition import definition_path  # lazy: start-up

    out: dict[str, list] = {}
    for g in gprims:
        api = UsdShade.MaterialBindingAPI(g)
        covered: list[int] = []
        for subset in api.GetMaterialBindSubsets():
            mat, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial(UsdShade.Tokens.preview)
            idx = numbers(subset.GetIndicesAttr().Get(), np.int64)
            covered += idx.tolist()
            if mat:
                out.setdefault(definition_path(mat.GetPrim()), []).append((g, idx))
        try:
            mat, _ = api.ComputeBoundMaterial(UsdShade.Tokens.preview)
        except Exception:  # noqa: BLE001 - a malformed binding binds nothing (as in the scan)
            continue
        if mat:
            n = len(numbers(g.GetAttribute("faceVertexCounts").Get(), np.int64)) if g.GetAttribute("faceVertexCounts") else 0
            rest = None if not covered else np.setdiff1d(np.arange(n), covered)
            if rest is None or len(rest):
                out.setdefault(definition_path(mat.GetPrim()), []).append((g, rest))
    return out


def job_size(sources: Iterable[SourceFile], resolution: int | None) -> tuple[int, int]:
    """(width, height) of a texture set: its sources' common size, or, under a density cap, that
    size scaled so that its larger side is ``resolution``."""
    from bcfpipe.scan.sources import common_resolution  # lazy: start-up

    sizes = [(s.width, s.height) for s in sources]
    if not sizes or any(w < 1 or h < 1 for w, h in sizes):  # an unreadable header: training will say why
        return 0, 0
    w, h = common_resolution(sizes)
    if resolution is None:
        return w, h
    f = resolution / max(w, h)
    return max(1, int(w * f)), max(1, int(h * f))


def density_options(options: "Options", models) -> "Options":
    """The job's options under ``options.texel_density``: the largest resolution any member needs
    (no cap when a member has no density figure, or needs the source itself); the profile drops to
    what fits that resolution when it asked for more."""
    if options.texel_density is None:
        return options
    needs = [required_resolution(mm.density, options.texel_density) if mm.density else None for mm in models]
    if not needs or any(n is None for n in needs):
        return options
    res = max(needs)
    profile = options.profile
    if profile != "auto" and PROFILES[profile][0] > res:
        profile = "auto"
    return replace(options, resolution=res, profile=profile)
