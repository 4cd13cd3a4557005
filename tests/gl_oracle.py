"""Test utility: decode BC6H and BC7 blocks with the OpenGL driver (Mesa llvmpipe through EGL).

BC6H blocks are uploaded with glCompressedTexImage2D as
GL_COMPRESSED_RGB_BPTC_{UNSIGNED,SIGNED}_FLOAT and read back with
glGetTexImage(GL_RGB, GL_HALF_FLOAT); BC7 blocks as GL_COMPRESSED_RGBA_BPTC_UNORM, read back
with glGetTexImage(GL_RGBA, GL_UNSIGNED_BYTE). So the driver's own BPTC decoder is the
oracle.  Any failure to get a context skips the calling test.
"""
from __future__ import annotations

import ctypes
import os
from typing import Sequence

import numpy as np
import pytest

GL_COMPRESSED_RGB_BPTC_SIGNED_FLOAT = 0x8E8E
GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT = 0x8E8F
GL_COMPRESSED_RGBA_BPTC_UNORM = 0x8E8C

_STATE: dict = {}


def _gl():
    """Return (moderngl context, OpenGL.GL module), creating them once; pytest.skip if unavailable."""
    if "error" in _STATE:
        pytest.skip(_STATE["error"])
    if "gl" in _STATE:
        return _STATE["ctx"], _STATE["gl"]
    try:
        import moderngl
    except ImportError as e:
        _STATE["error"] = f"moderngl is not installed ({e})"
        pytest.skip(_STATE["error"])
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=420)
    except Exception as e:  # noqa: BLE001 - any EGL/driver failure means "no GL here"
        _STATE["error"] = f"no OpenGL >= 4.2 context through EGL: {type(e).__name__}: {e}"
        pytest.skip(_STATE["error"])
    if os.environ.get("PYOPENGL_PLATFORM", "egl") != "egl":
        _STATE["error"] = f"PYOPENGL_PLATFORM={os.environ['PYOPENGL_PLATFORM']!r}; the GL oracle needs 'egl'"
        pytest.skip(_STATE["error"])
    os.environ["PYOPENGL_PLATFORM"] = "egl"
    try:
        from OpenGL import GL
        from OpenGL.raw.GL.VERSION.GL_1_1 import glGetTexImage as raw_get_tex_image
        from OpenGL.raw.GL.VERSION.GL_1_3 import glCompressedTexImage2D as raw_compressed_tex_image_2d
    except Exception as e:  # noqa: BLE001
        _STATE["error"] = f"PyOpenGL (EGL platform) unavailable: {type(e).__name__}: {e}"
        pytest.skip(_STATE["error"])
    _STATE.update(ctx=ctx, gl=GL, info=dict(ctx.info),
                  upload=raw_compressed_tex_image_2d, get=raw_get_tex_image)
    return ctx, GL


def renderer() -> str:
    """GL_RENDERER / GL_VERSION of the oracle context (for reports)."""
    _gl()
    info = _STATE["info"]
    return f"{info.get('GL_RENDERER')} | {info.get('GL_VERSION')}"


