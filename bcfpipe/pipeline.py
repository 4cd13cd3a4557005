"""`bcfpipe build`: turn the textured UsdPreviewSurface materials of a USD scene into neural
materials, and write a USD stage that uses them.

A build runs in three steps, each usable on its own (a cache or a distributed executor slots in
between them):

1. `plan` scans the stage (``bcfpipe.scan``) and turns every material decided ``model`` into a
   `MaterialPlan`; materials whose texture sets are identical (the same files and channels, the
   same addressing) share one frozen, JSON-serialisable `MaterialJob`, whose ``content_hash``
   (xxh3-128 over the source file *bytes* and the training configuration, never paths or times)
   names its result.
2. `execute` trains the jobs, each in its own worker process (``ProcessPoolExecutor``, spawn
   context), with ``config.DEFAULT_THREADS`` (1) torch threads each unless told otherwise. A job
   that raises, or whose worker dies, becomes ``failed`` with a one-line reason; the others go on.
3. `assemble` writes the combined ``weights.bin`` (`bcfpipe.weightsbuf`), the USD layers
   (`bcfpipe.usdout`) and ``manifest.json``.

`build` runs the three into a temporary sibling folder and renames it to OUT at the end, so an
interrupted build never leaves a half-written OUT. An existing OUT is only replaced when it holds a
bcfpipe ``manifest.json`` (or with ``force``); an OUT that contains the scene or one of its
textures is always refused (inputs are never modified).

Output folder (OUT, default ``<scene>.bcf/`` next to the scene)::

    <scene>.bcf.usda     the stage to open: sublayers overrides.usda and the input (relative paths)
    overrides.usda       variant selections + BcfNeuralMaterialAPI on every modelled Material
    weights.bin          all decoders, fp16, one table (see bcfpipe.weightsbuf)
    manifest.json        per-material status, sources with hashes, targets, metrics, sizes, times
    materials/<name>/    the trainer's export per trained texture set: T0..T3.dds, weights.bin
                         (that decoder alone), decoder.onnx, material.json

What is modelled, and how (the contract with renderers):

* Only textured UsdPreviewSurface inputs become decoder outputs; constant inputs keep their
  authored USD values (nothing in the input's shading network is changed).
* Each (file, channel) is one decoder output, however many inputs read it. A normal map read
  through ``.rgb`` gives two outputs (x, y, stored as ``2 v - 1``); the decoder appends
  z = sqrt(1 - x^2 - y^2) after y, and ``normal.z`` is a target.
* The model reproduces *stored* texel values (no colour decoding; see bcfpipe.texset). Per target
  the overrides author ``colorSpace`` (``sRGB``/``raw``), ``scale`` and ``bias`` so that
  ``target = decode(y[channel]) * scale + bias`` equals what the UsdUVTexture would have produced:
  scale/bias are the texture's own (for normals adjusted for the ``2 v - 1`` encoding, so the
  usual scale 2 / bias -1 becomes 1 / 0), and ``colorSpace`` is the texture's sourceColorSpace with
  ``auto`` resolved as Hydra does (sRGB for 8-bit files with 3 or 4 channels, else raw; alpha is
  never sRGB). Normal maps are always treated as raw data; an sRGB-tagged normal map gets a
  warning. ``normal.z`` is always the unit-length reconstruction (scale 1, bias 0).
* Opacity, displacement and emissive colour are modelled like any other input when textured.
  Opacity is learnt as the filtered (mip-averaged) *coverage*, never thresholded: the authored
  ``opacityThreshold`` (a constant that stays in USD, or a target if textured) is applied by the
  renderer to the decoded opacity, exactly as UsdPreviewSurface applies it to the texture fetch, so
  cut-outs keep their threshold and get smooth, stable coverage at distance. Displacement is
  decoded at the vertex/tessellation stage by renderers that displace.
* Addressing is ``clamp`` when every texture of the material clamps both axes, else ``repeat``
  (``black``/``mirror`` are modelled as repeat, with a warning). The textures' st primvar and
  UsdTransform2d are recorded; textures of one material must share them (else a warning).
* The profile ``auto`` is capped by the source resolution (``config.resolve_profile``).

Exit codes (`BuildResult.exit_code`, and the CLI): 0 every modelled material was built (skipped
ones are reported, not errors); 1 at least one material failed; 2 bad input or refused OUT (raised
as `BuildError`, before any training).

Determinism: the same inputs, options and seed give the same DDS, weights, ONNX and USD files on
the same machine (CPU training with the same number of worker threads). ``manifest.json`` and
``material.json`` also record times, which differ between runs.
"""
from __future__ import annotations

import concurrent.futures as cf
import json
import math
import multiprocessing as mp
import os
import re
import shutil
import sys
import tempfile
import time
import uuid
from concurrent.futures.process import BrokenProcessPool
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Sequence

