"""What the reference renderer draws, read from the USD stage alone: every visible mesh as
world-space triangles grouped by bound material, and a view (a UsdGeom.Camera, or a default
that frames the scene).

Meshes: points, faceVertexCounts/Indices, normals (authored ones, else smooth normals for a
subdivision surface and flat ones for ``subdivisionScheme = "none"``; the cage is drawn, not the
limit surface), every float2 primvar (the materials pick theirs by name), the material bound for
the ``full`` purpose, per GeomSubset of the ``materialBind`` family. Spheres and cubes are
tessellated; other implicit gprims, point instancers, invisible prims and the ``guide``/``proxy``
purposes are not drawn. Values are read at the earliest time code.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdShade

from bcfpipe.errors import InputError
from bcfpipe.scan.values import number, numbers

__all__ = ["Batch", "View", "read_batches", "usd_camera_view", "framing_view"]

TIME = Usd.TimeCode.EarliestTime()


@dataclass
class Batch:
    """Triangles of one mesh that share a material: three corners per triangle, world space."""

    mesh: str
    material: str | None
    positions: np.ndarray  # (3n, 3) float32
    normals: np.ndarray  # (3n, 3) float32, unit length
    primvars: dict[str, np.ndarray] = field(default_factory=dict)  # name -> (3n, 2) float32
    display_color: tuple[float, float, float] = (0.18, 0.18, 0.18)

    @property
    def triangles(self) -> int:
        return len(self.positions) // 3


@dataclass(frozen=True)
class View:
    """A camera as matrices in USD's row-vector convention (p' = p M): world to eye, eye to clip."""

    view: np.ndarray  # (4, 4) float64
    projection: np.ndarray  # (4, 4) float64
    eye: tuple[float, float, float]
    source: str  # the camera prim, or "framing"


def _fan(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation: (face of each triangle, face-varying index of its 3 corners)."""
    counts = counts.astype(np.int64)
    starts = np.cumsum(counts) - counts
    ntri = np.maximum(counts - 2, 0)
    face = np.repeat(np.arange(len(counts)), ntri)
    k = np.arange(int(ntri.sum())) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    first = starts[face]
    return face, np.stack([first, first + k, first + k + 1], axis=1)


def _expand(values: np.ndarray, interpolation: str, face: np.ndarray, corners: np.ndarray,
            fvi: np.ndarray) -> np.ndarray | None:
    """A primvar's values at the triangle corners ((3n, ...)), None if its size does not fit."""
    idx = {
        UsdGeom.Tokens.constant: np.zeros(corners.size, np.int64),
        UsdGeom.Tokens.uniform: np.repeat(face, 3),
        UsdGeom.Tokens.faceVarying: corners.ravel(),
    }.get(interpolation)
    if idx is None:  # vertex, varying
        idx = fvi[corners.ravel()]
    if len(idx) and (idx.max() >= len(values) or idx.min() < 0):
        return None
    return values[idx]


def _normals(mesh: UsdGeom.Mesh, points: np.ndarray, fvi: np.ndarray, face: np.ndarray,
             corners: np.ndarray) -> np.ndarray:
    """Authored normals (primvars:normals first) at the corners, else computed ones."""
    pv = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    if pv and pv.HasAuthoredValue():
        values, interp = pv.ComputeFlattened(TIME), pv.GetInterpolation()
    else:
        values, interp = mesh.GetNormalsAttr().Get(TIME), mesh.GetNormalsInterpolation()
    values = numbers(values, np.float64, 3)
    if len(values):
        n = _expand(values, interp, face, corners, fvi)
        if n is not None:
            return n
    tri = points[fvi[corners]]  # (n, 3, 3)
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # area-weighted
    if mesh.GetOrientationAttr().Get(TIME) == UsdGeom.Tokens.leftHanded:
        fn = -fn
    if mesh.GetSubdivisionSchemeAttr().Get(TIME) == UsdGeom.Tokens.none:
        return np.repeat(fn, 3, axis=0)
    acc = np.zeros_like(points)
    for c in range(3):
        np.add.at(acc, fvi[corners[:, c]], fn)
    return acc[fvi[corners.ravel()]]


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 0, v / np.where(n > 0, n, 1), np.array([0.0, 0.0, 1.0]))


