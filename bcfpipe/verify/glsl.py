"""Run the GLSL runtime decoder (glsl/) through OpenGL 4.5: moderngl on EGL plus raw GL entry points.

Used by ``bcfpipe verify`` and ``bcfpipe decode --backend glsl`` and by the benchmarks. The
context is headless (EGL): Mesa llvmpipe where there is no GPU, the GPU's EGL driver where there is.

- :func:`assemble` builds a stage's source: its ``#version`` line, optional ``#define`` lines, the
  library ``bcf_decode.glsl``, then the rest of the stage file (glsl/README.md).
- :class:`GLRuntime` owns the context and the compiled compute program; :meth:`GLRuntime.load`
  uploads a material (its BC6H mip chains with glCompressedTexImage2D and its weight buffer as an
  SSBO) and :meth:`GLRuntime.decode` / :meth:`GLRuntime.decode_grid` run ``bcf_decode.comp``.
"""
from __future__ import annotations

import ctypes
import functools
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from bcfpipe.formats.addressing import gl_wrap_modes, wrap_codes
from bcfpipe.formats.vocabulary import Wrap
from bcfpipe.errors import Unavailable
from bcfpipe.formats import dds
from bcfpipe.formats import material as mf
from bcfpipe import resources

GL_COMPRESSED_RGB_BPTC_SIGNED_FLOAT = 0x8E8E
GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT = 0x8E8F
GL_COMPRESSED_RGBA_BPTC_UNORM = 0x8E8C  # BC7 feature layers (--features bc7)


def gl_format(tex) -> int:
    """The GL internal format of a feature DDS (bcfpipe.formats.dds.DdsTexture), from its DXGI format."""
    if tex.is_bc7:
        return GL_COMPRESSED_RGBA_BPTC_UNORM
    return GL_COMPRESSED_RGB_BPTC_SIGNED_FLOAT if tex.signed else GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT
LOCAL_SIZE = 64  # bcf_decode.comp's local_size_x
MAX_GROUPS = 65535  # GL's guaranteed minimum of GL_MAX_COMPUTE_WORK_GROUP_COUNT[0]
LIBRARY = "bcf_decode.glsl"
DEFAULT_LAYERS = 4  # bcf_decode.glsl's BCF_N_LAYERS when undefined; a material may have 4 to 6
STAGES = {"vert": "bcf_fullscreen.vert", "frag": "bcf_fullscreen.frag", "comp": "bcf_decode.comp"}


class GLUnavailable(Unavailable):
    """No usable OpenGL 4.5 context (no EGL, no driver, missing moderngl/PyOpenGL)."""


def glsl_dir() -> Path:
    """The folder with the shader sources: the package's glsl/ (``BCFPIPE_GLSL_DIR`` overrides it)."""
    return resources.data_dir(resources.GLSL_DIR, "BCFPIPE_GLSL_DIR", LIBRARY)


def read_source(name: str) -> str:
    return (glsl_dir() / name).read_text()


def assemble(stage: str, defines: dict[str, object] | None = None, version: str | None = None,
             library: bool | None = None) -> str:
    """Full source of ``stage`` ('vert', 'frag', 'comp' or a file name in glsl/).

    The library is inserted right after the stage's ``#version`` line (not for vertex shaders
    unless asked), preceded by ``#define NAME VALUE`` lines. ``version`` replaces the version line
    (e.g. ``"320 es\\nprecision highp float;..."`` for an ES build check).
    """
    text = read_source(STAGES.get(stage, stage))
    first, _, rest = text.partition("\n")
    if not first.startswith("#version"):
        raise ValueError(f"{stage}: the first line must be the #version line")
    if version is not None:
        first = f"#version {version}"
    if library is None:
        library = not STAGES.get(stage, stage).endswith(".vert")
    parts = [first]
    parts += [f"#define {k} {v}" for k, v in (defines or {}).items()]
    if library:
        parts.append(read_source(LIBRARY))
        parts.append("#line 2")  # keep the stage's error messages at its own line numbers
    parts.append(rest)
    return "\n".join(parts)


