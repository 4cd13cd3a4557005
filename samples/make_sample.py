"""Generate the project's own sample scene: samples/sample_scene.usda and samples/textures/*.png.

    python samples/make_sample.py            # rewrites the committed files (deterministic)

Everything is procedural (numpy, fixed seeds), so the committed files can be regenerated
byte for byte with the same numpy / OpenImageIO / usd-core versions. The scene exercises what
`bcfpipe build` must handle:

  Bricks     albedo (sRGB) + normal (raw, scale 2 / bias -1) + roughness + displacement, 512²;
             bound to three wall meshes (one material shared by several meshes)
  Tiles      albedo + normal + a packed ORM texture (occlusion .r, roughness .g, metallic .b), 512²
  TilesWorn  the same texture set as Tiles with a different constant (clearcoat): trained once
  Leaves     RGBA albedo with opacity from .a and a constant opacityThreshold (a cut-out), 256²
  Plastic    constants only: not modelled
  Unused     textured but bound to nothing: modelled only with --all-materials
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SCENE = "sample_scene.usda"
TEX = "textures"


# ---------------------------------------------------------------------------------------------
# procedural textures


def value_noise(n: int, cells: int, seed: int) -> np.ndarray:
    """Smooth tileable value noise in [0, 1], (n, n)."""
    rng = np.random.default_rng(seed)
    grid = rng.random((cells, cells))
    t = np.arange(n) * cells / n
    i0 = np.floor(t).astype(int)
    f = t - i0
    f = f * f * (3 - 2 * f)
    i1 = (i0 + 1) % cells
    a = grid[i0][:, i0] * (1 - f)[None, :] + grid[i0][:, i1] * f[None, :]
    b = grid[i1][:, i0] * (1 - f)[None, :] + grid[i1][:, i1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def fbm(n: int, seed: int, octaves: int = 4, base: int = 4) -> np.ndarray:
    out, amp, total = np.zeros((n, n)), 1.0, 0.0
    for o in range(octaves):
        out += amp * value_noise(n, base << o, seed + o)
        total += amp
        amp *= 0.5
    return out / total


def normal_map(height: np.ndarray, strength: float) -> np.ndarray:
    """Tangent-space normals of a tileable height field, encoded (n + 1) / 2."""
    dx = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) * 0.5 * strength
    dy = (np.roll(height, -1, 0) - np.roll(height, 1, 0)) * 0.5 * strength
    nrm = np.stack([-dx, dy, np.ones_like(height)], -1)  # +y up in uv space (v = 1 - row)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    return nrm * 0.5 + 0.5


def bricks(n: int) -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:n, 0:n] / n
    rows = 8
    row = np.floor(y * rows)
    xo = x * 4 + 0.5 * (row % 2)
    bx, by = xo % 1.0, (y * rows) % 1.0
    mortar_w = 0.06
    edge = np.minimum(np.minimum(bx, 1 - bx) * 4 / rows * 2, np.minimum(by, 1 - by))
    brick = np.clip((edge - mortar_w * 0.5) / 0.04, 0, 1)  # 0 in mortar, 1 on bricks
    brick_id = (np.floor(xo) % 4) * 8 + row
    tint = (np.sin(brick_id * 12.9898) * 43758.5453) % 1.0
    grain = fbm(n, 11, 4, 8)
    base = np.stack([0.55 + 0.15 * tint, 0.23 + 0.06 * tint, 0.17 + 0.04 * tint], -1)
    mortar = np.array([0.62, 0.60, 0.56])
    albedo = base * (0.8 + 0.35 * grain[..., None])
    albedo = albedo * brick[..., None] + mortar * (1 - brick[..., None]) * (0.85 + 0.2 * grain[..., None])
    height = 0.75 * brick + 0.25 * grain * brick
    return {
        "bricks_albedo": np.clip(albedo, 0, 1),
        "bricks_normal": normal_map(height, 6.0),
        "bricks_roughness": np.clip(0.55 + 0.35 * (1 - brick) + 0.15 * (grain - 0.5), 0, 1),
        "bricks_height": np.clip(height, 0, 1),
    }


def tiles(n: int) -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:n, 0:n] / n
    k = 4
    tx, ty = (x * k) % 1.0, (y * k) % 1.0
    edge = np.minimum(np.minimum(tx, 1 - tx), np.minimum(ty, 1 - ty))
    tile = np.clip((edge - 0.025) / 0.02, 0, 1)
    checker = (np.floor(x * k) + np.floor(y * k)) % 2
    wear = fbm(n, 23, 4, 4)
    c0, c1 = np.array([0.82, 0.80, 0.74]), np.array([0.18, 0.30, 0.42])
    albedo = np.where(checker[..., None] > 0, c1, c0) * (0.9 + 0.15 * wear[..., None])
    grout = np.array([0.35, 0.34, 0.32])
    albedo = albedo * tile[..., None] + grout * (1 - tile[..., None])
    occlusion = 0.55 + 0.45 * tile
    roughness = np.clip(0.2 + 0.5 * wear * tile + 0.7 * (1 - tile), 0, 1)
    metallic = np.clip(checker * tile * (wear > 0.55), 0, 1) * 0.9
    return {
        "tiles_albedo": np.clip(albedo, 0, 1),
        "tiles_normal": normal_map(0.4 * tile + 0.05 * wear, 5.0),
        "tiles_orm": np.stack([occlusion, roughness, metallic], -1),
    }


def leaves(n: int) -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:n, 0:n] / n
    rng = np.random.default_rng(5)
    alpha = np.zeros((n, n))
    colour = np.zeros((n, n, 3))
    for _ in range(14):
        cx, cy, r, ang = rng.random(), rng.random(), 0.12 + 0.1 * rng.random(), rng.random() * np.pi
        dx, dy = (x - cx + 0.5) % 1.0 - 0.5, (y - cy + 0.5) % 1.0 - 0.5
        u = dx * np.cos(ang) + dy * np.sin(ang)
        v = -dx * np.sin(ang) + dy * np.cos(ang)
        leaf = np.clip(1 - (u / r) ** 2 - (v / (0.4 * r)) ** 2, 0, 1)
        m = np.clip(leaf * 8, 0, 1)
        hue = rng.random()
        c = np.array([0.20 + 0.25 * hue, 0.45 + 0.2 * (1 - hue), 0.12])
        vein = 1 - 0.35 * np.exp(-(v / (0.03 * r)) ** 2) * (leaf > 0)
        colour = colour * (1 - m[..., None]) + (c * vein[..., None]) * m[..., None]
        alpha = np.maximum(alpha, m)
    colour += (1 - alpha[..., None]) * np.array([0.25, 0.35, 0.15])
    return {"leaves_albedo": np.concatenate([np.clip(colour, 0, 1), alpha[..., None]], -1)}


def panel(n: int) -> dict[str, np.ndarray]:
    y, x = np.mgrid[0:n, 0:n] / n
    stripes = 0.5 + 0.5 * np.sin((x + 0.3 * y) * 2 * np.pi * 6)
    c = np.stack([0.3 + 0.5 * stripes, 0.3 + 0.2 * stripes, 0.6 - 0.3 * stripes], -1)
    return {"panel_albedo": c}


def write_png(path: Path, data: np.ndarray) -> None:
    import OpenImageIO as oiio

    a = np.ascontiguousarray(np.round(np.clip(data, 0, 1) * 255).astype(np.uint8))
    if a.ndim == 2:
        a = a[..., None]
    spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], oiio.UINT8)
    spec.attribute("png:compressionLevel", 9)
    spec.attribute("Software", "bcfpipe samples/make_sample.py")
    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), spec):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(a)
    out.close()


# ---------------------------------------------------------------------------------------------
# USD


def _box(size: tuple[float, float, float], center: tuple[float, float, float], uv_scale: float):
    """Points, counts, indices and faceVarying st of an axis-aligned box."""
    sx, sy, sz = (s / 2 for s in size)
    cx, cy, cz = center
    faces = [  # (normal axis, sign): corners in counter-clockwise order seen from outside
        [(-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)],
        [(1, -1, -1), (-1, -1, -1), (-1, 1, -1), (1, 1, -1)],
        [(1, -1, 1), (1, -1, -1), (1, 1, -1), (1, 1, 1)],
        [(-1, -1, -1), (-1, -1, 1), (-1, 1, 1), (-1, 1, -1)],
        [(-1, 1, 1), (1, 1, 1), (1, 1, -1), (-1, 1, -1)],
        [(-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)],
    ]
    points, st = [], []
    for corners in faces:
        for k, (a, b, c) in enumerate(corners):
            points.append((cx + a * sx, cy + b * sy, cz + c * sz))
            st.append(((0, 0), (1, 0), (1, 1), (0, 1))[k])
    st = [(u * uv_scale, v * uv_scale) for u, v in st]
    return points, [4] * 6, list(range(24)), st


def _quad(w: float, h: float, center, axis: str, uv_scale: float):
    cx, cy, cz = center
    if axis == "y":  # horizontal (floor)
        pts = [(cx - w / 2, cy, cz + h / 2), (cx + w / 2, cy, cz + h / 2), (cx + w / 2, cy, cz - h / 2),
               (cx - w / 2, cy, cz - h / 2)]
    else:  # vertical, facing +z
        pts = [(cx - w / 2, cy - h / 2, cz), (cx + w / 2, cy - h / 2, cz), (cx + w / 2, cy + h / 2, cz),
               (cx - w / 2, cy + h / 2, cz)]
    st = [(0, 0), (uv_scale, 0), (uv_scale, uv_scale), (0, uv_scale)]
    return pts, [4], [0, 1, 2, 3], st


def _mesh(stage, path: str, geo, material) -> None:
    from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

    points, counts, indices, st = geo
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in points]))
    mesh.CreateFaceVertexCountsAttr(counts)
    mesh.CreateFaceVertexIndicesAttr(indices)
    mesh.CreateSubdivisionSchemeAttr("none")
    lo = [min(p[i] for p in points) for i in range(3)]
    hi = [max(p[i] for p in points) for i in range(3)]
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*lo), Gf.Vec3f(*hi)]))
    pv = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
    pv.Set(Vt.Vec2fArray([Gf.Vec2f(*uv) for uv in st]))
    api = UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim())
    api.Bind(material)


class _Material:
    """Author one UsdPreviewSurface material with UsdUVTexture inputs."""

    def __init__(self, stage, path: str):
        from pxr import Sdf, UsdShade

        self.stage, self.path = stage, path
        self.material = UsdShade.Material.Define(stage, path)
        self.surface = UsdShade.Shader.Define(stage, f"{path}/PreviewSurface")
        self.surface.CreateIdAttr("UsdPreviewSurface")
        self.material.CreateSurfaceOutput().ConnectToSource(self.surface.ConnectableAPI(), "surface")
        self.reader = None
        self.textures: dict[str, object] = {}
        self.Sdf = Sdf

    def _st(self):
        from pxr import UsdShade

        if self.reader is None:
            r = UsdShade.Shader.Define(self.stage, f"{self.path}/StReader")
            r.CreateIdAttr("UsdPrimvarReader_float2")
            r.CreateInput("varname", self.Sdf.ValueTypeNames.String).Set("st")
            self.reader = r.CreateOutput("result", self.Sdf.ValueTypeNames.Float2)
        return self.reader

    def texture(self, name: str, file: str, color_space: str, normal: bool = False):
        from pxr import Gf, UsdShade

        if name in self.textures:
            return self.textures[name]
        T = self.Sdf.ValueTypeNames
        tex = UsdShade.Shader.Define(self.stage, f"{self.path}/{name}")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", T.Asset).Set(file)
        tex.CreateInput("st", T.Float2).ConnectToSource(self._st())
        tex.CreateInput("sourceColorSpace", T.Token).Set(color_space)
        tex.CreateInput("wrapS", T.Token).Set("repeat")
        tex.CreateInput("wrapT", T.Token).Set("repeat")
        if normal:
            tex.CreateInput("scale", T.Float4).Set(Gf.Vec4f(2, 2, 2, 1))
            tex.CreateInput("bias", T.Float4).Set(Gf.Vec4f(-1, -1, -1, 0))
        self.textures[name] = tex
        return tex

    def connect(self, input_name: str, tex, output: str) -> None:
        T = self.Sdf.ValueTypeNames
        in_type = {"diffuseColor": T.Color3f, "emissiveColor": T.Color3f, "normal": T.Normal3f}.get(input_name, T.Float)
        out = tex.CreateOutput(output, T.Float3 if output == "rgb" else T.Float)
        self.surface.CreateInput(input_name, in_type).ConnectToSource(out)

    def constant(self, input_name: str, value) -> None:
        T = self.Sdf.ValueTypeNames
        in_type = T.Color3f if isinstance(value, tuple) else T.Float
        self.surface.CreateInput(input_name, in_type).Set(value)

    def displacement(self) -> None:
        self.material.CreateDisplacementOutput().ConnectToSource(self.surface.ConnectableAPI(), "displacement")


def write_scene(path: Path) -> None:
    from pxr import Kind, Sdf, Usd, UsdGeom

    layer = Sdf.Layer.CreateAnonymous(".usda")
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    Usd.ModelAPI(world.GetPrim()).SetKind(Kind.Tokens.component)
    stage.DefinePrim("/World/Looks", "Scope")
    stage.DefinePrim("/World/Geom", "Scope")
    t = f"./{TEX}"

    bricks_m = _Material(stage, "/World/Looks/Bricks")
    tx = bricks_m.texture("AlbedoTex", f"{t}/bricks_albedo.png", "sRGB")
    bricks_m.connect("diffuseColor", tx, "rgb")
    bricks_m.connect("normal", bricks_m.texture("NormalTex", f"{t}/bricks_normal.png", "raw", normal=True), "rgb")
    bricks_m.connect("roughness", bricks_m.texture("RoughnessTex", f"{t}/bricks_roughness.png", "raw"), "r")
    bricks_m.connect("displacement", bricks_m.texture("HeightTex", f"{t}/bricks_height.png", "raw"), "r")
    bricks_m.displacement()

    def tiles_material(path: str, clearcoat: float | None):
        m = _Material(stage, path)
        m.connect("diffuseColor", m.texture("AlbedoTex", f"{t}/tiles_albedo.png", "sRGB"), "rgb")
        m.connect("normal", m.texture("NormalTex", f"{t}/tiles_normal.png", "raw", normal=True), "rgb")
        orm = m.texture("OrmTex", f"{t}/tiles_orm.png", "raw")
        m.connect("occlusion", orm, "r")
        m.connect("roughness", orm, "g")
        m.connect("metallic", orm, "b")
        if clearcoat is not None:
            m.constant("clearcoat", clearcoat)
            m.constant("clearcoatRoughness", 0.1)
        return m

    tiles_m = tiles_material("/World/Looks/Tiles", None)
    worn_m = tiles_material("/World/Looks/TilesWorn", 0.6)

    leaves_m = _Material(stage, "/World/Looks/Leaves")
    lt = leaves_m.texture("AlbedoTex", f"{t}/leaves_albedo.png", "sRGB")
    leaves_m.connect("diffuseColor", lt, "rgb")
    leaves_m.connect("opacity", lt, "a")
    leaves_m.constant("opacityThreshold", 0.5)
    leaves_m.constant("roughness", 0.6)

    plastic_m = _Material(stage, "/World/Looks/Plastic")
    plastic_m.constant("diffuseColor", (0.8, 0.1, 0.08))
    plastic_m.constant("roughness", 0.3)

    unused_m = _Material(stage, "/World/Looks/Unused")
    unused_m.connect("diffuseColor", unused_m.texture("AlbedoTex", f"{t}/panel_albedo.png", "sRGB"), "rgb")
    unused_m.constant("roughness", 0.4)

    _mesh(stage, "/World/Geom/Floor", _quad(8, 8, (0, 0, 0), "y", 4), tiles_m.material)
    _mesh(stage, "/World/Geom/Rug", _quad(2, 2, (1.5, 0.01, 1.5), "y", 1), worn_m.material)
    for i, (x, z, w, d) in enumerate([(-3.8, 0, 0.4, 8), (0, -3.8, 7.2, 0.4), (3.8, 0, 0.4, 8)]):
        _mesh(stage, f"/World/Geom/Wall{'ABC'[i]}", _box((w, 2.0, d), (x, 1.0, z), 2), bricks_m.material)
    _mesh(stage, "/World/Geom/Hedge", _quad(3, 1.5, (-1, 0.75, -3.4), "z", 1), leaves_m.material)
    ball = UsdGeom.Sphere.Define(stage, "/World/Geom/Ball")
    ball.CreateRadiusAttr(0.5)
    ball.CreateExtentAttr([(-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)])
    UsdGeom.XformCommonAPI(ball).SetTranslate((0, 0.5, 0))
    from pxr import UsdShade

    UsdShade.MaterialBindingAPI.Apply(ball.GetPrim()).Bind(plastic_m.material)
    layer.comment = "bcfpipe sample scene; generated by samples/make_sample.py"
    layer.Export(str(path))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=HERE, help="folder to write into (default: samples/)")
    args = ap.parse_args()
    out: Path = args.out
    (out / TEX).mkdir(parents=True, exist_ok=True)
    textures = {**bricks(512), **tiles(512), **leaves(256), **panel(256)}
    for name, data in textures.items():
        write_png(out / TEX / f"{name}.png", data)
    write_scene(out / SCENE)
    total = sum(f.stat().st_size for f in (out / TEX).glob("*.png"))
    print(f"wrote {out / SCENE} and {len(textures)} textures ({total / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