def _bound(prim: Usd.Prim) -> str | None:
    try:
        mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(UsdShade.Tokens.full)
    except Tf.ErrorException:  # a malformed binding binds nothing (as in the scan)
        return None
    return str(mat.GetPath()) if mat else None


def _display_color(prim: Usd.Prim) -> tuple[float, float, float]:
    dc = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    v = numbers(dc.ComputeFlattened(TIME), np.float64, 3) if dc and dc.HasValue() else ()
    return tuple(float(x) for x in v[0]) if len(v) else (0.18, 0.18, 0.18)


def _mesh_batches(prim: Usd.Prim, xf: Gf.Matrix4d) -> list[Batch]:
    mesh = UsdGeom.Mesh(prim)
    points = numbers(mesh.GetPointsAttr().Get(TIME), np.float64, 3)
    counts = numbers(mesh.GetFaceVertexCountsAttr().Get(TIME), np.int64)
    fvi = numbers(mesh.GetFaceVertexIndicesAttr().Get(TIME), np.int64)
    if not len(points) or not len(counts) or (counts < 0).any() or counts.sum() != len(fvi) or \
            (len(fvi) and (fvi.min() < 0 or fvi.max() >= len(points))):
        return []
    face, corners = _fan(counts)
    if not len(face):
        return []
    m = np.array(xf, np.float64)
    pos = points[fvi[corners.ravel()]] @ m[:3, :3] + m[3, :3]
    nrm = _unit(_normals(mesh, points, fvi, face, corners) @ np.linalg.inv(m[:3, :3]).T)
    primvars = {}
    for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
        if pv.GetTypeName().scalarType not in (Sdf.ValueTypeNames.Float2, Sdf.ValueTypeNames.TexCoord2f,
                                               Sdf.ValueTypeNames.Double2, Sdf.ValueTypeNames.TexCoord2d):
            continue
        values = numbers(pv.ComputeFlattened(TIME), np.float64, 2)
        if not len(values) or pv.GetTypeName().isArray is False:
            continue
        st = _expand(values, pv.GetInterpolation(), face, corners, fvi)
        if st is not None:
            primvars[pv.GetPrimvarName()] = st.astype(np.float32)
    color = _display_color(prim)
    # faces -> material: the mesh's own binding, then each materialBind subset's
    face_material = np.zeros(len(counts), np.int64)
    materials = [_bound(prim)]
    for subset in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets():
        ids = numbers(subset.GetIndicesAttr().Get(TIME), np.int64)
        ids = ids[(ids >= 0) & (ids < len(counts))]
        materials.append(_bound(subset.GetPrim()))
        face_material[ids] = len(materials) - 1
    batches = []
    tri_material = face_material[face]
    for i, mat in enumerate(materials):
        sel = np.flatnonzero(tri_material == i)
        if not len(sel):
            continue
        rows = (sel[:, None] * 3 + np.arange(3)).ravel()
        batches.append(Batch(str(prim.GetPath()), mat, pos[rows].astype(np.float32), nrm[rows].astype(np.float32),
                             {k: v[rows] for k, v in primvars.items()}, color))
    return _merge(batches)


def _merge(batches: list[Batch]) -> list[Batch]:
    """One batch per material of a mesh (subsets bound to the same material are drawn together)."""
    by: dict[str | None, list[Batch]] = {}
    for b in batches:
        by.setdefault(b.material, []).append(b)
    out = []
    for group in by.values():
        if len(group) == 1:
            out.append(group[0])
            continue
        names = set.intersection(*(set(b.primvars) for b in group))
        out.append(Batch(group[0].mesh, group[0].material, np.concatenate([b.positions for b in group]),
                         np.concatenate([b.normals for b in group]),
                         {k: np.concatenate([b.primvars[k] for b in group]) for k in names}, group[0].display_color))
    return out