@dataclass(frozen=True)
class MaterialDesc:
    """A material as the runtime loads it: its material.json, and where its weight record lives
    (its own weights.bin, or its record in a build's combined buffer)."""

    folder: Path
    name: str
    file: mf.MaterialFile
    weights_file: Path
    weight_offset: int

    @property
    def layer_files(self) -> list[Path]:
        return [self.folder / layer.file for layer in self.file.layers]

    def layer_textures(self):
        """Each feature layer's DDS (`dds.DdsTexture`), checked against material.json's format."""
        out = []
        for path in self.layer_files:
            tex = dds.read(path)
            if tex.signed != self.signed or tex.is_bc7 != self.bc7:
                raise ValueError(f"{path}: {tex.format_name} but material.json says "
                                 f"{'bc7' if self.bc7 else 'signed=' + str(self.signed)}")
            out.append(tex)
        return out

    @property
    def lod_biases(self) -> tuple[float, ...]:
        return self.file.lod_biases

    @property
    def defines(self) -> dict[str, int]:
        """The #defines the decoder needs for this material's feature layers: BCF_N_LAYERS when
        they are not the library's default 4 (a T_0 of several layers)."""
        n = len(self.file.layers)
        return {} if n == DEFAULT_LAYERS else {"BCF_N_LAYERS": n}

    @property
    def mip_counts(self) -> tuple[int, ...]:
        return self.file.mip_counts

    @property
    def wrap(self) -> tuple[str, str]:
        """(S, T) addressing."""
        return self.file.wrap

    @property
    def signed(self) -> bool:
        return self.file.signed

    @property
    def bc7(self) -> bool:
        return self.file.features == "bc7"

    @property
    def ref_size(self) -> tuple[int, int]:
        return self.file.reference.width, self.file.reference.height

    @property
    def normal_index(self) -> int:
        return self.file.normal_index

    @property
    def n_out(self) -> int:
        return len(self.file.kinds)

    @property
    def outputs(self) -> tuple[mf.Output, ...]:
        """The decoder's outputs (a layout's classic outputs are not the shader's)."""
        return self.file.mlp_outputs

    @property
    def c_out(self) -> int:
        return self.n_out + (1 if self.normal_index >= 0 else 0)


def read_material(folder: str | os.PathLike, weights_file: str | os.PathLike | None = None,
                  weight_offset: int | None = None, name: str | None = None) -> MaterialDesc:
    """Read ``folder/material.json``. ``weights_file``/``weight_offset`` point at a combined
    weight buffer (a build) instead of the material's own record."""
    folder = Path(folder)
    desc = mf.read(folder)
    return MaterialDesc(
        folder=folder, name=name or folder.name, file=desc,
        weights_file=Path(weights_file) if weights_file is not None else folder / desc.mlp.weights if desc.mlp else None,
        weight_offset=int(weight_offset if weight_offset is not None else desc.mlp.offset if desc.mlp else 0))


@dataclass
class GLMaterial:
    desc: MaterialDesc
    textures: list[int]
    weights: object  # moderngl.Buffer

    def defines(self, extra: dict | None = None) -> dict[str, object]:
        """The #defines this material's programs need, with ``extra``'s on top."""
        return {**self.desc.defines, **(extra or {})}

    def uniforms(self) -> dict[str, object]:
        b = self.desc.lod_biases
        return {"uWeightOffset": self.desc.weight_offset, "uLodBias": tuple(float(x) for x in b),
                "uNormalIndex": self.desc.normal_index, "uRefSize": tuple(float(x) for x in self.desc.ref_size),
                "uWrap": wrap_codes(self.desc.wrap)}


def _current(method):
    """Make the runtime's context current before a method runs (several contexts may exist in one
    process, e.g. a second GLRuntime; EGL keeps whichever was made current last). It is left
    current: moderngl's ``with ctx:`` releases it on exit, which breaks nested calls."""
    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        self.ctx.__enter__()
        return method(self, *args, **kwargs)
    return wrapper


