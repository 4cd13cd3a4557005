"""Decode cost of a neural material against classic BC textures: the paper's Table 3 protocol.

Two full-screen passes draw into the same RGBA8 framebuffer: one decodes the neural material per
pixel (glsl/bcf_fullscreen.frag: its four to six feature layers, lod from the uv derivatives, the MLP
from the weight SSBO), the other samples the material's classic BC textures (trilinear, full mip chains)
and writes three of their channels. The uv transform tiles the material so that one reference
texel covers about one pixel (s ~ 0). Frames of the two passes alternate, so that the load of a
shared machine falls on both alike; each time is the median over the frames.

On a GPU each draw is timed with a GL timer query (GL_TIME_ELAPSED). On a software renderer
(Mesa llvmpipe) a timer query misses the rasterizer threads, so each draw is timed as draw +
glFinish on the CPU clock, and only the ratio means anything.

:func:`measure_compute` times the same two decodes as compute dispatches over a W x H grid
(glsl/bcf_decode.comp at lod 0 against ``textureLod`` of the classic set), each writing three
float channels per sample: on parts whose fragment stage is weak (a data-centre GPU) it separates
the decoder's own cost from the rasterizer's.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from bcfpipe.verify import glsl as G

__all__ = ["DecodeCost", "measure", "measure_compute", "upload_classic", "random_classic", "classic_frag",
           "classic_comp", "FORMATS", "SIZES"]

GL_COMPRESSED_RGB_S3TC_DXT1_EXT = 0x83F0
GL_COMPRESSED_RED_RGTC1 = 0x8DBB
GL_COMPRESSED_RG_RGTC2 = 0x8DBD
GL_COMPRESSED_RGBA_BPTC_UNORM = 0x8E8C
GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT = 0x8E8F  # BC6H_UF16: an HDR colour group's baseline
# baseline format -> (GL internal format, bytes per block, name)
FORMATS = {"bc1": (GL_COMPRESSED_RGB_S3TC_DXT1_EXT, 8, "BC1"), "bc4": (GL_COMPRESSED_RED_RGTC1, 8, "BC4"),
           "bc5": (GL_COMPRESSED_RG_RGTC2, 16, "BC5"), "bc6h": (GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT, 16, "BC6H"),
           "bc7": (GL_COMPRESSED_RGBA_BPTC_UNORM, 16, "BC7")}
SIZES = {"1080p": (1920, 1080), "1440p": (2560, 1440), "2160p": (3840, 2160)}


@dataclass(frozen=True)
class DecodeCost:
    """One side-by-side measurement; times in ms (absolute only when ``software`` is False)."""

    width: int
    height: int
    frames: int
    neural_ms: float
    classic_ms: float
    timer: str  # "GL_TIME_ELAPSED" or "draw+glFinish wall clock"
    software: bool
    stage: str = "fragment"  # "fragment" (full-screen draw) or "compute" (grid dispatch)

    @property
    def ratio(self) -> float:
        return self.neural_ms / self.classic_ms

    def to_json(self) -> dict:
        return dict(asdict(self), ratio=self.ratio)


def classic_frag(n: int) -> str:
    """The classic pass: sample each of ``n`` textures (trilinear, implicit derivatives) and write
    three of their channels, as bcf_fullscreen.frag writes three of the decoded ones."""
    decl = "\n".join(f"layout(binding = {k}) uniform sampler2D tex{k};" for k in range(n))
    fetch = "\n".join(f"    t = texture(tex{k}, vUv); ch[{4 * k}] = t.r; ch[{4 * k + 1}] = t.g; "
                      f"ch[{4 * k + 2}] = t.b; ch[{4 * k + 3}] = t.a;" for k in range(n))
    return f"""#version 450 core