def _sphere(radius: float, n_lon: int = 48, n_lat: int = 24) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UV sphere about the Y axis (UsdGeom.Sphere): corner positions, normals, st (s around)."""
    s = np.linspace(0.0, 1.0, n_lon + 1)
    t = np.linspace(0.0, 1.0, n_lat + 1)
    ss, tt = np.meshgrid(s, t)
    phi, theta = ss * 2 * np.pi, (tt - 0.5) * np.pi
    nrm = np.stack([np.cos(theta) * np.sin(phi), np.sin(theta), np.cos(theta) * np.cos(phi)], -1)
    i, j = np.meshgrid(np.arange(n_lat), np.arange(n_lon), indexing="ij")
    a, b = i * (n_lon + 1) + j, i * (n_lon + 1) + j + 1
    c, d = a + n_lon + 1, b + n_lon + 1
    tris = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)]).ravel()
    flat_n, flat_st = nrm.reshape(-1, 3), np.stack([ss, tt], -1).reshape(-1, 2)
    return flat_n[tris] * radius, flat_n[tris], flat_st[tris]


def _cube(size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A UsdGeom.Cube: six faces, each with st over [0, 1]^2."""
    pos, nrm, st = [], [], []
    quad_st = np.array([[0, 0], [1, 0], [1, 1], [0, 0], [1, 1], [0, 1]], np.float64)
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.roll(np.eye(3), 1, axis=0)[axis], np.roll(np.eye(3), 2, axis=0)[axis]
            if sign < 0:
                u = -u
            corners = n * 0.5 + (quad_st[:, :1] - 0.5) * u + (quad_st[:, 1:] - 0.5) * v
            pos.append(corners * size)
            nrm.append(np.repeat(n[None], 6, 0))
            st.append(quad_st)
    return np.concatenate(pos), np.concatenate(nrm), np.concatenate(st)


def _implicit_batch(prim: Usd.Prim, xf: Gf.Matrix4d) -> Batch | None:
    if prim.IsA(UsdGeom.Sphere):
        pos, nrm, st = _sphere(number(UsdGeom.Sphere(prim).GetRadiusAttr().Get(TIME), 1.0))
    elif prim.IsA(UsdGeom.Cube):
        pos, nrm, st = _cube(number(UsdGeom.Cube(prim).GetSizeAttr().Get(TIME), 2.0))
    else:
        return None
    m = np.array(xf, np.float64)
    color = _display_color(prim)
    return Batch(str(prim.GetPath()), _bound(prim), (pos @ m[:3, :3] + m[3, :3]).astype(np.float32),
                 _unit(nrm @ np.linalg.inv(m[:3, :3]).T).astype(np.float32), {"st": st.astype(np.float32)}, color)


def read_batches(stage: Usd.Stage) -> tuple[list[Batch], list[str]]:
    """Every visible, renderable mesh of ``stage`` (instance proxies included) as batches, and
    the gprims it does not draw. Spheres and cubes are tessellated (st: longitude/latitude, per face)."""
    xforms = UsdGeom.XformCache(TIME)
    out, skipped = [], []
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        if prim.IsA(UsdGeom.PointInstancer):
            skipped.append(f"{prim.GetPath()}: PointInstancer not drawn")
            it.PruneChildren()
            continue
        img = UsdGeom.Imageable(prim)
        if not img:
            continue
        if img.ComputeVisibility(TIME) == UsdGeom.Tokens.invisible or \
                img.ComputePurpose() in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
            it.PruneChildren()
            continue
        if not prim.IsA(UsdGeom.Gprim):
            continue
        try:
            xf = xforms.GetLocalToWorldTransform(prim)
        except Tf.ErrorException:
            skipped.append(f"{prim.GetPath()}: its transform cannot be read; not drawn")
            continue
        if prim.IsA(UsdGeom.Mesh):
            batches = _mesh_batches(prim, xf)
            if not batches:
                skipped.append(f"{prim.GetPath()}: no valid faces; not drawn")
            out += batches
        else:
            b = _implicit_batch(prim, xf)
            if b is None:
                skipped.append(f"{prim.GetPath()}: {prim.GetTypeName()} not drawn")
            else:
                out.append(b)
    return out, skipped


