"""`bcfpipe dds`: look inside the DDS textures bcfpipe writes (features, and classic layouts' textures)."""
from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np
from rich.console import Console
from rich.table import Table

from bcfpipe.bc7 import decode as bc7_decode
from bcfpipe.bc6h import decode as bc6h_decode
from bcfpipe.cli.errors import Group
from bcfpipe.formats import dds as ddsmod
from bcfpipe.errors import InputError
from bcfpipe.formats.bcn import FORMAT_OF, ClassicFormat, decode_levels


def _load(path: str) -> ddsmod.DdsTexture:
    try:
        return ddsmod.read(path)
    except ddsmod.DdsError as e:
        raise InputError(str(e)) from None


def _decode_level(tex: ddsmod.DdsTexture, k: int) -> np.ndarray:
    """Mip ``k`` as (h, w, channels): 3 half-float channels for BC6H, 4 in [0, 1] for BC7, and
    a classic texture's stored channels in [0, 1] (BC1: 3, BC4: 1, BC5: 2)."""
    blocks, w, h = tex.levels[k]
    if FORMAT_OF.get(tex.dxgi_format) in (ClassicFormat.BC1, ClassicFormat.BC4, ClassicFormat.BC5):
        return decode_levels(FORMAT_OF[tex.dxgi_format], [tex.levels[k]])[0]
    if tex.is_bc7:
        try:
            return bc7_decode(blocks, w, h)
        except ValueError as e:
            raise InputError(f"mip {k}: {e}") from None


    return bc6h_decode(blocks, w, h, signed=tex.signed)


@click.group(cls=Group)
def dds() -> None:
    """Inspect and decode the DDS files bcfpipe writes: BC7 (any mode) and BC6H feature textures,
    and a classic layout's BC1, BC4, BC5, BC6H and BC7 textures (C*.dds)."""


@dds.command("info")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
def info(file: str, as_json: bool) -> None:
    """Format, size, mip chain and per-channel value range of FILE."""
    tex = _load(file)
    mips = []
    for k, (blocks, w, h) in enumerate(tex.levels):
        img = _decode_level(tex, k).astype(np.float32)
        c = img.shape[-1]
        mips.append({"level": k, "width": w, "height": h, "blocks": int(blocks.shape[0]),
                     "min": img.reshape(-1, c).min(0).tolist(), "max": img.reshape(-1, c).max(0).tolist()})
    size = Path(file).stat().st_size
    report = {"file": str(file), "format": tex.format_name, "dxgi_format": tex.dxgi_format,
              "width": tex.width, "height": tex.height, "mip_count": tex.mip_count,
              "size_bytes": size, "mips": mips}
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return

    table = Table(title=f"{file}: {tex.format_name} {tex.width}x{tex.height}, {tex.mip_count} mips, {size} bytes")
    rgb = " ".join("rgba"[:len(mips[0]["min"])]) if mips else "r g b"
    for col in ("mip", "size", "blocks", f"min ({rgb})", f"max ({rgb})"):
        table.add_column(col, justify="right")
    fmt = lambda v: " ".join(f"{x:.4g}" for x in v)  # noqa: E731
    for m in mips:
        table.add_row(str(m["level"]), f"{m['width']}x{m['height']}", str(m["blocks"]), fmt(m["min"]), fmt(m["max"]))
    Console().print(table)


@dds.command("decode")
@click.argument("file", type=click.Path(dir_okay=False))
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False),
              help="Output image (OpenEXR recommended; any float-capable format OpenImageIO writes).")
@click.option("--mip", default=0, show_default=True, help="Mip level to decode.")
@click.option("-f", "--force", is_flag=True, help="Overwrite OUTPUT if it exists.")
def decode_cmd(file: str, output: str, mip: int, force: bool) -> None:
    """Decode one mip of FILE: half floats for BC6H, 32-bit floats (value / 255) for BC1, BC4, BC5
    and BC7."""
    import OpenImageIO as oiio  # lazy: start-up

    tex = _load(file)
    if not 0 <= mip < tex.mip_count:
        raise InputError(f"{file}: mip {mip} out of range (0..{tex.mip_count - 1})")
    out = Path(output)
    if out.exists() and not force:
        raise InputError(f"{out} exists; pass --force to overwrite")
    img = _decode_level(tex, mip)
    spec = oiio.ImageSpec(img.shape[1], img.shape[0], img.shape[2], oiio.HALF if tex.dxgi_format in (ddsmod.DXGI_FORMAT_BC6H_UF16, ddsmod.DXGI_FORMAT_BC6H_SF16) else oiio.FLOAT)
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), img)
    tmp = out.with_name(out.name + ".tmp" + out.suffix)
    if not buf.write(str(tmp)):
        tmp.unlink(missing_ok=True)
        raise InputError(f"cannot write {out}: {buf.geterror()}")
    tmp.replace(out)
    click.echo(f"wrote {out} ({img.shape[1]}x{img.shape[0]}, mip {mip})", err=True)
