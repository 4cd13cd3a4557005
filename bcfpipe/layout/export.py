"""Write a chosen layout as one material folder: the neural model's files (if any), the classic
groups as C_i.dds, and a material.json whose every output says where its value comes from.

Only the chosen parts are written; the probe and any model not chosen stay behind. The folder is
deterministic for the same inputs (the build's cache relies on it), and material.json goes last.
"""
from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from bcfpipe.export.writer import output_channels
from bcfpipe.formats import dds, material as mf
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.formats.digest import sha256_file
from bcfpipe.formats.vocabulary import Source
from bcfpipe.formats.bcn import DXGI
from bcfpipe.layout.classic import EncodedGroup, split_levels
from bcfpipe.layout.result import LayoutFit
from bcfpipe.texset.texture_set import TextureSet


def classic_texture(i: int, enc: EncodedGroup, reference_width: int) -> mf.ClassicTexture:
    _, w, h = enc.levels[0]
    fmt = DXGI[enc.group.format]
    return mf.ClassicTexture(mf.classic_file(i), fmt, dds.DXGI_NAMES[fmt], w, h, len(enc.levels),
                             math.log2(w / reference_width), len(enc.group.channels))


def output_sources(ts: TextureSet) -> list[int]:
    """Per decoder output of ``output_channels(ts.channels)``, the set channel it reads (normal z:
    its y). By position, not by name: generic channels of two files can share a name (``generic.b``)."""
    out = []
    for c, ch in enumerate(ts.channels):
        out.append(c)
        if ch.kind == "normal" and ch.component == "y":
            out.append(c)
    return out


def _slots(enc: EncodedGroup, ts: TextureSet) -> tuple[int, ...] | None:
    """Per texel channel, the output it stores (``ClassicTexture.slots``), when a colour's slots
    repeat a channel (issue 57): where the USD layer finds each of its components; else None."""
    chans = enc.group.channels
    if len(set(chans)) == len(chans):
        return None
    index = {}
    for k, c in enumerate(output_sources(ts)):
        index.setdefault(c, k)
    return tuple(index[c] for c in chans)


def _where(shipped: Sequence[EncodedGroup], ts: TextureSet) -> dict[int, tuple[int, int, float, float]]:
    """Set channel -> (texture, texel channel, scale, bias), at a repeated channel's first slot (a
    slope normal's x and y: the slope's 2m, -m)."""
    where: dict[int, tuple[int, int, float, float]] = {}
    for i, enc in enumerate(shipped):
        for j, (c, (scale, bias)) in enumerate(zip(enc.group.channels, enc.texel_map(ts))):
            where.setdefault(c, (i, j, scale, bias))
    return where


def _encoding(o: mf.Output, shipped: Sequence[EncodedGroup], texture: int) -> str | None:
    """Output ``o``'s material.json encoding: `mf.SLOPE` for a normal's x, y and z read from a slope normal."""
    return mf.SLOPE if o.kind == "normal" and shipped[texture].slope is not None else None


def export_layout(fit: LayoutFit, ts: TextureSet, out_dir: str | os.PathLike, wrap: str) -> Path:
    """Write ``fit``'s chosen layout of ``ts`` to ``out_dir``, as its kind writes it; returns it."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    chosen = fit.decision.chosen
    chosen.kind.export(fit, chosen, ts, out, wrap)
    return out


def export_groups(fit: LayoutFit, shipped: Sequence[EncodedGroup], ts: TextureSet, out: Path, wrap: str) -> Path:
    """Write the classic textures ``shipped`` as C_i.dds and ``fit``'s model (if any) for the other
    channels to ``out``, with the material.json that says where each output comes from."""
    classic = []
    for i, enc in enumerate(shipped):
        dds.write(out / mf.classic_file(i), enc.levels, dxgi_format=DXGI[enc.group.format])
        classic.append(classic_texture(i, enc, ts.width))
    where = _where(shipped, ts)  # set channel -> (texture, channel, scale, bias)

    base = None
    if fit.neural is not None:
        src = Path(fit.neural.out_dir)
        base = mf.read(src)
        for f in base.files:
            shutil.copyfile(src / f, out / f)
    outputs = []
    for o, c in zip(output_channels(ts.channels), output_sources(ts)):
        if c in where:
            t, j, scale, bias = where[c]
            # a classic texture holds linear values: the decoder's log curve is no part of its output
            outputs.append(replace(o, source=Source.CLASSIC.value, texture=t, log_gain=None,
                                   texel_channel=None if o.reconstructed else j,
                                   texel_scale=None if o.reconstructed else scale,
                                   texel_bias=None if o.reconstructed else bias, encoding=_encoding(o, shipped, t)))
        else:
            outputs.append(o)
    classic = [replace(c, slots=_slots(enc, ts)) for c, enc in zip(classic, shipped)]
    if base is not None:
        desc = replace(base, outputs=tuple(outputs), classic=tuple(classic), sha256=None)
    else:
        desc = mf.MaterialFile(layers=(), sampling=mf.Sampling.of(wrap),
                               reference=mf.Reference(ts.width, ts.height, max(ts.width, ts.height).bit_length()),
                               outputs=tuple(outputs), training=mf.Training((), "none", 0, "cpu"),
                               classic=tuple(classic))
    desc = replace(desc, sha256={f: sha256_file(out / f) for f in desc.files})
    _drop_stale(out, desc)
    mf.write(out, desc)
    return out


def _drop_stale(out: Path, desc: mf.MaterialFile) -> None:
    """Remove an earlier export's files (train --force) that ``desc`` does not list."""
    for stale in (*out.glob("T[0-9].dds"), *out.glob("C[0-9]*.dds"), out / mf.WEIGHTS, out / mf.ONNX):
        if stale.name not in desc.files and stale.is_file():
            stale.unlink()


