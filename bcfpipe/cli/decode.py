"""`bcfpipe decode`: write what a neural material reconstructs as ordinary images.

One image per semantic (albedo.png, normal.png, roughness.exr, ...), at the texel centres of a
W x H grid (row 0 = v = 0.5 / H = the first stored row, like the source files) and one lod s:
  * PNG (8-bit) when every source file of that semantic was 8-bit, EXR (float) otherwise;
  * values are the model's outputs as the source files stored them (no colour conversion);
  * normals are written as a tangent-space normal map: rgb = 0.5 * (x, y, z) + 0.5, z reconstructed.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import click
import numpy as np

from bcfpipe.cli.errors import Command
from bcfpipe.errors import InputError
from bcfpipe.formats import material as mf
from bcfpipe.export import writer as E
from bcfpipe.verify.vulkan import VulkanRuntime
from bcfpipe.verify import glsl as G

if TYPE_CHECKING:
    from bcfpipe.formats.material import Output

__all__ = ["decode", "decode_material", "parse_size", "select_target", "write_images"]



def parse_size(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or int(m.group(1)) < 1 or int(m.group(2)) < 1:
        raise InputError(f"bad --size {text!r}: expected WxH, e.g. 1024x1024")
    return int(m.group(1)), int(m.group(2))


def select_target(out: str, prim: str | None):
    """The material of ``out`` named ``prim`` (a prim path, a material name or folder name)."""
    from bcfpipe.verify import checks as V  # lazy: start-up

    try:
        targets = V.find_targets(out)
    except V.VerifyInputError as e:
        raise InputError(str(e)) from None
    names = [t.desc.name for t in targets]
    if prim is None:
        if len(targets) == 1:
            return targets[0]
        raise InputError(f"{out} holds {len(targets)} materials; pick one with --material: {', '.join(names)}")

    def keys(t):
        out = {t.desc.folder.name, str(t.desc.folder)}
        for n in [t.desc.name, *t.aliases]:
            out |= {n, n.rstrip("/").rsplit("/", 1)[-1]}
        return out

    hits = [t for t in targets if prim in keys(t)]
    if len({str(t.desc.folder) for t in hits}) > 1:
        raise InputError(f"--material {prim!r} is ambiguous: {', '.join(t.desc.name for t in hits)}")
    if not hits:
        raise InputError(f"no material {prim!r} in {out}; choose from: {', '.join(names)}")
    return hits[0]


def _grid_rows(w: int, h: int):
    """(first row, row count, texel-centre uvs row-major) of a w x h grid, about 2^18 texels at a
    time: O(chunk) scratch whatever the size."""
    xs = (np.arange(w, dtype=np.float64) + 0.5) / w
    rows = max(1, (1 << 18) // w)
    for y0 in range(0, h, rows):
        ys = (np.arange(y0, min(h, y0 + rows), dtype=np.float64) + 0.5) / h
        yy, xx = np.meshgrid(ys, xs, indexing="ij")
        yield y0, len(ys), np.stack([xx.ravel(), yy.ravel()], 1).astype(np.float32)


def decode_material(target, size: tuple[int, int], lod: float, backend: str) -> tuple[np.ndarray, str]:
    """(H, W, outputs) float32 at the grid's texel centres, every output of material.json: the
    decoder's (through ``backend``), a layout's classic ones from their BC textures, and a mip
    split's mixed below its split, as material.json says. Returns it and what decoded it."""
    file = target.desc.file
    w, h = size
    img, used = _decode_network(target, size, lod, backend) if file.neural else (None, "classic textures")
    if not file.mixed:
        return img, used

    em = E.load(target.desc.folder)
    full = np.empty((h * w, len(file.outputs)), np.float32)
    if img is not None:
        full[:, [i for i, o in enumerate(file.outputs) if o.source != mf.Source.CLASSIC]] = img.reshape(h * w, -1)
        used += " and classic textures"
    for y0, n, uv in _grid_rows(w, h):
        E.classic_outputs(em, uv, float(lod), full[y0 * w:(y0 + n) * w])
    return full.reshape(h, w, -1), used


def _decode_network(target, size: tuple[int, int], lod: float, backend: str) -> tuple[np.ndarray, str]:
    from bcfpipe.model.decoder import ONNX_INPUT, ONNX_OUTPUT, from_bytes  # lazy: start-up


    m = target.desc
    try:  # a record the runtimes would refuse (NaN, magenta) or ONNX's reader raise on: one line, exit 2
        weights = from_bytes(m.weights_file.read_bytes(), m.weight_offset)[0]
    except ValueError as e:
        raise InputError(f"{m.weights_file}: {e}") from None
    if weights.dims[0] != m.file.mlp.n_in:
        raise InputError(f"{m.weights_file}: the record at byte {m.weight_offset} takes {weights.dims[0]} inputs, "
                         f"material.json's layers give {m.file.mlp.n_in}")
    w, h = size
    if backend == "vulkan":  # the shipped HLSL's SPIR-V on a Vulkan device (bcfpipe.verify.vulkan)
        with VulkanRuntime() as vk:
            vm = vk.load(target.desc)
            try:
                return vk.decode_grid(vm, w, h, lod), "vulkan"
            finally:
                vk.unload(vm)
    if backend in ("glsl", "auto"):
        try:
            rt = G.GLRuntime()
        except G.GLUnavailable as e:
            if backend == "glsl":
                raise InputError(f"{e} (use --backend onnx)") from None
        else:
            try:
                gm = rt.load(target.desc)
                try:
                    return rt.decode_grid(gm, w, h, lod), "glsl"
                finally:
                    rt.unload(gm)
            finally:
                rt.release()

    em = E.load(target.desc.folder)
    sess = E.onnx_session(em)
    out = np.empty((h, w, target.desc.c_out), np.float32)
    for y0, n, uv in _grid_rows(w, h):
        feats = E.sample_exported_features(em, uv, float(lod))
        out[y0:y0 + n] = sess.run([ONNX_OUTPUT], {ONNX_INPUT: feats})[0].reshape(n, w, -1)
    return out, "onnx"