import xxhash

from . import __version__, weightsbuf
from .config import DEFAULT_PRESET, DEFAULT_THREADS, PRESETS, PROFILE_NAMES
from .errors import EXIT_FAILED, EXIT_OK, BcfError

if TYPE_CHECKING:  # pxr and torch load lazily: `import bcfpipe` stays cheap
    from .scan import MaterialScan, StageScan

__all__ = [
    "BuildError", "SourceFile", "ModelChannel", "TargetMap", "MaterialJob", "MaterialPlan", "BuildPlan",
    "JobResult", "BuildResult", "plan", "execute", "assemble", "build", "default_jobs", "cpu_count",
    "MANIFEST", "WEIGHTS", "OVERRIDES", "MATERIALS_DIR", "BUILD_FORMAT",
]

BUILD_FORMAT = "bcfpipe-build"
BUILD_FORMAT_VERSION = 1
MANIFEST = "manifest.json"
WEIGHTS = "weights.bin"
OVERRIDES = "overrides.usda"
MATERIALS_DIR = "materials"

ProgressCallback = Callable[[dict], None]

_COLOR_SEMANTIC = {"diffuseColor": "albedo", "emissiveColor": "emissiveColor"}
_SCALAR_SEMANTICS = frozenset({"occlusion", "roughness", "metallic", "displacement", "opacity"})


class BuildError(BcfError):
    """A build that cannot start: unreadable scene, bad option, or an OUT it must not replace."""


# ---------------------------------------------------------------------------------------------
# plan data


@dataclass(frozen=True)
class SourceFile:
    """One texture file a job reads: where it is, what it hashes to, how USD decodes it."""

    path: str  # resolved (absolute, or ``package.usdz[inner]``)
    asset_path: str  # as authored
    xxh3_128: str
    size_bytes: int
    width: int
    height: int
    channels: int
    format: str  # OpenImageIO base type of the stored texels, e.g. uint8
    color_space: str  # sourceColorSpace as authored (auto/raw/sRGB)
    resolved_color_space: str  # sRGB or raw (auto resolved as Hydra does)


@dataclass(frozen=True)
class ModelChannel:
    """One decoder output before normal z: a file channel, read as a value or a normal component."""

    file: str
    channel: str  # r, g, b or a
    kind: str  # "value" or "normal"


@dataclass(frozen=True)
class TargetMap:
    """One UsdPreviewSurface target of a material and the decoder output that drives it."""

    target: str  # diffuseColor.r, normal.x, roughness, ...
    input: str
    channel: int  # decoder output index (normal z included)
    scale: float
    bias: float
    color_space: str  # "sRGB" or "raw"
    file: str | None  # None for the reconstructed normal.z
    file_channel: str | None


@dataclass(frozen=True)
class MaterialJob:
    """One training run (a texture set), shared by every material in ``materials``.

    Frozen and JSON-serialisable (`to_dict` / `from_dict`). ``content_hash`` covers everything the
    result depends on: source bytes, specs, addressing, profile, preset (its schedule), seed,
    device, architecture and the bcfpipe version; not paths, not the machine's thread count.
    """

    name: str
    materials: tuple[str, ...]
    specs: tuple[tuple[str, str, str], ...]  # (semantic, file, channels) for bcfpipe.texset
    channels: tuple[ModelChannel, ...]
    sources: tuple[SourceFile, ...]
    wrap: str
    profile: str
    preset: str
    seed: int
    device: str
    hidden: int
    signed: bool
    content_hash: str

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MaterialJob":
        d = dict(d)
        d["materials"] = tuple(d["materials"])
        d["specs"] = tuple(tuple(s) for s in d["specs"])
        d["channels"] = tuple(ModelChannel(**c) for c in d["channels"])
        d["sources"] = tuple(SourceFile(**s) for s in d["sources"])
        return cls(**d)


@dataclass(frozen=True)
class MaterialPlan:
    """What the build does with one scanned material."""

    path: str
    aliases: tuple[str, ...]
    decision: str  # model | skip
    reason: str | None
    message: str
    job: str | None = None
    targets: tuple[TargetMap, ...] = ()
    fallback_surface: str | None = None
    st_primvar: str = "st"
    st_scale: tuple[float, float] = (1.0, 1.0)
    st_rotation: float = 0.0
    st_translation: tuple[float, float] = (0.0, 0.0)
    sources: tuple[str, ...] = ()  # files (SourceFile.path) this material reads
    warnings: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class BuildPlan:
    """A scanned scene turned into jobs: everything `execute` and `assemble` need."""

    scene: str
    root_layer: str
    variants: tuple[tuple[str, str], ...]
    variant_selections: tuple[tuple[str, str, str], ...]
    all_materials: bool
    up_axis: str
    meters_per_unit: float
    default_prim: str | None
    materials: tuple[MaterialPlan, ...]
    jobs: tuple[MaterialJob, ...]
    options: dict = field(default_factory=dict)
    diagnostics: tuple[str, ...] = ()

    def job(self, name: str) -> MaterialJob:
        for j in self.jobs:
            if j.name == name:
                return j
        raise KeyError(name)

    @property
    def sources(self) -> dict[str, SourceFile]:
        return {s.path: s for j in self.jobs for s in j.sources}

    def to_dict(self) -> dict:
        d = asdict(self)
        d["jobs"] = [j.to_dict() for j in self.jobs]
        return d


