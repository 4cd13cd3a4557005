"""Step 3 of a build: the combined weights.bin, the USD layers and manifest.json."""
from __future__ import annotations

import functools
import os
from dataclasses import replace
from pathlib import Path
from typing import Callable, Mapping, Sequence

from bcfpipe.errors import WorkFailed
from bcfpipe.formats.vocabulary import Decision, Status
from bcfpipe import __version__
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import material as mf
from bcfpipe.formats import weights as weightsbuf
from bcfpipe.errors import EXIT_FAILED, EXIT_OK
from bcfpipe.builder.executor import JobResult
from bcfpipe.builder.plan import BuildPlan, MaterialJob, MaterialPlan, MATERIALS_DIR, OVERRIDES
from bcfpipe.formats.manifest import WEIGHTS
from bcfpipe.scan.sources import package_split


def _scene_name(scene: str | os.PathLike) -> str:
    return Path(scene).name.split(".")[0] or "scene"


def default_out(scene: str | os.PathLike, resolve: bool = True) -> Path:
    """``<scene>.bcf/`` next to the scene (as given, or resolved)."""
    p = Path(scene).resolve() if resolve else Path(scene)
    return p.parent / f"{_scene_name(p)}.bcf"


def root_layer_name(scene: str | os.PathLike) -> str:
    return f"{_scene_name(scene)}.bcf.usda"


def _device_class(device: str) -> str:
    """cpu / cuda: what the manifest records (the device index does not change results)."""
    return device.split(":")[0]


def _features_bytes(folder: Path) -> int:
    """The feature textures' bytes: T0..T3.dds, and a T_0 of several layers' T0b.dds, T0c.dds."""
    return sum(p.stat().st_size for p in folder.glob("T[0-9]*.dds"))


def _classic_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.glob("C*.dds"))


def _neural_targets(targets, desc: mf.MaterialFile) -> list:
    """The targets the decoder drives, with channels renumbered to its outputs; a layout's classic
    targets keep their UsdUVTexture (and are left out). Constant components (channel -1) stay."""
    index = {}
    for i, o in enumerate(desc.outputs):
        if o.source != mf.Source.CLASSIC:
            index[i] = len(index)
    return [replace(t, channel=index[t.channel]) if t.channel >= 0 else t
            for t in targets if t.channel < 0 or t.channel in index]


def assemble(bplan: BuildPlan, results: Mapping[str, JobResult], staging: str | os.PathLike,
             final_out: str | os.PathLike | None = None) -> mfst.Manifest:
    """Write weights.bin, the USD layers and manifest.json into ``staging`` (whose contents will
    live at ``final_out``; relative paths are computed from there). Returns the manifest."""
    staging = Path(staging)
    final_out = Path(final_out) if final_out is not None else staging
    built = [j for j in bplan.jobs if results.get(j.name) and results[j.name].status == Status.BUILT]
    descs = {j.name: mf.read(staging / MATERIALS_DIR / j.name) for j in built}
    neural = [j for j in built if descs[j.name].neural]  # a --layout auto material may be all classic
    entries = _write_weights(staging, neural)
    entry_of = {j.name: e for j, e in zip(neural, entries)}
    scene_rel, root_name = _write_layers(bplan, staging, final_out, descs, entry_of)
    rel = functools.partial(_relative, final_out=final_out)
    mats = tuple(_material(mp_, results.get(mp_.job) if mp_.job else None, bplan.sources, rel,
                           staging / MATERIALS_DIR, entry_of.get(mp_.job)) for mp_ in bplan.materials)
    totals = _totals(bplan, mats, built, staging)
    manifest = mfst.Manifest(
        scene=scene_rel, root_layer=root_name, overrides_layer=OVERRIDES, weights=WEIGHTS,
        variants=tuple(tuple(v) for v in bplan.variants),
        variant_selections=tuple(mfst.VariantSelection(p, s, v) for p, s, v in bplan.variant_selections),
        all_materials=bplan.all_materials, options=bplan.options.recorded(),
        stage=mfst.Stage(bplan.up_axis, bplan.meters_per_unit, bplan.default_prim),
        materials=mats, jobs=_job_entries(bplan, results, entry_of),
        weights_table=tuple(mfst.WeightsRecord(e.index, e.offset, e.size, e.n_hidden, e.n_out, j.name)
                            for j, e in zip(neural, entries)),
        totals=totals, diagnostics=tuple(bplan.diagnostics),
        exit_code=EXIT_FAILED if totals.failed else EXIT_OK)
    mfst.write(staging, manifest)
    _normalise_modes(staging)
    return manifest