class GLRuntime:
    """A headless OpenGL 4.5 context with the compute decoder compiled."""

    def __init__(self, require: int = 450):
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
        if os.environ["PYOPENGL_PLATFORM"] != "egl":
            raise GLUnavailable(f"PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']!r}; bcfpipe needs 'egl'")
        try:
            import moderngl  # lazy: start-up
        except ImportError as e:
            raise GLUnavailable(f"moderngl is not installed ({e}): pip install moderngl PyOpenGL") from None
        try:
            self.ctx = moderngl.create_standalone_context(backend="egl", require=require)
        except Exception as e:  # noqa: BLE001 - any EGL/driver failure means "no GL here"
            raise GLUnavailable(f"no OpenGL {require // 100}.{require % 100 // 10} context through EGL: "
                                f"{type(e).__name__}: {e}") from None
        try:
            from OpenGL import GL  # lazy: start-up
            from OpenGL.raw.GL.VERSION.GL_1_3 import glCompressedTexImage2D  # lazy: start-up
        except Exception as e:  # noqa: BLE001
            self.ctx.release()
            raise GLUnavailable(f"PyOpenGL (EGL platform) unavailable: {type(e).__name__}: {e}") from None
        self.moderngl = moderngl
        self.GL = GL
        self._upload = glCompressedTexImage2D
        self._programs: dict[tuple, object] = {}
        self._fbos: dict[tuple[int, int], object] = {}
        self.empty_buffer = self.ctx.buffer(reserve=16)

    # ------------------------------------------------------------------ info / lifetime
    @property
    def info(self) -> dict[str, str]:
        i = self.ctx.info
        return {"renderer": str(i.get("GL_RENDERER")), "version": str(i.get("GL_VERSION")),
                "vendor": str(i.get("GL_VENDOR"))}

    @property
    def is_software(self) -> bool:
        r = self.info["renderer"].lower()
        return any(k in r for k in ("llvmpipe", "softpipe", "swrast", "lavapipe"))

    def release(self) -> None:
        self.ctx.release()

    def __enter__(self) -> "GLRuntime":
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    # ------------------------------------------------------------------ programs
    @_current
    def compute_program(self, defines: dict[str, object] | None = None):
        key = ("comp", tuple(sorted((defines or {}).items())))
        if key not in self._programs:
            try:
                self._programs[key] = self.ctx.compute_shader(assemble("comp", defines))
            except Exception as e:  # noqa: BLE001
                raise RuntimeError(f"bcf_decode.comp failed to compile/link: {e}") from None
        return self._programs[key]

    @_current
    def render_program(self, defines: dict[str, object] | None = None):
        key = ("render", tuple(sorted((defines or {}).items())))
        if key not in self._programs:
            self._programs[key] = self.ctx.program(vertex_shader=assemble("vert"),
                                                   fragment_shader=assemble("frag", defines))
        return self._programs[key]

    # ------------------------------------------------------------------ textures
    @_current
    def upload_compressed(self, levels: Sequence[tuple[np.ndarray, int, int]], internal_format: int,
                          wrap=Wrap.REPEAT) -> int:
        """A new GL_TEXTURE_2D with the given compressed mip chain, trilinear filtering,
        GL_TEXTURE_MAX_LEVEL = len(levels) - 1 and ``wrap``'s addressing per axis (REPEAT,
        CLAMP_TO_EDGE, MIRRORED_REPEAT)."""
        GL = self.GL
        tex = int(GL.glGenTextures(1))
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BASE_LEVEL, 0)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, len(levels) - 1)
        for lvl, (blocks, w, h) in enumerate(levels):
            data = np.ascontiguousarray(blocks, dtype=np.uint8)
            self._upload(GL.GL_TEXTURE_2D, lvl, internal_format, w, h, 0, data.nbytes,
                         data.ctypes.data_as(ctypes.c_void_p))
            err = GL.glGetError()
            if err != GL.GL_NO_ERROR:
                GL.glDeleteTextures([tex])
                raise RuntimeError(f"glCompressedTexImage2D(level {lvl}, {w}x{h}, 0x{internal_format:04X}) "
                                   f"failed: GL error 0x{err:04X}")
        mode_s, mode_t = gl_wrap_modes(wrap, GL)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MIN_FILTER, GL.GL_LINEAR_MIPMAP_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAG_FILTER, GL.GL_LINEAR)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_S, mode_s)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_WRAP_T, mode_t)
        GL.glBindTexture(GL.GL_TEXTURE_2D, 0)
        return tex

    @_current
    def bind_textures(self, textures: Sequence[int]) -> None:
        GL = self.GL
        for unit, tex in enumerate(textures):
            GL.glActiveTexture(GL.GL_TEXTURE0 + unit)
            GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glActiveTexture(GL.GL_TEXTURE0)

    @_current
    def delete_textures(self, textures: Sequence[int]) -> None:
        if textures:
            self.GL.glDeleteTextures(list(textures))

    # ------------------------------------------------------------------ materials
    @_current
    def load(self, m: MaterialDesc, weights: bytes | None = None) -> GLMaterial:
        """Upload ``m``'s feature layers (four BC6H, or four to six BC7) and its weight buffer (``weights``
        overrides the file)."""
        textures: list[int] = []
        try:
            for tex in m.layer_textures():
                textures.append(self.upload_compressed(tex.levels, gl_format(tex), m.wrap))
        except BaseException:
            self.delete_textures(textures)
            raise
        data = weights if weights is not None else m.weights_file.read_bytes()
        data = data + b"\0" * (-len(data) % 4)
        return GLMaterial(m, textures, self.ctx.buffer(data))

    @_current
    def unload(self, gm: GLMaterial) -> None:
        self.delete_textures(gm.textures)
        gm.textures = []
        gm.weights.release()

    @_current
    def _run(self, gm: GLMaterial, count: int, queries, grid: tuple[int, int], grid_lod: float,
             stride: int, defines: dict | None, grad: bool = False) -> np.ndarray:
        prog = self.compute_program(gm.defines(defines))
        out = self.ctx.buffer(reserve=max(4, count * stride * 4))
        try:
            self.bind_textures(gm.textures)
            gm.weights.bind_to_storage_buffer(0)
            (queries or self.empty_buffer).bind_to_storage_buffer(1)
            out.bind_to_storage_buffer(2)
            values = dict(gm.uniforms(), uCount=count, uOutStride=stride, uGrid=grid, uGridLod=float(grid_lod),
                          uGradQueries=grad)
            set_uniforms(prog, values)
            groups = -(-count // LOCAL_SIZE)
            if groups > MAX_GROUPS:
                raise ValueError(f"{count} samples exceed one dispatch; decode in chunks")
            prog.run(group_x=groups)
            self.ctx.memory_barrier()
            res = np.frombuffer(out.read(), np.float32, count=count * stride).reshape(count, stride)
            self.ctx.finish()
            return res.copy()
        finally:
            out.release()

    @_current
    def decode(self, gm: GLMaterial, uv: np.ndarray, s: np.ndarray | float, chunk: int = 1 << 20,
               defines: dict | None = None) -> np.ndarray:
        """Decode at points ``uv`` (N, 2) and lods ``s`` (N,) or scalar -> (N, c_out) float32."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        n = uv.shape[0]
        s_arr = np.broadcast_to(np.asarray(s, np.float32), (n,))
        q = np.zeros((n, 4), np.float32)
        q[:, :2], q[:, 2] = uv, s_arr
        c = gm.desc.c_out
        parts = []
        for a in range(0, n, chunk):
            b = self.ctx.buffer(np.ascontiguousarray(q[a:a + chunk]).tobytes())
            try:
                parts.append(self._run(gm, min(chunk, n - a), b, (0, 0), 0.0, c, defines))
            finally:
                b.release()
        return np.concatenate(parts) if parts else np.zeros((0, c), np.float32)

    @_current
    def decode_grad(self, gm: GLMaterial, uv: np.ndarray, duvdx: np.ndarray, duvdy: np.ndarray,
                    chunk: int = 1 << 20, defines: dict | None = None) -> np.ndarray:
        """Decode at points ``uv`` (N, 2) with s from the uv derivatives (N, 2) each, through
        ``bcfDecodeGrad`` (the fragment-shader path) -> (N, c_out) float32."""
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        n = uv.shape[0]
        q = np.zeros((n, 2, 4), np.float32)
        q[:, 0, :2], q[:, 0, 2:] = uv, np.asarray(duvdx, np.float32).reshape(-1, 2)
        q[:, 1, :2] = np.asarray(duvdy, np.float32).reshape(-1, 2)
        c = gm.desc.c_out
        parts = []
        for a in range(0, n, chunk):
            b = self.ctx.buffer(np.ascontiguousarray(q[a:a + chunk]).tobytes())
            try:
                parts.append(self._run(gm, min(chunk, n - a), b, (0, 0), 0.0, c, defines, grad=True))
            finally:
                b.release()
        return np.concatenate(parts) if parts else np.zeros((0, c), np.float32)

    @_current
    def framebuffer(self, width: int, height: int):
        """A float RGBA framebuffer of this size, kept for the context's lifetime (releasing a bound
        framebuffer leaves moderngl's surfaceless context in a state where the next draw fails)."""
        key = (width, height)
        if key not in self._fbos:
            self._fbos[key] = self.ctx.simple_framebuffer((width, height), components=4, dtype="f4")
        return self._fbos[key]

    @_current
    def render_fullscreen(self, gm: GLMaterial, width: int, height: int, lod: float | None = None, view: int = 0,
                          uv_transform: tuple[float, float, float, float] = (1.0, 1.0, 0.0, 0.0),
                          defines: dict | None = None) -> np.ndarray:
        """Draw bcf_fullscreen.vert/.frag into a width x height float framebuffer and read it back
        -> (height, width, 4); row 0 is the bottom row (v = 0.5 / height with the default transform).
        ``lod`` None: s from the uv derivatives (paper sec. 5.2), else the explicit lod."""
        prog = self.render_program(gm.defines(defines))
        fbo = self.framebuffer(width, height)
        vao = self.ctx.vertex_array(prog, [])
        try:
            fbo.use()
            fbo.clear(0.0, 0.0, 0.0, 0.0)
            self.bind_textures(gm.textures)
            gm.weights.bind_to_storage_buffer(0)
            set_uniforms(prog, dict(gm.uniforms(), uLodMode=0 if lod is None else 1,
                                    uLod=0.0 if lod is None else float(lod), uView=int(view),
                                    uUvTransform=tuple(float(x) for x in uv_transform)))
            vao.render(self.moderngl.TRIANGLES, vertices=3)
            data = fbo.read(components=4, dtype="f4")
            return np.frombuffer(data, np.float32).reshape(height, width, 4).copy()
        finally:
            vao.release()

    @_current
    def decode_grid(self, gm: GLMaterial, width: int, height: int, lod: float,
                    defines: dict | None = None) -> np.ndarray:
        """Decode the texel centres of a width x height grid at lod ``lod`` -> (height, width, c_out);
        row 0 is v = 0.5 / height (the first stored row)."""
        c = gm.desc.c_out
        rows_per = max(1, (MAX_GROUPS * LOCAL_SIZE) // width)
        if rows_per >= height:
            return self._run(gm, width * height, None, (width, height), lod, c, defines).reshape(height, width, c)
        # tall grids: decode in bands through the query path (same texel-centre uvs)
        ys = (np.arange(height, dtype=np.float64) + 0.5) / height
        xs = (np.arange(width, dtype=np.float64) + 0.5) / width
        out = np.empty((height, width, c), np.float32)
        for y0 in range(0, height, rows_per):
            yy, xx = np.meshgrid(ys[y0:y0 + rows_per], xs, indexing="ij")
            uv = np.stack([xx.ravel(), yy.ravel()], 1)
            out[y0:y0 + yy.shape[0]] = self.decode(gm, uv, lod, defines=defines).reshape(yy.shape[0], width, c)
        return out


def set_uniforms(prog, values: dict[str, object]) -> None:
    """Set the uniforms the program uses (the compiler drops unused ones)."""
    for k, v in values.items():
        try:
            u = prog[k]
        except KeyError:
            continue
        u.value = v


def open_runtime() -> GLRuntime:
    """A :class:`GLRuntime`, or :class:`GLUnavailable` with a one-line reason."""
    return GLRuntime()