# ---------------------------------------------------------------------------------------------
# planning


def _package_split(path: str) -> tuple[str, str] | None:
    """``pkg.usdz[inner/a.png]`` -> (pkg.usdz, inner/a.png); None for plain files."""
    m = re.match(r"^(.*)\[([^\[\]]+)\]$", path)
    return (m.group(1), m.group(2)) if m else None


def read_asset(path: str) -> bytes:
    """The bytes of a resolved texture path (a plain file, or a file inside a package via Ar)."""
    if _package_split(path) is None:
        return Path(path).read_bytes()
    from pxr import Ar

    asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(path))
    if asset is None:
        raise OSError(f"cannot open {path}")
    return bytes(asset.GetBuffer())


def local_file(path: str, tmp_dir: str | os.PathLike) -> str:
    """A filesystem path with the asset's bytes: the file itself, or a copy of a packaged file."""
    pkg = _package_split(path)
    if pkg is None:
        return path
    dst = Path(tmp_dir) / f"{xxhash.xxh3_64_hexdigest(path.encode())}_{Path(pkg[1]).name}"
    if not dst.exists():
        dst.write_bytes(read_asset(path))
    return str(dst)


def _probe(path: str) -> tuple[int, int, int, str]:
    """(width, height, channels, base type) from the image header; zeros when unreadable."""
    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory() as tmp:
        local = local_file(path, tmp)
        inp = oiio.ImageInput.open(local)
        if inp is None:
            oiio.geterror()
            return 0, 0, 0, "unreadable"
        try:
            spec = inp.spec()
            return spec.width, spec.height, spec.nchannels, str(spec.format)
        finally:
            inp.close()


def _resolved_color_space(authored: str, channels: int, fmt: str) -> str:
    """Hydra's reading of sourceColorSpace: auto is sRGB for 8-bit files with 3 or 4 channels."""
    if authored == "sRGB":
        return "sRGB"
    if authored == "auto":
        return "sRGB" if fmt == "uint8" and channels in (3, 4) else "raw"
    return "raw"


def _source_file(path: str, asset_path: str, color_space: str, cache: dict) -> SourceFile:
    key = path
    if key not in cache:
        data = read_asset(path)
        cache[key] = (xxhash.xxh3_128_hexdigest(data), len(data), _probe(path))
    digest, size, (w, h, c, fmt) = cache[key]
    return SourceFile(path, asset_path, digest, size, w, h, c, fmt, color_space,
                      _resolved_color_space(color_space, c, fmt))


def _job_name(material_path: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_.-]+", "_", material_path.rstrip("/").rsplit("/", 1)[-1]) or "material"
    name, n = base, 2
    while name.lower() in taken:
        name, n = f"{base}_{n}", n + 1
    taken.add(name.lower())
    return name


@dataclass
class _MaterialModel:
    """A scanned material's channels, specs and targets (before grouping into jobs)."""

    channels: list[ModelChannel]
    specs: list[tuple[str, str, str]]
    targets: list[tuple[str, str, ModelChannel, float, float, str]]  # target, input, key, scale, bias, cs
    sources: dict[str, SourceFile]
    wrap: str
    st: tuple[str, tuple[float, float], float, tuple[float, float]]
    warnings: list[str]