def _write_weights(staging: Path, neural: Sequence[MaterialJob]) -> list:
    """weights.bin: the ``neural`` jobs' weight records packed in order; their table entries."""
    records = [(staging / MATERIALS_DIR / j.name / WEIGHTS).read_bytes() for j in neural]
    buffer, entries = weightsbuf.pack(records)
    (staging / WEIGHTS).write_bytes(buffer)
    return entries


def _write_layers(bplan: BuildPlan, staging: Path, final_out: Path, descs: Mapping[str, mf.MaterialFile],
                  entry_of: Mapping) -> tuple[str, str]:
    """The overrides layer (each neural material's override, the constant inputs, the classic
    wiring) and the root layer over it and the scene; (the scene relative to OUT, the root layer)."""
    import bcfpipe.builder.usd_layer as usdout  # lazy: start-up

    overrides = [_override(mp_, descs[mp_.job], entry_of[mp_.job]) for mp_ in bplan.materials
                 if mp_.job is not None and mp_.job in entry_of]
    scene_rel = usdout.relative_asset(bplan.scene, final_out)
    stamp = f"Written by bcfpipe {__version__} build from {scene_rel}"
    classic, source_stage = _classic_wiring(bplan, descs)
    check_classic_read({mp_.path: mp_.job for mp_ in bplan.materials}, descs, classic)
    usdout.write_overrides_layer(staging / OVERRIDES, overrides, bplan.variant_selections, comment=stamp,
                                 constants=_constant_inputs(bplan), classic=classic, source_stage=source_stage)
    root_name = root_layer_name(bplan.scene)
    usdout.write_root_layer(staging / root_name, [f"./{OVERRIDES}", scene_rel], bplan.up_axis,
                            bplan.meters_per_unit, bplan.default_prim, bplan.root_layer, comment=stamp)
    return scene_rel, root_name


def _override(mp_: MaterialPlan, desc: mf.MaterialFile, e):
    """A neural material's override (usd_layer.NeuralMaterialOverride): its feature textures, its
    record ``e`` in weights.bin, its decoder and the targets it drives."""
    import bcfpipe.builder.usd_layer as usdout  # lazy: start-up

    folder = f"./{MATERIALS_DIR}/{mp_.job}"
    layers = desc.layers
    targets = _neural_targets(mp_.targets, desc)
    outs = desc.mlp_outputs
    return usdout.NeuralMaterialOverride(
        material=mp_.path,
        feature_textures=tuple(f"{folder}/{layer.file}" for layer in layers),
        feature_resolutions=tuple(layer.resolution for layer in layers),
        feature_mip_counts=desc.mip_counts,
        feature_lod_biases=desc.lod_biases,
        feature_signed=desc.signed,
        wrap=desc.wrap,
        reference_resolution=(desc.reference.width, desc.reference.height),
        st_primvar=mp_.st_primvar, st_scale=mp_.st_scale, st_rotation=mp_.st_rotation,
        st_translation=mp_.st_translation,
        weights=f"./{WEIGHTS}", weights_offset=e.offset, weights_size=e.size, weights_index=e.index,
        mlp=desc.mlp,
        decoder=f"{folder}/{desc.onnx.file}",
        targets=tuple(t.target for t in targets), channels=tuple(t.channel for t in targets),
        # an HDR output's value map (material.json value_scale/value_bias) folds into the target's;
        # channel -1 is a constant component (its value is the bias)
        scale=tuple(t.scale * outs[t.channel].value_scale if t.channel >= 0 else 0.0 for t in targets),
        bias=tuple(t.bias + t.scale * outs[t.channel].value_bias if t.channel >= 0 else t.bias
                   for t in targets),
        color_spaces=tuple(t.color_space for t in targets),
        fallback_surface=mp_.fallback_surface, version=__version__, split=desc.split or 0,
    )