layout(location = 0) in vec2 vUv;
layout(location = 0) out vec4 fragColor;
{decl}
uniform int uView;
void main() {{
    float ch[{4 * n}];
    vec4 t;
{fetch}
    int last = {4 * n - 1};
    fragColor = vec4(ch[clamp(uView, 0, last)], ch[clamp(uView + 1, 0, last)], ch[clamp(uView + 2, 0, last)], 1.0);
}}
"""


def classic_comp(n: int) -> str:
    """The classic pass as a compute dispatch: sample each of ``n`` textures at the grid's texel
    centres (``textureLod``, as bcf_decode.comp's grid) and write three of their channels."""
    decl = "\n".join(f"layout(binding = {k}) uniform sampler2D tex{k};" for k in range(n))
    fetch = "\n".join(f"    t = textureLod(tex{k}, uv, uGridLod); ch[{4 * k}] = t.r; ch[{4 * k + 1}] = t.g; "
                      f"ch[{4 * k + 2}] = t.b; ch[{4 * k + 3}] = t.a;" for k in range(n))
    return f"""#version 450 core
layout(local_size_x = {G.LOCAL_SIZE}) in;
{decl}
layout(std430, binding = 2) writeonly buffer ClassicOut {{ float outCh[]; }};
uniform uint uCount;
uniform uvec2 uGrid;
uniform float uGridLod;
uniform int uView;
void main() {{
    uint i = gl_GlobalInvocationID.x;
    if (i >= uCount) return;
    vec2 uv = (vec2(float(i % uGrid.x), float(i / uGrid.x)) + 0.5) / vec2(uGrid);
    float ch[{4 * n}];
    vec4 t;
{fetch}
    int last = {4 * n - 1};
    for (int k = 0; k < 3; ++k) outCh[i * 3u + uint(k)] = ch[clamp(uView + k, 0, last)];
}}
"""


def upload_classic(rt: G.GLRuntime, textures: Sequence[tuple[str, list, list]], wrap: str) -> tuple[list[int], list[str]]:
    """Upload a BC baseline's own blocks (bcfpipe.texset.baselines ``textures=``) -> (GL names, formats).

    BC1 needs GL_EXT_texture_compression_s3tc (every desktop driver and Mesa have it); without it
    a BC1 texture is replaced by random BC7 blocks of its size, which the format list says."""
    has_s3tc = "GL_EXT_texture_compression_s3tc" in rt.ctx.extensions
    names, fmts = [], []
    rng = np.random.default_rng(0)
    for fmt, _idx, levels in textures:
        if fmt == "bc1" and not has_s3tc:
            levels = [(rng.integers(0, 256, (len(b), 16), dtype=np.uint8), w, h) for b, w, h in levels]
            fmt = "bc7"
        gl_fmt, _, name = FORMATS[fmt]
        names.append(rt.upload_compressed(levels, gl_fmt, wrap))
        fmts.append(name)
    return names, fmts


def random_classic(m: G.MaterialDesc) -> list[tuple[str, list, list]]:
    """Random blocks in the formats an engine would ship ``m``'s semantics in, at its reference
    size with full mip chains (colour BC1, normal x/y BC5, scalar BC4): sampling cost does not
    depend on block contents."""
    groups: dict[str, list] = {}
    for o in m.outputs:
        if not o.reconstructed:
            groups.setdefault(o.semantic, []).append(o)
    w0, h0 = m.ref_size
    rng = np.random.default_rng(0)
    out = []
    for outs in groups.values():
        fmt = "bc5" if outs[0].kind == "normal" else "bc4" if len(outs) == 1 else "bc1"
        block = FORMATS[fmt][1]
        levels = []
        for k in range(max(w0, h0).bit_length()):
            w, h = max(1, w0 >> k), max(1, h0 >> k)
            levels.append((rng.integers(0, 256, (((w + 3) // 4) * ((h + 3) // 4), block), dtype=np.uint8), w, h))
        out.append((fmt, [], levels))
    return out


def _net(m: G.MaterialDesc) -> dict[str, int]:
    """The #defines that compile the decoder for ``m``'s network shape (and layer count)."""
    return {**m.defines, "BCF_N_HIDDEN": m.file.mlp.n_hidden, "BCF_N_OUT": m.n_out, "BCF_MAX_OUT": m.c_out}


def _medians(rt: G.GLRuntime, passes: Sequence[tuple], frames: int, warmup: int, timed) -> list[float]:
    """Each pass's median time (ms) over ``frames`` after ``warmup``, the passes interleaved per
    frame. A pass is (program, textures, uniforms, weight buffer), the last two None for the classic
    one; ``timed(k)`` runs pass k once and returns its time."""
    times: list[list[float]] = [[] for _ in passes]
    for i in range(warmup + frames):
        for k, (prog, tex, uniforms, weights) in enumerate(passes):
            if uniforms is not None:  # the programs are shared between materials of one shape
                G.set_uniforms(prog, uniforms)
                weights.bind_to_storage_buffer(0)
            rt.bind_textures(tex)
            t = timed(k)
            if i >= warmup:
                times[k].append(t)
    return [statistics.median(t) for t in times]


def _time_draw(rt: G.GLRuntime, vao, query, wall: bool) -> float:
    if wall:
        t0 = time.perf_counter()
        vao.render(rt.moderngl.TRIANGLES, vertices=3)
        rt.ctx.finish()
        return (time.perf_counter() - t0) * 1e3
    with query:
        vao.render(rt.moderngl.TRIANGLES, vertices=3)
    return query.elapsed / 1e6


def measure(rt: G.GLRuntime, materials: Sequence[G.MaterialDesc], classic: Sequence[int], size: tuple[int, int],
            frames: int = 200, warmup: int = 20) -> list[DecodeCost]:
    """Median time of each material's neural pass and of the classic pass at ``size``, all frames
    interleaved (classic, neural 1, neural 2, ... per frame) in one framebuffer."""
    w, h = size
    software = rt.is_software
    plain = rt.ctx.program(vertex_shader=G.assemble("vert"), fragment_shader=classic_frag(len(classic)))
    # never released: after a framebuffer is deleted, moderngl's next simple_framebuffer fails with
    # GL_INVALID_OPERATION (it rebinds the deleted one); one per call is a few MB
    fbo = rt.ctx.simple_framebuffer((w, h), components=4)
    query = rt.ctx.query(time=True)
    passes, loaded, vaos = [], [], []
    try:
        vaos.append(rt.ctx.vertex_array(plain, []))
        G.set_uniforms(plain, {"uView": 0, "uUvTransform": (w / materials[0].ref_size[0], h / materials[0].ref_size[1],
                                                             0.0, 0.0)})
        passes.append((plain, list(classic), None, None))
        for m in materials:
            gm = rt.load(m)
            loaded.append(gm)
            prog = rt.render_program(_net(m))
            vaos.append(rt.ctx.vertex_array(prog, []))
            uvt = (w / m.ref_size[0], h / m.ref_size[1], 0.0, 0.0)  # ~1 reference texel per pixel
            passes.append((prog, gm.textures, dict(gm.uniforms(), uLodMode=0, uLod=0.0, uView=0, uUvTransform=uvt),
                           gm.weights))
        fbo.use()
        ms = _medians(rt, passes, frames, warmup, lambda k: _time_draw(rt, vaos[k], query, software))
    finally:
        for vao in vaos:
            vao.release()
        for gm in loaded:
            rt.unload(gm)
        plain.release()
    timer = "draw+glFinish wall clock" if software else "GL_TIME_ELAPSED"
    return [DecodeCost(w, h, frames, t, ms[0], timer, software) for t in ms[1:]]


def _time_dispatch(rt: G.GLRuntime, prog, groups: int, query, wall: bool) -> float:
    if wall:
        t0 = time.perf_counter()
        prog.run(group_x=groups)
        rt.ctx.finish()
        return (time.perf_counter() - t0) * 1e3
    with query:
        prog.run(group_x=groups)
    return query.elapsed / 1e6


def measure_compute(rt: G.GLRuntime, materials: Sequence[G.MaterialDesc], classic: Sequence[int],
                    size: tuple[int, int], frames: int = 200, warmup: int = 20) -> list[DecodeCost]:
    """As :func:`measure`, with each pass a compute dispatch over a ``size`` grid at lod 0 (one
    invocation per sample, three float channels written per sample by both passes)."""
    w, h = size
    count = w * h
    groups = -(-count // G.LOCAL_SIZE)
    if groups > G.MAX_GROUPS:
        raise ValueError(f"a {w}x{h} grid exceeds one dispatch ({G.MAX_GROUPS} groups of {G.LOCAL_SIZE})")
    software = rt.is_software
    grid = {"uCount": count, "uGrid": (w, h), "uGridLod": 0.0}
    plain = rt.ctx.compute_shader(classic_comp(len(classic)))
    out = rt.ctx.buffer(reserve=count * 3 * 4)
    dummy = rt.ctx.buffer(reserve=16)
    query = rt.ctx.query(time=True)
    passes, loaded = [], []
    try:
        G.set_uniforms(plain, dict(grid, uView=0))
        passes.append((plain, list(classic), None, None))
        for m in materials:
            gm = rt.load(m)
            loaded.append(gm)
            passes.append((rt.compute_program(_net(m)), gm.textures,
                           dict(gm.uniforms(), uOutStride=3, uGradQueries=False, **grid), gm.weights))
        out.bind_to_storage_buffer(2)
        dummy.bind_to_storage_buffer(1)
        ms = _medians(rt, passes, frames, warmup, lambda k: _time_dispatch(rt, passes[k][0], groups, query, software))
    finally:
        for gm in loaded:
            rt.unload(gm)
        plain.release()
        out.release()
        dummy.release()
    timer = "dispatch+glFinish wall clock" if software else "GL_TIME_ELAPSED"
    return [DecodeCost(w, h, frames, t, ms[0], timer, software, "compute") for t in ms[1:]]