def _material_model(ms: MaterialScan, file_cache: dict) -> _MaterialModel:
    """Map a scanned material's texture inputs to model channels, texset specs and targets."""
    channels: list[ModelChannel] = []
    specs: list[tuple[str, str, str]] = []
    targets: list[tuple[str, str, ModelChannel, float, float, str]] = []
    sources: dict[str, SourceFile] = {}
    warnings = list(ms.warnings)
    wraps: set[str] = set()
    sts: list[tuple[str, tuple[float, float], float, tuple[float, float]]] = []
    for inp in ms.texture_inputs:
        tex = inp.texture
        assert tex is not None
        src = _source_file(tex.resolved_path, tex.asset_path, tex.source_color_space, file_cache)
        sources[src.path] = src
        uses = [u for u in ms.channel_uses if u.input == inp.name]
        if not uses:
            continue
        is_normal = inp.name == "normal" and tex.channel == "rgb"
        kind = "normal" if is_normal else "value"
        keys = [ModelChannel(u.file, u.channel, kind) for u in uses]
        new = [k for k in keys if k not in channels]
        if new:
            letters = "".join(k.channel for k in new)
            if is_normal and len(new) == 2:
                specs.append(("normal", src.path, "xy"))
            elif inp.name in _COLOR_SEMANTIC and tex.channel == "rgb" and len(new) == 3:
                specs.append((_COLOR_SEMANTIC[inp.name], src.path, letters))
            elif inp.name in _SCALAR_SEMANTICS and len(new) == 1 and len(keys) == 1:
                specs.append((inp.name, src.path, letters))
            else:
                specs.extend(("generic", src.path, k.channel) for k in new)
            channels.extend(new)
        if tex.source_color_space not in ("auto", "raw", "sRGB"):
            warnings.append(f"{inp.name}: unknown sourceColorSpace {tex.source_color_space!r}, read as raw")
        for u, key in zip(uses, keys):
            comp = "rgba".index(u.channel)
            s, b = float(tex.scale[comp]), float(tex.bias[comp])
            cs = src.resolved_color_space if u.channel != "a" else "raw"
            if is_normal:
                if cs == "sRGB":
                    warnings.append(f"{inp.name}: normal map colour space resolves to sRGB; modelled as raw")
                cs = "raw"
                s, b = s / 2.0, s / 2.0 + b  # the model stores 2 v - 1
            elif cs == "sRGB" and inp.name not in ("diffuseColor", "emissiveColor", "specularColor") \
                    and tex.source_color_space == "auto":
                warnings.append(f"{inp.name}: sourceColorSpace auto resolves to sRGB for this 8-bit file "
                                "(as in Hydra); the renderer decodes it as sRGB")
            targets.append((u.target, inp.name, key, s, b, cs))
        for w in tex.effective_wrap:
            if w not in ("repeat", "clamp"):
                warnings.append(f"{inp.name}: wrap mode {w!r} modelled as repeat")
        wraps.update(tex.effective_wrap)
        st = tex.st
        xf = st.transform
        sts.append((st.varname or "st", xf.scale if xf else (1.0, 1.0), xf.rotation if xf else 0.0,
                    xf.translation if xf else (0.0, 0.0)))
    wrap = "clamp" if wraps == {"clamp"} else "repeat"
    if len(set(sts)) > 1:
        warnings.append("textures use different st primvars or transforms; the model uses the first texture's")
    st = sts[0] if sts else ("st", (1.0, 1.0), 0.0, (0.0, 0.0))
    return _MaterialModel(channels, specs, targets, sources, wrap, st, list(dict.fromkeys(warnings)))


def _decoder_index(channels: Sequence[ModelChannel]) -> tuple[dict[ModelChannel, int], int | None]:
    """Decoder output index of every model channel (normal z inserted after normal y), and z's."""
    normal = [i for i, c in enumerate(channels) if c.kind == "normal"]
    ny = normal[1] if len(normal) == 2 else None
    index = {c: i + (1 if ny is not None and i > ny else 0) for i, c in enumerate(channels)}
    return index, (ny + 1 if ny is not None else None)


def _content_hash(specs, sources: Mapping[str, SourceFile], wrap: str, options: Mapping[str, Any]) -> str:
    preset = options["preset"]
    payload = {
        "bcfpipe": __version__,
        "specs": [[sem, sources[path].xxh3_128, ch] for sem, path, ch in specs],
        "wrap": wrap,
        "profile": options["profile"],
        "preset": preset,
        "schedule": asdict(PRESETS[preset]),
        "seed": options["seed"],
        "device": options["device"],
        "hidden": options["hidden"],
        "signed": options["signed"],
    }
    return xxhash.xxh3_128_hexdigest(json.dumps(payload, sort_keys=True).encode())


def _variants_dict(variants: Mapping[str, str] | Iterable[str] | None) -> dict[str, str]:
    if not variants:
        return {}
    if isinstance(variants, Mapping):
        return {str(k): str(v) for k, v in variants.items()}
    from .scan import ScanError, parse_variant

    try:
        return dict(parse_variant(v) for v in variants)
    except ScanError as exc:
        raise BuildError(str(exc)) from None


def _resolve_device_name(device: str) -> str:
    from .train import resolve_device

    try:
        return resolve_device(device).type
    except (ValueError, RuntimeError) as exc:
        raise BuildError(str(exc)) from None


def _instance_proxies(scene, variants: Mapping[str, str], paths: Sequence[str]) -> set[str]:
    """Which of ``paths`` are instance proxies on the composed stage (overrides cannot reach them)."""
    if not paths:
        return set()
    from .scan import apply_variants, open_stage

    stage = open_stage(scene)
    if variants:
        apply_variants(stage, variants)
    out = set()
    for p in paths:
        prim = stage.GetPrimAtPath(p)
        if prim and prim.IsInstanceProxy():
            out.add(p)
    return out


