"""Step 3 of a build: the combined weights.bin, the USD layers and manifest.json."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from bcfpipe import __version__
from bcfpipe.formats import weights as weightsbuf
from bcfpipe.errors import EXIT_FAILED, EXIT_OK
from bcfpipe.build.executor import JobResult
from bcfpipe.build.plan import BUILD_FORMAT, BUILD_FORMAT_VERSION, BuildPlan, MANIFEST, MATERIALS_DIR, OVERRIDES, WEIGHTS
from bcfpipe.scan.texture_sets import package_split


def _scene_name(scene: str | os.PathLike) -> str:
    return Path(scene).name.split(".")[0] or "scene"


def default_out(scene: str | os.PathLike) -> Path:
    """``<scene>.bcf/`` next to the scene."""
    p = Path(scene).resolve()
    return p.parent / f"{_scene_name(p)}.bcf"


def root_layer_name(scene: str | os.PathLike) -> str:
    return f"{_scene_name(scene)}.bcf.usda"


def _features_bytes(folder: Path) -> int:
    return sum((folder / f"T{i}.dds").stat().st_size for i in range(4) if (folder / f"T{i}.dds").exists())


def assemble(bplan: BuildPlan, results: Mapping[str, JobResult], staging: str | os.PathLike,
             final_out: str | os.PathLike | None = None, wall_seconds: float = 0.0) -> dict:
    """Write weights.bin, the USD layers and manifest.json into ``staging`` (whose contents will
    live at ``final_out``; relative paths are computed from there). Returns the manifest."""
    from bcfpipe.build import usd_layer as usdout

    staging = Path(staging)
    final_out = Path(final_out) if final_out is not None else staging
    built = [j for j in bplan.jobs if results.get(j.name) and results[j.name].status == "built"]
    records = [(staging / MATERIALS_DIR / j.name / WEIGHTS).read_bytes() for j in built]
    buffer, entries = weightsbuf.pack(records)
    (staging / WEIGHTS).write_bytes(buffer)
    entry_of = {j.name: e for j, e in zip(built, entries)}
    descs = {j.name: json.loads((staging / MATERIALS_DIR / j.name / "material.json").read_text()) for j in built}

    overrides: list[usdout.NeuralMaterialOverride] = []
    for mp_ in bplan.materials:
        if mp_.job is None or mp_.job not in entry_of:
            continue
        e, desc = entry_of[mp_.job], descs[mp_.job]
        folder = f"./{MATERIALS_DIR}/{mp_.job}"
        layers = desc["layers"]
        overrides.append(usdout.NeuralMaterialOverride(
            material=mp_.path,
            feature_textures=tuple(f"{folder}/{layer['file']}" for layer in layers),
            feature_resolutions=tuple(int(layer["resolution"]) for layer in layers),
            feature_mip_counts=tuple(int(layer["mip_count"]) for layer in layers),
            feature_lod_biases=tuple(float(layer["lod_bias"]) for layer in layers),
            feature_signed=bool(desc["bc6h"]["signed"]),
            addressing=desc["sampling"]["addressing"],
            reference_resolution=(int(desc["reference"]["width"]), int(desc["reference"]["height"])),
            st_primvar=mp_.st_primvar, st_scale=mp_.st_scale, st_rotation=mp_.st_rotation,
            st_translation=mp_.st_translation,
            weights=f"./{WEIGHTS}", weights_offset=e.offset, weights_size=e.size, weights_index=e.index,
            mlp_inputs=int(desc["mlp"]["n_in"]), mlp_hidden=int(desc["mlp"]["n_hidden"]),
            mlp_outputs=int(desc["mlp"]["n_out"]), mlp_precision=desc["mlp"]["precision"],
            mlp_activation=desc["mlp"]["activation"],
            decoder=f"{folder}/{desc['onnx']['file']}",
            targets=tuple(t.target for t in mp_.targets), channels=tuple(t.channel for t in mp_.targets),
            scale=tuple(t.scale for t in mp_.targets), bias=tuple(t.bias for t in mp_.targets),
            color_spaces=tuple(t.color_space for t in mp_.targets),
            fallback_surface=mp_.fallback_surface, version=__version__,
        ))
    scene_rel = usdout.relative_asset(bplan.scene, final_out)
    stamp = f"Written by bcfpipe {__version__} build from {scene_rel}"
    usdout.write_overrides_layer(staging / OVERRIDES, overrides, bplan.variant_selections, comment=stamp)
    root_name = root_layer_name(bplan.scene)
    usdout.write_root_layer(staging / root_name, [f"./{OVERRIDES}", scene_rel], bplan.up_axis,
                            bplan.meters_per_unit, bplan.default_prim, bplan.root_layer, comment=stamp)

    sources = bplan.sources
    mats: list[dict] = []
    for mp_ in bplan.materials:
        entry: dict[str, Any] = {"path": mp_.path, "aliases": list(mp_.aliases), "job": mp_.job}
        r = results.get(mp_.job) if mp_.job else None
        if mp_.decision == "skip":
            entry.update(status="skipped", reason=mp_.reason, message=mp_.message)
        elif mp_.reason == "failed" and mp_.job is None:
            entry.update(status="failed", reason=mp_.message, message=mp_.message)
        elif r is None or r.status != "built":
            entry.update(status="failed", reason=r.reason if r else "not run", message=mp_.message)
        else:
            entry.update(status="built", reason=None, message=mp_.message)
        job = bplan.job(mp_.job) if mp_.job else None
        entry["shared_with"] = [m for m in job.materials if m != mp_.path] if job else []
        entry["sources"] = [
            {"file": usdout.relative_asset(s.path, final_out) if package_split(s.path) is None else s.path,
             "asset_path": s.asset_path, "xxh3_128": s.xxh3_128, "size_bytes": s.size_bytes,
             "width": s.width, "height": s.height, "channels": s.channels, "format": s.format,
             "color_space": s.color_space, "resolved_color_space": s.resolved_color_space}
            for s in (sources[p] for p in mp_.sources if p in sources)]
        entry["targets"] = [
            {"target": t.target, "input": t.input, "channel": t.channel, "scale": t.scale, "bias": t.bias,
             "color_space": t.color_space,
             "source": (usdout.relative_asset(t.file, final_out) if t.file and package_split(t.file) is None
                        else t.file),
             "source_channel": t.file_channel} for t in mp_.targets]
        if entry["status"] == "built" and r is not None:
            folder = staging / MATERIALS_DIR / mp_.job
            e = entry_of[mp_.job]
            feats = _features_bytes(folder)
            res = r.result
            entry["metrics"] = {"psnr": res.get("psnr"), "ssim": res.get("ssim"), "flip": res.get("flip"),
                                "float_psnr": res.get("float_psnr"), "detail": res.get("metrics")}
            entry["sizes"] = {"features_bytes": feats, "weights_bytes": e.size, "total_bytes": feats + e.size,
                              "source_bytes": sum(sources[p].size_bytes for p in mp_.sources if p in sources)}
            entry["outputs"] = {"folder": f"{MATERIALS_DIR}/{mp_.job}", "weights_index": e.index,
                                "weights_offset": e.offset, "weights_size": e.size}
            entry["profile"] = res.get("profile")
            entry["resolutions"] = res.get("resolutions")
            entry["train_seconds"] = res.get("train_seconds")
            entry["device"] = r.device
        else:
            entry.update(metrics=None, sizes=None, outputs=None, train_seconds=r.seconds if r else None,
                         device=r.device if r else None)
        entry["warnings"] = list(mp_.warnings)
        mats.append(entry)

    job_entries = []
    for j in bplan.jobs:
        r = results.get(j.name)
        job_entries.append({"name": j.name, "materials": list(j.materials), "content_hash": j.content_hash,
                            "status": r.status if r else "not run", "reason": r.reason if r else None,
                            "seconds": round(r.seconds, 3) if r else None, "device": r.device if r else None,
                            "threads": r.threads if r else None,
                            "weights_index": entry_of[j.name].index if j.name in entry_of else None})
    counts = {s: sum(1 for m in mats if m["status"] == s) for s in ("built", "failed", "skipped")}
    feature_total = sum(_features_bytes(staging / MATERIALS_DIR / j.name) for j in built)
    weights_size = (staging / WEIGHTS).stat().st_size
    manifest = {
        "format": BUILD_FORMAT, "format_version": BUILD_FORMAT_VERSION, "bcfpipe_version": __version__,
        "scene": scene_rel, "root_layer": root_name, "overrides_layer": OVERRIDES, "weights": WEIGHTS,
        "variants": [list(v) for v in bplan.variants],
        "variant_selections": [{"prim": p, "set": s, "value": v} for p, s, v in bplan.variant_selections],
        "all_materials": bplan.all_materials, "options": dict(bplan.options),
        "stage": {"up_axis": bplan.up_axis, "meters_per_unit": bplan.meters_per_unit,
                  "default_prim": bplan.default_prim},
        "materials": mats,
        "jobs": job_entries,
        "weights_table": [e.to_dict() | {"job": j.name} for j, e in zip(built, entries)],
        "totals": {
            "materials": len(mats), **counts,
            "jobs": len(bplan.jobs), "trained": len(built),
            "train_seconds": round(sum((results[j.name].result.get("train_seconds") or 0.0) for j in built), 3),
            "wall_seconds": round(wall_seconds, 3),
            "features_bytes": feature_total, "weights_bytes": weights_size,
            "total_bytes": feature_total + weights_size,
            "source_bytes": sum(s.size_bytes for s in sources.values()),
        },
        "diagnostics": list(bplan.diagnostics),
        "exit_code": EXIT_FAILED if counts["failed"] else EXIT_OK,
    }
    (staging / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    _normalise_modes(staging)
    return manifest


def _umask() -> int:
    """The process umask, read without changing it (Linux); 0o022 elsewhere."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def _normalise_modes(folder: Path) -> None:
    """Ordinary file modes for everything in the output (the exporter writes 0600 temp files)."""
    mask = _umask()
    for p in folder.rglob("*"):
        if p.is_symlink():
            continue
        p.chmod((0o777 if p.is_dir() else 0o666) & ~mask)
    folder.chmod(0o777 & ~mask)
