"""Draw batches with their surfaces through OpenGL 4.5 (glsl/bcf_render.vert/.frag) into a float
framebuffer, one sample per pixel, with a depth buffer and no culling.

Resources are uploaded once per renderer: BC6H feature mip chains as stored in the DDS files,
weight buffers as shader storage, a layout's classic DDS textures with their stored mips
(bcfpipe.render.dds_texture), original texture files at their own resolution with GL's
mip generation (8-bit files as RGBA8, others as RGBA16F; colour as stored, not premultiplied by
alpha, as training reads it), trilinear, no anisotropy, so both paths filter alike. Colour
decoding (sRGB) happens after filtering in both, as in the decoder.
"""
from __future__ import annotations

import math
import tempfile
import time
from dataclasses import dataclass

import numpy as np

from bcfpipe.formats import images
from bcfpipe.formats.addressing import wrap_codes
from bcfpipe.formats.images import channel_index as source_channel_index
from bcfpipe.formats.vocabulary import ColorSpace, Wrap
from bcfpipe.errors import InputError
from bcfpipe.formats import dds
from bcfpipe.render.dds_texture import is_dds
from bcfpipe.render.dds_texture import read_dds
from bcfpipe.render.scene import Batch, View
from bcfpipe.render.surfaces import COMPONENTS, MAX_TEXTURES, MIN_LAYERS, TEXTURE_SOURCE, Surface
from bcfpipe.scan.results import Transform2d
from bcfpipe.scan.sources import local_file, read_asset, resolved_color_space
from bcfpipe.verify import glsl

__all__ = ["Lighting", "Renderer"]

_NEURAL_ST = MAX_TEXTURES


@dataclass(frozen=True)
class Lighting:
    """One directional light fixed to the camera (from above-left, behind the viewer) and an
    ambient term; radiance is linear."""

    radiance: float = 2.6
    ambient: float = 0.25
    direction: tuple[float, float, float] = (-0.45, 0.75, 0.5)  # in camera space: right, up, back


@dataclass
class _Draw:
    surface: Surface
    program: object
    vao: object
    vbo: object
    textures: list[int]
    srgb_units: tuple[bool, ...]
    weights: object | None


def _glsl_array(kind: str, values) -> str:
    if kind == "float":
        return "float[](" + ", ".join(repr(float(np.float32(v))) for v in values) + ")"
    return "int[](" + ", ".join(str(int(v)) for v in values) + ")"


def _routing_defines(surface: Surface, srgb_units: tuple[bool, ...],
                     shape: tuple[int, int] | None = None) -> dict[str, object]:
    """The #defines that compile one material's component routing (and, for a neural material
    with a valid record, its network shape (n_hidden, n_out)) into bcf_render.frag."""
    comps = surface.components
    net = {"BCF_N_HIDDEN": shape[0], "BCF_N_OUT": shape[1]} if shape else {}
    n_layers = len(surface.neural.textures) if surface.kind == "neural" and surface.neural else MIN_LAYERS
    if n_layers != MIN_LAYERS:  # the feature layers take units 0..n-1, the original's textures follow
        net["BCF_N_LAYERS"] = n_layers
    def unit(c):  # the original texture unit a component reads, or None (a constant or a decoder channel)
        if c.source < 0 or (surface.kind == "neural" and c.source < TEXTURE_SOURCE):
            return None
        return (c.source - (TEXTURE_SOURCE if surface.kind == "neural" else 0)) >> 2

    srgb = [int(c.srgb and (unit(c) is None or srgb_units[unit(c)])) for c in comps]
    split = surface.neural.split if surface.kind == "neural" and surface.neural else 0
    below = {}
    if split > 0:  # a mip split: the original network's value below it (bcf_render.frag)
        def below_unit(c):
            return None if c.below < 0 else (c.below - TEXTURE_SOURCE) >> 2

        below = {"BCF_SPLIT": split,
                 "BCF_BELOW": _glsl_array("int", [c.below for c in comps]),
                 "BCF_BELOW_SCALE": _glsl_array("float", [np.nan_to_num(c.below_scale) for c in comps]),
                 "BCF_BELOW_BIAS": _glsl_array("float", [np.nan_to_num(c.below_bias) for c in comps]),
                 "BCF_BELOW_SRGB": _glsl_array("int", [int(c.below_srgb and below_unit(c) is not None
                                                           and srgb_units[below_unit(c)]) for c in comps])}
    return {"BCF_NEURAL": int(surface.kind == "neural"),
            "BCF_SOURCE": _glsl_array("int", [c.source for c in comps]),
            "BCF_SCALE": _glsl_array("float", [np.nan_to_num(c.scale) for c in comps]),
            "BCF_BIAS": _glsl_array("float", [np.nan_to_num(c.bias) for c in comps]),
            "BCF_SRGB": _glsl_array("int", srgb),
            "BCF_TEXTURES": len(surface.textures), **net, **below}