def plan(scene: str | os.PathLike, variants: Mapping[str, str] | Iterable[str] | None = None,
         all_materials: bool = False, profile: str = "auto", preset: str = DEFAULT_PRESET, seed: int = 0,
         device: str = "auto", hidden: int = 16, signed: bool = False) -> BuildPlan:
    """Scan ``scene`` and list what to train. Reads the source textures (to hash them) but writes
    nothing. Raises `BuildError` for an unreadable stage or bad options."""
    if profile not in PROFILE_NAMES:
        raise BuildError(f"unknown profile {profile!r}; choose from {', '.join(PROFILE_NAMES)}")
    if preset not in PRESETS:
        raise BuildError(f"unknown quality preset {preset!r}; choose from {', '.join(PRESETS)}")
    options = {"profile": profile, "preset": preset, "seed": int(seed), "device": _resolve_device_name(device),
               "hidden": int(hidden), "signed": bool(signed)}
    from .scan import ScanError, scan_stage

    vdict = _variants_dict(variants)
    try:
        scan: StageScan = scan_stage(scene, vdict or None, all_materials=all_materials)
    except ScanError as exc:
        raise BuildError(str(exc)) from None

    instanced = _instance_proxies(scene, vdict, [m.path for m in scan.materials if m.decision == "model"])
    file_cache: dict = {}
    plans: list[MaterialPlan] = []
    groups: dict[tuple, list[tuple[MaterialScan, _MaterialModel]]] = {}
    failed_plans: dict[str, MaterialPlan] = {}
    for ms in scan.materials:
        if ms.decision != "model" or ms.path in instanced:
            continue
        try:
            mm = _material_model(ms, file_cache)
        except Exception as exc:  # noqa: BLE001 - an unreadable file fails this material only
            failed_plans[ms.path] = MaterialPlan(ms.path, ms.aliases, "model", "failed",
                                                 f"cannot read textures: {_one_line(exc)}",
                                                 warnings=tuple(ms.warnings))
            continue
        key = (frozenset(mm.channels), mm.wrap)
        groups.setdefault(key, []).append((ms, mm))

    jobs: list[MaterialJob] = []
    material_job: dict[str, tuple[MaterialJob, _MaterialModel]] = {}
    taken: set[str] = set()
    for members in groups.values():
        rep = members[0][1]
        sources = {p: s for _, mm in members for p, s in mm.sources.items()}
        rep_sources = {p: sources[p] for p in dict.fromkeys(path for _, path, _ in rep.specs)}
        job = MaterialJob(
            name=_job_name(members[0][0].path, taken),
            materials=tuple(ms.path for ms, _ in members),
            specs=tuple(rep.specs),
            channels=tuple(rep.channels),
            sources=tuple(rep_sources.values()),
            wrap=rep.wrap,
            profile=profile, preset=preset, seed=options["seed"], device=options["device"],
            hidden=options["hidden"], signed=options["signed"],
            content_hash=_content_hash(rep.specs, rep_sources, rep.wrap, options),
        )
        jobs.append(job)
        for ms, mm in members:
            material_job[ms.path] = (job, mm)

    for ms in scan.materials:
        if ms.decision != "model":
            plans.append(MaterialPlan(ms.path, ms.aliases, "skip", ms.reason, ms.message,
                                      warnings=tuple(ms.warnings)))
            continue
        if ms.path in instanced:
            plans.append(MaterialPlan(ms.path, ms.aliases, "skip", "instanced",
                                      "inside an instance: instance proxies cannot take an API schema override",
                                      warnings=tuple(ms.warnings)))
            continue
        if ms.path in failed_plans:
            plans.append(failed_plans[ms.path])
            continue
        job, mm = material_job[ms.path]
        index, z = _decoder_index(job.channels)
        targets: list[TargetMap] = []
        for target, inp, key, s, b, cs in mm.targets:
            targets.append(TargetMap(target, inp, index[key], s, b, cs, key.file, key.channel))
            if target == "normal.y" and z is not None:
                targets.append(TargetMap("normal.z", inp, z, 1.0, 0.0, "raw", None, None))
        prim, scale, rot, trans = mm.st
        plans.append(MaterialPlan(
            ms.path, ms.aliases, "model", None, ms.message, job=job.name, targets=tuple(targets),
            fallback_surface=ms.surface_shader, st_primvar=prim, st_scale=tuple(scale), st_rotation=float(rot),
            st_translation=tuple(trans), sources=tuple(mm.sources), warnings=tuple(mm.warnings)))

    return BuildPlan(
        scene=scan.path, root_layer=scan.root_layer,
        variants=tuple(sorted(vdict.items())),
        variant_selections=tuple(tuple(v) for v in scan.variant_selections),
        all_materials=all_materials, up_axis=scan.up_axis, meters_per_unit=scan.meters_per_unit,
        default_prim=scan.default_prim, materials=tuple(plans), jobs=tuple(jobs), options=options,
        diagnostics=tuple(scan.composition_errors) + tuple(scan.diagnostics),
    )