def write_images(img: np.ndarray, outputs: Sequence[Output], out_dir: Path) -> list[Path]:
    """One file per semantic group of ``outputs`` (material.json order, normal z included)."""
    import OpenImageIO as oiio  # lazy: start-up

    out_dir.mkdir(parents=True, exist_ok=True)
    groups: dict[str, list[int]] = {}
    for i, o in enumerate(outputs):
        groups.setdefault(o.semantic, []).append(i)
    written = []
    for sem, idx in groups.items():
        data = img[..., idx].astype(np.float32)
        scale = np.array([outputs[i].value_scale for i in idx], np.float32)
        data = data * scale + np.array([outputs[i].value_bias for i in idx], np.float32)  # source values
        kind = outputs[idx[0]].kind
        if kind == "normal":
            data = data * 0.5 + 0.5
        if data.shape[-1] == 2:  # e.g. a two-channel generic: pad to RGB
            data = np.concatenate([data, np.zeros_like(data[..., :1])], -1)
        formats = [outputs[i].source_format for i in idx if not outputs[i].reconstructed]
        eight = bool(formats) and all(f == "uint8" for f in formats)
        path = out_dir / f"{sem}.{'png' if eight else 'exr'}"
        h, w, c = data.shape
        if eight:
            pixels = np.round(np.clip(data, 0, 1) * 255).astype(np.uint8)
            spec = oiio.ImageSpec(w, h, c, "uint8")
        else:
            pixels = np.ascontiguousarray(data, np.float32)
            spec = oiio.ImageSpec(w, h, c, "float")
            spec.attribute("compression", "zip")
        o = oiio.ImageOutput.create(str(path))
        if o is None or not o.open(str(path), spec):
            raise InputError(f"{path}: cannot write ({oiio.geterror()})")
        try:
            if not o.write_image(np.ascontiguousarray(pixels)):
                raise InputError(f"{path}: write failed ({o.geterror()})")
        finally:
            o.close()
        written.append(path)
    return written


@click.command("decode", cls=Command)
@click.argument("out", type=click.Path(exists=True, file_okay=False))
@click.option("--material", "prim", default=None, metavar="PRIM",
              help="Which material of a build (prim path, material or folder name); optional for one material.")
@click.option("--lod", type=float, default=0.0, show_default=True,
              help="Lod s in reference mip units (0 = full resolution; < 0 magnifies).")
@click.option("--size", default=None, metavar="WxH",
              help="Output size; default: the reference size at mip floor(max(s, 0)).")
@click.option("--backend", type=click.Choice(["auto", "glsl", "vulkan", "onnx"]), default="auto", show_default=True,
              help="glsl: the runtime shader through OpenGL; vulkan: the shipped HLSL's SPIR-V on a Vulkan device "
                   "(bcfpipe/decoders/); onnx: decoder.onnx on CPU; auto: glsl if OpenGL works.")
@click.option("-o", "--output", "out_dir", required=True, type=click.Path(file_okay=False),
              help="Folder for the images.")
def decode(out: str, prim: str | None, lod: float, size: str | None, backend: str, out_dir: str) -> None:
    """Write the texture set a neural material in OUT reconstructs, as images in a folder.

    PNG for semantics whose source files were 8-bit, EXR otherwise; normals as a normal map
    (rgb = 0.5 * xyz + 0.5). A --layout auto material's classic textures are decoded too (its
    classic groups, BC@R kept whole, or a mip split's levels below its split, mixed as
    material.json says). Exit codes: 0 ok, 2 bad input, no OpenGL with --backend glsl or no Vulkan with --backend vulkan.
    """
    target = select_target(out, prim)
    wh = parse_size(size)
    if wh is None:
        k = int(np.floor(max(lod, 0.0)))
        rw, rh = target.desc.ref_size
        wh = (max(1, rw >> k), max(1, rh >> k))
    img, used = decode_material(target, wh, lod, backend)
    files = write_images(img, target.desc.file.outputs, Path(out_dir))
    click.echo(f"{target.desc.name}: decoded {wh[0]}x{wh[1]} at s={lod:g} with {used}")
    for f in files:
        click.echo(f"  {f}")