def _st_uniform(t: Transform2d) -> tuple[tuple[float, float, float, float], tuple[float, float]]:
    """UsdTransform2d as st' = (dot(m.xy, st), dot(m.zw, st)) + offset: scale, then rotate."""
    r = math.radians(t.rotation)
    c, s = math.cos(r), math.sin(r)
    sx, sy = t.scale
    return (c * sx, -s * sy, s * sx, c * sy), tuple(t.translation)


class Renderer:
    """Renders a list of (batch, surface) pairs; one instance per frame size."""

    def __init__(self, runtime: glsl.GLRuntime, width: int, height: int, lighting: Lighting = Lighting()):
        self.rt, self.ctx, self.GL = runtime, runtime.ctx, runtime.GL
        self.width, self.height, self.lighting = width, height, lighting
        self.rt.ctx.__enter__()
        self.programs: dict[tuple, object] = {}
        self.fbo = runtime.framebuffer(width, height)
        self._features: dict[tuple, list[int]] = {}
        self._weights: dict[str, object] = {}
        self._originals: dict[tuple, tuple[int, bool]] = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="bcfpipe-render-")
        self.draws: list[_Draw] = []

    # ------------------------------------------------------------------ programs
    def program(self, surface: Surface, srgb_units: tuple[bool, ...], shape: tuple[int, int] | None = None):
        """The surface shader specialised for one material's component routing."""
        defines = _routing_defines(surface, srgb_units, shape)
        key = tuple(defines.items())
        if key not in self.programs:
            try:
                self.programs[key] = self.ctx.program(
                    vertex_shader=glsl.assemble("bcf_render.vert"),
                    fragment_shader=glsl.assemble("bcf_render.frag", defines))
            except Exception as e:  # noqa: BLE001
                raise RuntimeError(f"bcf_render shaders failed to compile: {e}") from None
        return self.programs[key]

    # ------------------------------------------------------------------ resources
    def _feature_textures(self, surface: Surface) -> list[int]:
        f = surface.neural
        key = (f.textures, f.wrap)
        if key not in self._features:
            texs = []
            for path in f.textures:
                tex = dds.parse(read_asset(path), path)
                if tex.signed != f.signed:
                    raise InputError(f"{path}: {tex.format_name} but {surface.material} says featureSigned={int(f.signed)}")
                texs.append(self.rt.upload_compressed(tex.levels, glsl.gl_format(tex), f.wrap))
            self._features[key] = texs
        return self._features[key]

    def _weight_buffer(self, path: str) -> tuple[object, bytes]:
        if path not in self._weights:
            data = read_asset(path)
            self._weights[path] = (self.ctx.buffer(data + b"\0" * (-len(data) % 4) if data else b"\0" * 4), data)
        return self._weights[path]

    def _network_shape(self, surface: Surface) -> tuple[int, int] | None:
        """(n_hidden, n_out) from the header of the material's BCFW record, None if it is not one
        (the generic decoder then rejects it and the material draws magenta)."""
        f = surface.neural
        data = self._weight_buffer(f.weights)[1]
        if f.weights_offset % 4 or f.weights_offset + 24 > len(data):
            return None
        magic, version, n_in, n_hidden, n_out, _ = np.frombuffer(data, "<u4", 6, f.weights_offset)
        if (magic, n_in) != (0x57464342, 12) or version not in (1, 2) or not (0 < n_hidden <= 64 and 0 < n_out < 16):
            return None
        c_out = int(n_out) + (1 if f.normal_index >= 0 else 0)
        bad = [c.source for c in surface.components if c_out <= c.source < TEXTURE_SOURCE]
        if bad:
            raise InputError(f"{surface.material}: bcf:outputs:channels name channel {max(bad)}, "
                             f"but its decoder has {c_out}")
        return int(n_hidden), int(n_out)

    def _original_texture(self, path: str, wrap: tuple[str, str], color_space: str) -> tuple[int, bool]:
        """(GL texture, decoded as sRGB) for a UsdUVTexture file; rgba slots as its r, g, b, a.
        Colour is read as stored (unassociated alpha), as training reads it: OpenImageIO would
        otherwise premultiply it by alpha and draw the original darker than its file."""
        key = (path, wrap, color_space)
        if key in self._originals:
            return self._originals[key]

        if is_dds(path):
            return self._dds_texture(key)

        im = images.read(local_file(path, self._tmp.name), as_float=True, unassociated_alpha=True, name=path)
        px, names = im.pixels, im.names
        rgba = np.zeros((*px.shape[:2], 4), np.float32)
        for slot, letter in enumerate("rgba"):
            try:
                rgba[..., slot] = px[..., source_channel_index(names, letter, path)]
            except InputError:
                rgba[..., slot] = 1.0 if letter == "a" else 0.0
        fmt = im.format
        srgb = resolved_color_space(color_space, px.shape[2], fmt) == ColorSpace.SRGB
        GL = self.GL
        tex = int(GL.glGenTextures(1))
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        if fmt == "uint8":
            data = np.ascontiguousarray(np.clip(np.rint(rgba * 255), 0, 255).astype(np.uint8))
            GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA8, px.shape[1], px.shape[0], 0, GL.GL_RGBA,
                            GL.GL_UNSIGNED_BYTE, data)
        else:
            data = np.ascontiguousarray(np.clip(rgba, -65504, 65504).astype(np.float16))
            GL.glTexImage2D(GL.GL_TEXTURE_2D, 0, GL.GL_RGBA16F, px.shape[1], px.shape[0], 0, GL.GL_RGBA,
                            GL.GL_HALF_FLOAT, data)
        GL.glGenerateMipmap(GL.GL_TEXTURE_2D)
        self._sampling(wrap)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        self._originals[key] = (tex, srgb)
        return tex, srgb

    def _dds_texture(self, key: tuple[str, tuple[str, str], str]) -> tuple[int, bool]:
        """A DDS (a layout's classic texture): its stored mips decoded by bcfpipe's decoders and
        uploaded as they are (RGBA8 for UNORM formats, exact; RGBA16F for BC6H), no mips generated;
        the lod clamps to the mips it has (a mip split's DDS stops at its split)."""
        path, wrap, color_space = key
        dec = read_dds(local_file(path, self._tmp.name))
        srgb = resolved_color_space(color_space, dec.channels, "uint8" if dec.unorm else "half") == ColorSpace.SRGB
        GL = self.GL
        tex = int(GL.glGenTextures(1))
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        for k, lv in enumerate(dec.levels):
            h, w = lv.shape[:2]
            if dec.unorm:
                data = np.ascontiguousarray(np.clip(np.rint(lv * 255), 0, 255).astype(np.uint8))
                GL.glTexImage2D(GL.GL_TEXTURE_2D, k, GL.GL_RGBA8, w, h, 0, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, data)
            else:
                data = np.ascontiguousarray(np.clip(lv, -65504, 65504).astype(np.float16))
                GL.glTexImage2D(GL.GL_TEXTURE_2D, k, GL.GL_RGBA16F, w, h, 0, GL.GL_RGBA, GL.GL_HALF_FLOAT, data)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BASE_LEVEL, 0)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, len(dec.levels) - 1)
        self._sampling(wrap)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        self._originals[key] = (tex, srgb)
        return tex, srgb

    def _sampling(self, wrap: tuple[str, str]) -> None:
        """Wrap modes and trilinear filtering of the bound original texture."""
        GL = self.GL
        modes = {Wrap.REPEAT: GL.GL_REPEAT, Wrap.CLAMP: GL.GL_CLAMP_TO_EDGE, "mirror": GL.GL_MIRRORED_REPEAT,
                 "black": GL.GL_CLAMP_TO_BORDER}
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, modes.get(wrap[0], GL.GL_REPEAT))
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, modes.get(wrap[1], GL.GL_REPEAT))
        GL.glTexParameterfv(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BORDER_COLOR, [0.0, 0.0, 0.0, 0.0])
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR)

    # ------------------------------------------------------------------ scene
    def add(self, batch: Batch, surface: Surface) -> None:
        """Upload one batch's vertices and its surface's textures."""
        self.rt.ctx.__enter__()
        st = batch.primvars.get(surface.st_primvar)
        if st is None:
            st = np.zeros((len(batch.positions), 2), np.float32)
        verts = np.ascontiguousarray(np.concatenate([batch.positions, batch.normals, st], axis=1), np.float32)
        shape = None
        units = [self._original_texture(t.path, t.wrap, t.color_space) for t in surface.textures]
        textures, srgb_units, weights = [u[0] for u in units], tuple(u[1] for u in units), None
        if surface.kind == "neural":  # the feature layers first, then any classic group's textures
            textures = self._feature_textures(surface) + textures
            weights = self._weight_buffer(surface.neural.weights)[0]
            shape = self._network_shape(surface)
        prog = self.program(surface, srgb_units, shape)
        vbo = self.ctx.buffer(verts.tobytes())
        vao = self.ctx.vertex_array(prog, [(vbo, "3f 3f 2f", "inPosition", "inNormal", "inSt")])
        self.draws.append(_Draw(surface, prog, vao, vbo, textures, srgb_units, weights))

    def _uniforms(self, d: _Draw, view: View) -> dict[str, object]:
        s = d.surface
        mats = [_st_uniform(Transform2d())] * (MAX_TEXTURES + 1)
        for i, t in enumerate(s.textures):
            mats[i] = _st_uniform(t.transform)
        src = s.components[COMPONENTS.index("normal.x")].source
        if s.kind == "neural":
            mats[_NEURAL_ST] = _st_uniform(s.st_transform)
            normal_st = (src - TEXTURE_SOURCE) >> 2 if src >= TEXTURE_SOURCE else _NEURAL_ST
        else:
            normal_st = src >> 2 if src >= 0 else _NEURAL_ST
        inv_view = np.linalg.inv(view.view)  # rows: camera right, up, back (row-vector convention)
        light = np.asarray(self.lighting.direction, np.float64) @ inv_view[:3, :3]
        light /= np.linalg.norm(light)
        u = {
            "uStMatrix": tuple(m for m, _ in mats), "uStOffset": tuple(o for _, o in mats), "uNormalSt": normal_st,
            "uEye": tuple(view.eye), "uLightDirection": tuple(float(x) for x in light),
            "uLightRadiance": (self.lighting.radiance,) * 3, "uAmbient": (self.lighting.ambient,) * 3,
            "uUseSpecularWorkflow": int(s.use_specular_workflow), "uOpacityThreshold": s.opacity_threshold,
        }
        if s.kind == "neural":
            f = s.neural
            u.update(uWeightOffset=f.weights_offset, uLodBias=f.lod_biases, uRefSize=tuple(float(x) for x in f.reference_size),
                     uNormalIndex=f.normal_index, uWrap=wrap_codes(f.wrap))
        return u

    # ------------------------------------------------------------------ drawing
    def draw(self, view: View) -> None:
        """Draw every batch into the framebuffer (no read-back)."""
        self.rt.ctx.__enter__()
        ctx = self.ctx
        self.fbo.use()
        self.fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        vp = (view.view @ view.projection).astype(np.float32)
        for d in self.draws:
            prog = d.program
            prog["uViewProj"].write(vp.tobytes())
            glsl.set_uniforms(prog, self._uniforms(d, view))
            self.rt.bind_textures(d.textures)
            (d.weights or self.rt.empty_buffer).bind_to_storage_buffer(0)
            d.vao.render(self.rt.moderngl.TRIANGLES)
        ctx.disable(ctx.DEPTH_TEST)

    def read(self) -> np.ndarray:
        """The framebuffer as (height, width, 4) float32, row 0 at the top, linear rgb + coverage."""
        self.rt.ctx.__enter__()
        data = self.fbo.read(components=4, dtype="f4")
        return np.frombuffer(data, np.float32).reshape(self.height, self.width, 4)[::-1].copy()

    def render(self, view: View) -> np.ndarray:
        self.draw(view)
        return self.read()

    def frame_time(self, view: View) -> tuple[float, float | None]:
        """(wall seconds of one frame up to glFinish, GPU seconds from a GL timer query or None)."""
        self.rt.ctx.__enter__()
        self.ctx.finish()
        query = None
        try:
            query = self.ctx.query(time=True)
        except Exception:  # noqa: BLE001 - no ARB_timer_query
            query = None
        t0 = time.perf_counter()
        if query is not None:
            with query:
                self.draw(view)
        else:
            self.draw(view)
        self.ctx.finish()
        wall = time.perf_counter() - t0
        gpu = query.elapsed * 1e-9 if query is not None else None
        return wall, gpu

    def release(self) -> None:
        self.rt.ctx.__enter__()
        for d in self.draws:
            d.vao.release()
            d.vbo.release()
        for p in self.programs.values():
            p.release()
        for texs in self._features.values():
            self.rt.delete_textures(texs)
        self.rt.delete_textures([t for t, _ in self._originals.values()])
        for b, _ in self._weights.values():
            b.release()
        self.draws, self._features, self._originals, self._weights, self.programs = [], {}, {}, {}, {}
        self._tmp.cleanup()