# ---------------------------------------------------------------------------------------------
# execution


def cpu_count() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _gpu_count(device: str) -> int:
    if not device.startswith("cuda"):
        return 0
    import torch

    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def default_jobs(n_jobs: int, device: str = "cpu") -> int:
    """Worker count: one per GPU on CUDA, else one per core; never more than there are jobs."""
    gpus = _gpu_count(device)
    limit = gpus if gpus else cpu_count()
    return max(1, min(max(n_jobs, 1), limit))


@dataclass(frozen=True)
class JobResult:
    """What one job's worker reported."""

    name: str
    status: str  # built | failed
    reason: str | None
    seconds: float
    device: str
    threads: int
    result: dict = field(default_factory=dict)  # MaterialResult.to_dict() when built

    def to_dict(self) -> dict:
        return asdict(self)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    name = type(exc).__name__
    line = f"{name}: {text}" if text else name
    return line if len(line) <= 300 else line[:297] + "..."


class _Throttle:
    """Forwards a worker's training progress to the parent's queue, at most ~4 times a second."""

    def __init__(self, queue, name: str):
        self.queue, self.name, self.last_phase, self.last = queue, name, None, 0.0

    def __call__(self, p) -> None:
        now = time.monotonic()
        if p.phase == self.last_phase and now - self.last < 0.25 and p.step != p.steps:
            return
        self.last_phase, self.last = p.phase, now
        psnr = p.psnr if p.psnr == p.psnr and math.isfinite(p.psnr) else None
        self.queue.put({"event": "progress", "job": self.name, "phase": p.phase, "step": p.step,
                        "steps": p.steps, "psnr": psnr, "eta": p.eta, "elapsed": p.elapsed})

    def phase(self, phase: str) -> None:
        self.queue.put({"event": "progress", "job": self.name, "phase": phase, "step": 0, "steps": 0,
                        "psnr": None, "eta": None, "elapsed": None})


def run_job(job: Mapping[str, Any], out_dir: str, threads: int, device: str, queue=None) -> dict:
    """Train and export one job into ``out_dir`` (runs in a worker process; never raises).

    Returns a `JobResult` as a dict. Only this process's own thread settings are changed.
    """
    t0 = time.perf_counter()
    name = job.get("name", "?")
    try:
        if mp.parent_process() is not None:  # a worker process: keep the build's stdout clean (--json)
            try:
                sys.stdout.flush()
                os.dup2(2, 1)
            except OSError:
                pass
        import warnings

        warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad=True to a scalar")
        import torch

        torch.set_num_threads(max(1, threads))
        try:
            torch.set_num_interop_threads(1)
        except RuntimeError:
            pass
        import OpenImageIO as oiio

        oiio.attribute("threads", max(1, threads))
        from .material import fit_material, make_config
        from .texset import TextureSpec, load_texture_set

        mj = MaterialJob.from_dict(job)
        progress = _Throttle(queue, mj.name) if queue is not None else None
        if progress:
            progress.phase("load")
        with tempfile.TemporaryDirectory(prefix="bcfpipe-src-") as tmp:
            local = {path: local_file(path, tmp) for _, path, _ in mj.specs}
            ts = load_texture_set([TextureSpec(sem, local[path], ch) for sem, path, ch in mj.specs])
        prof, cfg = make_config(ts, profile=mj.profile, preset=mj.preset, device=device, seed=mj.seed,
                                hidden=mj.hidden, signed=mj.signed, wrap=mj.wrap, threads=max(1, threads))
        extra = {"bcfpipe_build": {"job": mj.name, "materials": list(mj.materials),
                                   "content_hash": mj.content_hash}}
        res, _ = fit_material(ts, out_dir, cfg, prof, progress, extra)
        _restore_sources(Path(out_dir) / "material.json", {v: k for k, v in local.items() if v != k})
        d = res.to_dict()
        d.pop("out", None)
        return JobResult(mj.name, "built", None, time.perf_counter() - t0, cfg.device, threads, d).to_dict()
    except BaseException as exc:  # noqa: BLE001 - a failing material must not stop the build
        return JobResult(name, "failed", _one_line(exc), time.perf_counter() - t0, device, threads).to_dict()


