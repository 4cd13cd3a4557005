"""`--layout auto` for one material: decide the layout (`decide.decide_layout`), export it, and measure the exported folder."""
from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np
from typing import Callable

from bcfpipe.config import TrainingOptions
from bcfpipe.export.material import MaterialResult, evaluate_exported, exported_size
from bcfpipe.formats import dds, material as mf
from bcfpipe.formats.bcn import FORMAT_OF, decode_levels
from bcfpipe.layout.classic import magnify
from bcfpipe.layout.export import export_layout, write_decision
from bcfpipe.layout.decide import decide_layout
from bcfpipe.layout.predict import bc_resolution
from bcfpipe.texset.chain import Reference
from bcfpipe.texset.normals import angular_stats, rebuild_z, slope_normal
from bcfpipe.texset.texture_set import TextureSet
from bcfpipe.train.progress import ProgressFn

WORK = ".layout-work"  # inside the output folder while the probe and the chosen model train


def layout_material(ts: TextureSet, out_dir: str | Path, options: TrainingOptions, wrap: str,
                        log: Callable[[str], None] = lambda s: None,
                        progress: ProgressFn | None = None, coverage: np.ndarray | None = None) -> MaterialResult:
    """Choose, train and export ``ts``'s layout into ``out_dir`` (material.json says where every
    output comes from; layout.json why), measured from the exported files. With ``coverage`` (the
    texels the scene reads) training draws there and every figure is over those texels. ``ts``'s
    reference chain and coverage masks are built once here (`Reference`) and shared by the layout's
    fit and the final measure; ``progress`` hears that measure as ``evaluate``, step by step."""
    out = Path(out_dir)
    work = out / WORK
    start = time.perf_counter()
    reference = Reference.of(ts, coverage, wrap)
    fit = None
    try:
        fit = decide_layout(ts, work, options, bc_resolution(max(ts.width, ts.height), options.profile), wrap=wrap,
                         log=log, progress=progress, reference=reference)
        export_layout(fit, ts, out, wrap)
        t0 = time.perf_counter()
        ev = evaluate_exported(out, reference, ts.channels, progress, start=start)
        metrics, per_channel, dec = ev.metrics, ev.per_channel, ev.decoded
        del ev
        masks = reference.masks
        angle = normal_angles(out, ts, reference.mips[0], dec[0], masks[0] if masks else None)
        del dec
        # layout.json last: its sizes on disk and the BC7 quality set are estimated aside meanwhile
        fit = fit.resolved()
        decision = write_decision(out, fit, angle)  # with the shipped normal's angle, beside the PSNR (issue 57)
    finally:
        if fit is not None:
            fit.join_aside()  # a dropped training stops at its next progress report: mostly long since
        shutil.rmtree(work, ignore_errors=True)
    ch, n = fit.decision.chosen, fit.neural
    res = tuple(n.resolutions) if n else ()
    return MaterialResult(out, ch.profile or "classic", res,
                          options.preset if n else "none", n.device if n else "cpu", metrics, None, exported_size(out),
                          fit.train_seconds, {"layout": round(time.perf_counter() - start, 3),
                                              "classic_encode": round(fit.encode_seconds, 3),
                                              "evaluate": round(time.perf_counter() - t0, 3),
                                              **{f"layout_{k}": v for k, v in fit.costs.items()}},
                          None, per_channel, decision)


def normal_angles(folder: Path, ts: TextureSet, ref: np.ndarray, dec: np.ndarray,
                  mask: np.ndarray | None = None) -> dict | None:
    """Mean and p99 angle (degrees) at mip 0 between the set's normal (x, y, rebuilt z) and the
    shipped one as it is read: a classic normal stored as slopes as a UsdPreviewSurface reads it
    ((s_x, s_y, 1) normalised; level 0 magnified to the reference's size as it is sampled), else the
    decoder's x, y with z rebuilt, as the bcf context gives it. None without a normal."""
    xy = [i for i, c in enumerate(ts.channels) if c.kind == "normal"]
    if len(xy) != 2:
        return None
    desc = mf.read(folder)
    x = next((o for o in desc.outputs if o.kind == "normal" and not o.reconstructed), None)
    truth = rebuild_z(ref[..., xy])
    if x is not None and x.source == mf.Source.CLASSIC and x.encoding == mf.SLOPE:
        tex = desc.classic[x.texture]
        t = decode_levels(FORMAT_OF[tex.dxgi_format], dds.read(folder / tex.file).levels[:1])[0]
        if t.shape[:2] != ref.shape[:2]:
            t = magnify(t, *ref.shape[:2], desc.wrap)
        seen = slope_normal(t, -x.texel_bias)
        mean, p99 = angular_stats(truth, seen, mask)
        read = "USD: BC5 slopes (s_x, s_y, 1) normalised"
    else:
        mean, p99 = angular_stats(truth, rebuild_z(dec[..., xy]), mask)
        read = "z rebuilt from x, y"
    return {"mean_deg": round(mean, 3), "p99_deg": round(p99, 3), "mip": 0, "read_as": read}