def export_split(groups: list[EncodedGroup], neural_dir: str | os.PathLike, ts: TextureSet,
                 out_dir: str | os.PathLike, split: int, resolution: int) -> Path:
    """Write a mip-split layout of ``ts`` to ``out_dir``: every BC@R group as C_i.dds with the
    levels that serve the reference mips below ``split`` only, the model of ``neural_dir`` (trained
    for s >= split, ModelConfig.split) for the rest, and a material.json whose every output is
    ``split``: the classic texture's value up to s = split - 1, the MLP's from s = split, linear in
    s between. Returns the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    keep = split_levels(split, resolution, max(ts.width, ts.height))
    src = Path(neural_dir)
    base = mf.read(src)
    if base.mixed or not base.neural:
        raise ValueError(f"{src}: a mip split takes an all-neural model")
    for f in base.files:
        shutil.copyfile(src / f, out / f)
    classic, where = [], {}
    for i, enc in enumerate(groups):
        part = replace(enc, levels=enc.levels[:keep])
        dds.write(out / mf.classic_file(i), part.levels, dxgi_format=DXGI[enc.group.format])
        classic.append(classic_texture(i, part, ts.width))
        for j, (c, (scale, bias)) in enumerate(zip(enc.group.channels, enc.texel_map(ts))):
            where.setdefault(c, (i, j, scale, bias))
    outputs = []
    for o, c in zip(base.outputs, output_sources(ts)):
        t, j, scale, bias = where[c]
        outputs.append(replace(o, source=Source.SPLIT.value, texture=t,
                               texel_channel=None if o.reconstructed else j,
                               texel_scale=None if o.reconstructed else scale,
                               texel_bias=None if o.reconstructed else bias, encoding=_encoding(o, groups, t)))
    desc = replace(base, outputs=tuple(outputs), classic=tuple(classic), split=int(split), sha256=None)
    desc = replace(desc, sha256={f: sha256_file(out / f) for f in desc.files})
    _drop_stale(out, desc)
    mf.write(out, desc)
    return out


def decision_json(fit: LayoutFit) -> dict:
    """What layout.json says: the choice among measured layouts, why, each measured layout's figures
    against BC@R and the BC7 quality set, and ``weighed``: every candidate the first choice was made
    among (profiles × T_0 widths, mixed, splits), predicted ones included, with the first choice."""
    fit = fit.resolved()
    d = fit.decision.to_json()
    if fit.first is not fit.decision:
        d["weighed"] = fit.first.to_json()["candidates"]
        d["first_choice"] = fit.first.chosen.label
    return d


def write_decision(out_dir: str | os.PathLike, fit: LayoutFit, normal_angle: dict | None = None) -> dict:
    """layout.json beside material.json: the candidates, the choice and why (informative); with
    ``normal_angle``, the shipped normal's angular error as it is read (`layout.material.normal_angles`).
    Returns what it wrote."""
    d = decision_json(fit)
    if normal_angle is not None:
        d["normal_angular_error"] = normal_angle
    atomic_write(Path(out_dir) / "layout.json", (json.dumps(d, indent=2) + "\n").encode())
    return d