def _view_of(camera: Gf.Camera, aspect: float, source: str) -> View:
    # CameraUtilFit: grow one aperture so the window has the image's aspect and holds the original
    ha, va = camera.horizontalAperture, camera.verticalAperture
    if ha > 0 and va > 0:
        if ha / va > aspect:
            camera.verticalAperture = ha / aspect
        else:
            camera.horizontalAperture = va * aspect
    frustum = camera.frustum
    eye = frustum.GetPosition()
    return View(np.array(frustum.ComputeViewMatrix(), np.float64),
                np.array(frustum.ComputeProjectionMatrix(), np.float64), (eye[0], eye[1], eye[2]), source)


def usd_camera_view(stage: Usd.Stage, path: str, aspect: float) -> View:
    """The view of the UsdGeom.Camera at ``path``, its window fitted to ``aspect`` (width/height)."""
    prim = stage.GetPrimAtPath(path) if Sdf.Path.IsValidPathString(path) else Usd.Prim()
    if not prim or not prim.IsA(UsdGeom.Camera):
        cams = [str(p.GetPath()) for p in stage.Traverse() if p.IsA(UsdGeom.Camera)]
        hint = f"cameras in the stage: {', '.join(cams[:8])}" if cams else "the stage has no camera"
        raise InputError(f"--camera {path}: not a UsdGeom.Camera ({hint})")
    return _view_of(UsdGeom.Camera(prim).GetCamera(TIME), aspect, path)


def framing_view(stage: Usd.Stage, batches: list[Batch], aspect: float, zoom: float = 1.0,
                 fov: float = 30.0) -> View:
    """A camera that frames every batch: seen from the front-right, above, looking at the centre
    of their bounds from the nearest distance that keeps every point in view; ``zoom`` narrows
    the field of view (4 = a 4x close-up of the centre)."""
    if not batches:
        raise InputError("the stage has no visible mesh to frame")
    pts = np.concatenate([b.positions for b in batches]).astype(np.float64)
    lo, hi = pts.min(0), pts.max(0)
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    z_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    up = np.array([0.0, 0.0, 1.0]) if z_up else np.array([0.0, 1.0, 0.0])
    direction = np.array([0.55, -1.0, 0.45]) if z_up else np.array([0.55, 0.45, 1.0])
    direction /= np.linalg.norm(direction)
    half_v = math.radians(fov) / 2
    tan_v = math.tan(half_v)
    tan_h = tan_v * aspect
    # the nearest distance along `direction` at which every drawn point is in view
    right = np.cross(up, direction)
    right /= np.linalg.norm(right)
    cam_up = np.cross(direction, right)
    rel = pts - centre
    dist = float(np.max(rel @ direction + np.maximum(np.abs(rel @ right) / tan_h, np.abs(rel @ cam_up) / tan_v)))
    dist = max(dist * 1.05, radius * 1e-3)
    eye = centre + direction * dist
    look = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*centre), Gf.Vec3d(*up))
    cam = Gf.Camera(look.GetInverse())
    cam.projection = Gf.Camera.Perspective
    aperture = cam.verticalAperture
    cam.focalLength = aperture / (2 * math.tan(half_v) / max(zoom, 1e-6))
    cam.horizontalAperture = aperture * aspect
    cam.clippingRange = Gf.Range1f(max(dist - radius * 1.01, dist * 1e-3), dist + radius * 1.01)
    return _view_of(cam, aspect, "framing")