def _restore_sources(desc_path: Path, originals: Mapping[str, str]) -> None:
    """Name packaged textures by their package path in material.json, not by the temporary copy."""
    if not originals or not desc_path.exists():
        return
    desc = json.loads(desc_path.read_text())
    for out in desc.get("outputs", []):
        if out.get("source") in originals:
            out["source"] = originals[out["source"]]
    desc_path.write_text(json.dumps(desc, indent=2) + "\n")


def _drain(queue, progress: ProgressCallback | None) -> None:
    if queue is None:
        return
    import queue as queue_mod

    while True:
        try:
            ev = queue.get_nowait()
        except (queue_mod.Empty, EOFError, OSError):
            return
        if progress:
            progress(ev)


def _emit(progress: ProgressCallback | None, **event) -> None:
    if progress:
        progress(event)


def _run_pool(jobs: Sequence[MaterialJob], materials_dir: Path, workers: int, threads: int,
              devices: Sequence[str], executor: cf.Executor | None, queue,
              progress: ProgressCallback | None) -> tuple[dict[str, JobResult], list[MaterialJob]]:
    """Run ``jobs``; returns results and the jobs whose worker process died (to retry alone)."""
    results: dict[str, JobResult] = {}
    broken: list[MaterialJob] = []
    own = executor is None
    pool = executor or cf.ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"))
    try:
        futures = {}
        for i, job in enumerate(jobs):
            dev = devices[i % len(devices)]
            fut = pool.submit(run_job, job.to_dict(), str(materials_dir / job.name), threads, dev, queue)
            futures[fut] = (job, dev)
            _emit(progress, event="queued", job=job.name, materials=list(job.materials))
        pending = set(futures)
        while pending:
            done, pending = cf.wait(pending, timeout=0.2, return_when=cf.FIRST_COMPLETED)
            _drain(queue, progress)
            for fut in done:
                job, dev = futures[fut]
                try:
                    r = JobResult(**fut.result())
                except BrokenProcessPool:
                    broken.append(job)
                    continue
                except BaseException as exc:  # noqa: BLE001
                    r = JobResult(job.name, "failed", _one_line(exc), 0.0, dev, threads)
                results[job.name] = r
                _emit(progress, event="done", job=job.name, status=r.status, reason=r.reason,
                      psnr=r.result.get("psnr"), seconds=r.seconds)
    except BaseException:
        if own:
            pool.shutdown(wait=False, cancel_futures=True)
        raise
    if own:
        pool.shutdown(wait=True)
    _drain(queue, progress)
    return results, broken


def execute(jobs: Sequence[MaterialJob], materials_dir: str | os.PathLike, workers: int | None = None,
            executor: cf.Executor | None = None, progress: ProgressCallback | None = None,
            threads: int | None = None) -> dict[str, JobResult]:
    """Train every job into ``materials_dir/<job.name>/``; returns {job name: JobResult}.

    Each job runs in a worker process of a spawn-context ``ProcessPoolExecutor`` (or of
    ``executor``, anything with the concurrent.futures interface that runs `run_job`), with
    ``threads`` torch threads each (default ``config.DEFAULT_THREADS``). A job whose worker process
    dies is retried once in a fresh single-worker pool (so one crash cannot take others with it),
    then marked failed.
    ``progress`` receives event dicts: ``queued``, ``progress`` (phase, step, steps, psnr, eta) and
    ``done`` (status, reason, psnr, seconds).
    """
    materials_dir = Path(materials_dir)
    materials_dir.mkdir(parents=True, exist_ok=True)
    if not jobs:
        return {}
    device = jobs[0].device
    workers = max(1, int(workers)) if workers else default_jobs(len(jobs), device)
    threads = max(1, int(threads)) if threads else DEFAULT_THREADS
    gpus = _gpu_count(device)
    devices = [f"cuda:{i}" for i in range(gpus)] if gpus else [device]
    manager = mp.get_context("spawn").Manager() if progress else None
    try:
        queue = manager.Queue() if manager else None
        results, broken = _run_pool(jobs, materials_dir, workers, threads, devices, executor, queue, progress)
        for job in broken:
            retry, again = _run_pool([job], materials_dir, 1, threads, devices, None, queue, progress)
            results.update(retry)
            if again:
                results[job.name] = JobResult(job.name, "failed", "worker process died (out of memory?)",
                                              0.0, device, threads)
                _emit(progress, event="done", job=job.name, status="failed", reason=results[job.name].reason,
                      psnr=None, seconds=0.0)
    finally:
        if manager is not None:
            manager.shutdown()
    return {j.name: results[j.name] for j in jobs}