def _relative(path: str | None, final_out: Path) -> str | None:
    """A file path as the manifest records it: relative to OUT; a path inside a package as it is."""
    import bcfpipe.builder.usd_layer as usdout  # lazy: start-up

    return usdout.relative_asset(path, final_out) if path and package_split(path) is None else path


def _status(mp_: MaterialPlan, r: JobResult | None) -> tuple[Status, str | None]:
    """A material's status and why: as planned (skipped, constant, failed to plan), else as its job ended."""
    if mp_.decision == Decision.SKIP:
        return Status.SKIPPED, mp_.reason
    if mp_.decision == Decision.CONSTANT:
        return Status.CONSTANT, None
    if mp_.reason == "failed" and mp_.job is None:
        return Status.FAILED, mp_.message
    if r is None or r.status != Status.BUILT:
        return Status.FAILED, r.reason if r else "not run"
    return Status.BUILT, None


def _material(mp_: MaterialPlan, r: JobResult | None, sources: Mapping, rel: Callable[[str | None], str | None],
              materials_dir: Path, e) -> mfst.Material:
    """A material's manifest record: what it was made from and, when built, its figures and files."""
    status, reason = _status(mp_, r)
    common = dict(path=mp_.path, aliases=tuple(mp_.aliases), job=mp_.job, status=status, reason=reason,
                  message=mp_.message, **_inputs(mp_, sources, rel), warnings=tuple(mp_.warnings))
    if status != Status.BUILT:
        return mfst.Material(**common, device=_device_class(r.device) if r else None)
    return mfst.Material(**common, **_built(mp_, r, e, materials_dir / mp_.job, sources))


def _inputs(mp_: MaterialPlan, sources: Mapping, rel: Callable[[str | None], str | None]) -> dict:
    """A material's sources, targets, constants and folded channels, paths as ``rel`` records them."""
    return dict(
        sources=tuple(mfst.Source(rel(s.path), s.asset_path, s.xxh3_128, s.size_bytes, s.width, s.height,
                                  s.channels, s.format, s.color_space, s.resolved_color_space)
                      for s in (sources[p] for p in mp_.sources if p in sources)),
        targets=tuple(mfst.Target(t.target, t.input, t.channel, t.scale, t.bias, t.color_space, rel(t.file),
                                  t.file_channel) for t in mp_.targets),
        constants=tuple(mfst.Constant(c.target, c.input, c.value, rel(c.file), c.file_channel)
                        for c in mp_.constants),
        folded=tuple(mfst.Folded(rel(f.file), f.channel, f.reason, f.value,
                                 rel(f.same_as.file) if f.same_as else None,
                                 f.same_as.channel if f.same_as else None) for f in mp_.folded))


def _built(mp_: MaterialPlan, r: JobResult, e, folder: Path, sources: Mapping) -> dict:
    """A built material's figures (its job's result), sizes (its files in ``folder``, its record
    ``e`` in weights.bin, or None when all classic) and outputs."""
    feats = _features_bytes(folder)
    classic = _classic_bytes(folder)
    wsize = e.size if e else 0
    res = r.result
    return dict(
        metrics=mfst.Metrics(res.psnr, res.ssim, res.flip, res.float_psnr, res.metrics),
        sizes=mfst.Sizes(feats, wsize, feats + wsize + classic,
                         sum(sources[p].size_bytes for p in mp_.sources if p in sources), classic),
        outputs=mfst.Outputs(f"{MATERIALS_DIR}/{mp_.job}", e.index if e else None, e.offset if e else None,
                             e.size if e else None),
        layout=res.choice, profile=res.profile, resolutions=res.resolutions, preset=res.preset, target=res.target,
        device=_device_class(res.device or r.device))