def _upload_and_read(levels: Sequence[tuple[np.ndarray, int, int]], signed: bool, bc7: bool = False) -> list[np.ndarray]:
    _, GL = _gl()
    fmt = GL_COMPRESSED_RGBA_BPTC_UNORM if bc7 else (
        GL_COMPRESSED_RGB_BPTC_SIGNED_FLOAT if signed else GL_COMPRESSED_RGB_BPTC_UNSIGNED_FLOAT)
    read_fmt, read_type, channels, dtype = ((GL.GL_RGBA, GL.GL_UNSIGNED_BYTE, 4, np.uint8) if bc7 else
                                            (GL.GL_RGB, GL.GL_HALF_FLOAT, 3, np.float16))
    tex = GL.glGenTextures(1)
    try:
        GL.glBindTexture(GL.GL_TEXTURE_2D, tex)
        GL.glPixelStorei(GL.GL_UNPACK_ALIGNMENT, 1)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_BASE_LEVEL, 0)
        GL.glTexParameteri(GL.GL_TEXTURE_2D, GL.GL_TEXTURE_MAX_LEVEL, len(levels) - 1)
        for lvl, (blocks, w, h) in enumerate(levels):
            data = np.ascontiguousarray(blocks, dtype=np.uint8)
            need = ((w + 3) // 4) * ((h + 3) // 4)
            if data.shape != (need, 16):
                raise ValueError(f"level {lvl}: {w}x{h} needs ({need}, 16) blocks, got {data.shape}")
            _STATE["upload"](GL.GL_TEXTURE_2D, lvl, fmt, w, h, 0, data.nbytes,
                                      data.ctypes.data_as(ctypes.c_void_p))
            err = GL.glGetError()
            if err != GL.GL_NO_ERROR:
                raise RuntimeError(f"glCompressedTexImage2D(level {lvl}, {w}x{h}) failed: GL error 0x{err:04X}")
        out = []
        for lvl, (_, w, h) in enumerate(levels):
            buf = np.zeros((h, w, channels), dtype=dtype)
            _STATE["get"](GL.GL_TEXTURE_2D, lvl, read_fmt, read_type,
                             buf.ctypes.data_as(ctypes.c_void_p))
            err = GL.glGetError()
            if err != GL.GL_NO_ERROR:
                raise RuntimeError(f"glGetTexImage(level {lvl}) failed: GL error 0x{err:04X}")
            out.append(buf)
        return out
    finally:
        GL.glDeleteTextures([tex])


def gl_decode_bc6h(blocks: np.ndarray, width: int, height: int, signed: bool) -> np.ndarray:
    """Decode one BC6H image (row-major blocks) with the GL driver -> float16 (height, width, 3)."""
    return _upload_and_read([(blocks, width, height)], signed)[0]


def gl_decode_bc6h_mips(levels: Sequence[tuple[np.ndarray, int, int]], signed: bool) -> list[np.ndarray]:
    """Upload ``[(blocks, w, h), ...]`` as one texture's mip chain (level 0 first) and read every level back."""
    return _upload_and_read(list(levels), signed)


def gl_decode_blocks(blocks: np.ndarray, signed: bool, blocks_per_row: int = 256) -> np.ndarray:
    """Decode any number of blocks through GL as one tall texture -> uint16 half bits (n, 16, 3).

    Pads the last block row with zero blocks; texel order within each block is row-major.
    """
    n = blocks.shape[0]
    bw = min(blocks_per_row, max(n, 1))
    bh = -(-n // bw)
    padded = np.zeros((bw * bh, 16), dtype=np.uint8)
    padded[:n] = blocks
    img = gl_decode_bc6h(padded, bw * 4, bh * 4, signed).view(np.uint16)
    per_block = img.reshape(bh, 4, bw, 4, 3).transpose(0, 2, 1, 3, 4).reshape(bw * bh, 16, 3)
    return per_block[:n]


def gl_decode_bc7_mips(levels: Sequence[tuple[np.ndarray, int, int]]) -> list[np.ndarray]:
    """Upload ``[(blocks, w, h), ...]`` as one BC7 texture's mip chain and read every level back as
    uint8 (h, w, 4)."""
    return _upload_and_read(list(levels), False, bc7=True)


def gl_decode_bc7_blocks(blocks: np.ndarray, blocks_per_row: int = 256) -> np.ndarray:
    """Decode any number of BC7 blocks through GL as one tall texture -> uint8 (n, 16, 4)."""
    n = blocks.shape[0]
    bw = min(blocks_per_row, max(n, 1))
    bh = -(-n // bw)
    padded = np.zeros((bw * bh, 16), dtype=np.uint8)
    padded[:n] = blocks
    padded[n:, 0] = 0x40  # mode-6 padding
    img = gl_decode_bc7_mips([(padded, bw * 4, bh * 4)])[0]
    return img.reshape(bh, 4, bw, 4, 4).transpose(0, 2, 1, 3, 4).reshape(bw * bh, 16, 4)[:n]