# ---------------------------------------------------------------------------------------------
# assembly


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
    from . import usdout

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
            {"file": usdout.relative_asset(s.path, final_out) if _package_split(s.path) is None else s.path,
             "asset_path": s.asset_path, "xxh3_128": s.xxh3_128, "size_bytes": s.size_bytes,
             "width": s.width, "height": s.height, "channels": s.channels, "format": s.format,
             "color_space": s.color_space, "resolved_color_space": s.resolved_color_space}
            for s in (sources[p] for p in mp_.sources if p in sources)]
        entry["targets"] = [
            {"target": t.target, "input": t.input, "channel": t.channel, "scale": t.scale, "bias": t.bias,
             "color_space": t.color_space,
             "source": (usdout.relative_asset(t.file, final_out) if t.file and _package_split(t.file) is None
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


# ---------------------------------------------------------------------------------------------
# build


@dataclass(frozen=True)
class BuildResult:
    """A finished build: where it is and what its manifest says."""

    out: Path
    root_layer: Path
    manifest: dict
    plan: BuildPlan

    @property
    def exit_code(self) -> int:
        return int(self.manifest["exit_code"])

    @property
    def ok(self) -> bool:
        return self.exit_code == EXIT_OK

    @property
    def failed(self) -> list[str]:
        return [m["path"] for m in self.manifest["materials"] if m["status"] == "failed"]


def _is_within(path: Path, folder: Path) -> bool:
    try:
        path.resolve().relative_to(folder.resolve())
        return True
    except ValueError:
        return False


def _is_bcf_output(folder: Path) -> bool:
    try:
        return json.loads((folder / MANIFEST).read_text()).get("format") == BUILD_FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def check_out(out: Path, force: bool, inputs: Iterable[str | os.PathLike]) -> None:
    """Refuse an OUT that would overwrite inputs, or a folder not written by bcfpipe (without force)."""
    for p in inputs:
        p = Path(str(p).split("[", 1)[0]) if _package_split(str(p)) else Path(p)
        if _is_within(p, out):
            raise BuildError(f"output folder {out} contains the input {p}; choose another -o")
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir():
        raise BuildError(f"output {out} exists and is not a folder")
    if force or _is_bcf_output(out) or not any(out.iterdir()):
        return
    raise BuildError(f"output folder {out} exists and was not written by bcfpipe (no {MANIFEST}); "
                     "use --force to replace it")


def _install(staging: Path, out: Path) -> None:
    """Move the finished staging folder to ``out`` (replacing an old build)."""
    old = None
    if out.exists() or out.is_symlink():
        old = out.parent / f".{out.name}.old-{uuid.uuid4().hex[:8]}"
        os.replace(out, old)
    os.replace(staging, out)
    if old is not None:
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:
            old.unlink(missing_ok=True)


def build(scene: str | os.PathLike, out: str | os.PathLike | None = None, *,
          variants: Mapping[str, str] | Iterable[str] | None = None, all_materials: bool = False,
          profile: str = "auto", preset: str = DEFAULT_PRESET, jobs: int | None = None, device: str = "auto",
          seed: int = 0, force: bool = False, progress: ProgressCallback | None = None,
          executor: cf.Executor | None = None, threads: int | None = None) -> BuildResult:
    """Build neural materials for ``scene`` into ``out`` (default ``<scene>.bcf/`` next to it); the
    Python twin of ``bcfpipe build``.

    ``variants``: {set: value} or ["set=value", ...]. ``jobs``: worker processes (default: one per
    core, or per GPU, at most one per job). ``threads``: torch threads per worker (default
    ``config.DEFAULT_THREADS``, 1). ``progress``: a callable receiving event dicts (see
    `execute`). Raises `BuildError` (exit code 2) before any training for bad input or a refused
    ``out``; per-material failures are reported in the result (``exit_code`` 1), never raised.
    """
    t0 = time.perf_counter()
    if jobs is not None and int(jobs) < 1:
        raise BuildError("--jobs must be at least 1")
    if threads is not None and int(threads) < 1:
        raise BuildError("--threads must be at least 1")
    scene_path = Path(scene)
    out_path = Path(out).resolve() if out is not None else default_out(scene_path)
    # Refuse early: before the scan reads every texture, and again once the sources are known.
    check_out(out_path, force, [scene_path])
    bplan = plan(scene_path, variants, all_materials, profile, preset, seed, device)
    check_out(out_path, force, [bplan.scene, *bplan.sources])
    out_path.parent.mkdir(parents=True, exist_ok=True)
    staging = out_path.parent / f".{out_path.name}.tmp-{uuid.uuid4().hex[:8]}"
    staging.mkdir()
    try:
        results = execute(bplan.jobs, staging / MATERIALS_DIR, workers=jobs, executor=executor, progress=progress,
                          threads=threads)
        manifest = assemble(bplan, results, staging, out_path, time.perf_counter() - t0)
        _install(staging, out_path)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return BuildResult(out_path, out_path / manifest["root_layer"], manifest, bplan)