def _job_entries(bplan: BuildPlan, results: Mapping[str, JobResult], entry_of: Mapping) -> tuple[mfst.Job, ...]:
    """Every job as the manifest records it: its materials, key, how it ended, its weights record."""
    out = []
    for j in bplan.jobs:
        r = results.get(j.name)
        out.append(mfst.Job(j.name, tuple(j.materials), j.content_hash, r.status if r else "not run",
                            r.reason if r else None, _device_class(r.device) if r else None,
                            entry_of[j.name].index if j.name in entry_of else None))
    return tuple(out)


def _totals(bplan: BuildPlan, mats: Sequence[mfst.Material], built: Sequence[MaterialJob],
            staging: Path) -> mfst.Totals:
    """Materials by status, jobs, and the bytes the build ships and read."""
    counts = {s: sum(1 for m in mats if m.status == s) for s in mfst.STATUSES}
    feature_total = sum(_features_bytes(staging / MATERIALS_DIR / j.name) + _classic_bytes(staging / MATERIALS_DIR / j.name)
                        for j in built)
    weights_size = (staging / WEIGHTS).stat().st_size
    return mfst.Totals(
        materials=len(mats), **counts, jobs=len(bplan.jobs), trained=len(built),
        features_bytes=feature_total, weights_bytes=weights_size,
        total_bytes=feature_total + weights_size, source_bytes=sum(s.size_bytes for s in bplan.sources.values()))


def _classic_wiring(bplan: BuildPlan, descs: Mapping[str, mf.MaterialFile]) -> tuple[list, object]:
    """Each built material with classic outputs and how its UsdUVTexture nodes read them (from the
    input stage with the build's variant selections), and that stage; ([], None) when none has."""
    todo = [mp_ for mp_ in bplan.materials if mp_.job in descs and mp_.fallback_surface
            and any(o.source in (mf.Source.CLASSIC, mf.Source.SPLIT) for o in descs[mp_.job].outputs)]
    if not todo:
        return [], None
    import bcfpipe.builder.usd_classic as usd_classic  # lazy: start-up

    stage = usd_classic.open_source_stage(bplan.scene, bplan.variant_selections)
    out = []
    for mp_ in todo:
        cm = usd_classic.wire_material(stage, mp_.path, mp_.fallback_surface, mp_.targets, descs[mp_.job],
                                       f"./{MATERIALS_DIR}/{mp_.job}")
        if cm is not None:
            out.append(cm)
    return out, stage


def check_classic_read(job_of: Mapping[str, str | None], descs: Mapping[str, mf.MaterialFile],
                       classic: Sequence) -> None:
    """Every shipped classic DDS is read (issue 57: no file shipped that nothing reads): by a
    UsdUVTexture the wiring (``classic``: usd_classic.ClassicMaterial per material) points at it, or
    by the decoder (a mip split's, below its split). ``job_of``: material path -> its job; ``descs``:
    each built job's material.json. A texture nothing reads is an internal inconsistency of the
    layout and the wiring: the build fails, naming it, rather than ship and count it."""
    read = {(job_of[cm.material], w.texture) for cm in classic for w in cm.wired}
    unread = [f"{MATERIALS_DIR}/{job}/{c.file}" for job, desc in descs.items() if desc.split is None
              for i, c in enumerate(desc.classic) if (job, i) not in read]
    if unread:
        raise WorkFailed(f"internal: {', '.join(unread)} would ship with no UsdUVTexture and no decoder reading it")


def _constant_inputs(bplan: BuildPlan) -> list:
    """One ConstantInput per surface input whose texture channels are all constant."""
    from bcfpipe.builder.usd_layer import ConstantInput  # lazy: start-up

    out = []
    for mp_ in bplan.materials:
        if not mp_.constants or not mp_.fallback_surface:
            continue
        by_input: dict[str, list[tuple[str, float]]] = {}
        for c in mp_.constants:
            by_input.setdefault(c.input, []).append((c.target, c.value))
        out += [ConstantInput(mp_.fallback_surface, name, tuple(values)) for name, values in by_input.items()]
    return out


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
