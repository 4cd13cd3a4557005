"""``manifest.json``: what a ``bcfpipe build`` wrote, material by material.

The contract is this module's records and schemas/manifest.schema.json, which says what each key
means. The only writer is :func:`bcfpipe.builder.assemble.assemble`; readers (``bcfpipe verify``,
re-runs of ``bcfpipe build``) go through :func:`read`. Paths are relative to the build folder.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bcfpipe import __version__
from bcfpipe.formats.vocabulary import Status
from bcfpipe.formats.atomic import atomic_write
from bcfpipe.formats.record import Record, optional, read as read_record

FORMAT = "bcfpipe-build"
FORMAT_VERSION = 6
# 4 added optional keys only (options.target_psnr, materials' preset, target); 5 dropped each
# material's shared_with (jobs[].materials says it once: the list grew as materials² / jobs); 6
# records ``options`` as the job record writes itself (`bcfpipe.config.JobOptions.recorded`): every
# field, a None one too, where 5 left some out
COMPATIBLE_VERSIONS = (3, 4, 5)
FILE = "manifest.json"
WEIGHTS = "weights.bin"

STATUSES = tuple(Status)


@dataclass(frozen=True)
class Source(Record):
    """A texture file a material reads: ``file`` relative to the build folder (or package.usdz[inner])."""

    file: str
    asset_path: str
    xxh3_128: str
    size_bytes: int
    width: int
    height: int
    channels: int
    format: str
    color_space: str
    resolved_color_space: str


@dataclass(frozen=True)
class Target(Record):
    """A UsdPreviewSurface input channel and the decoder output ``channel`` that drives it."""

    target: str
    input: str
    channel: int
    scale: float
    bias: float
    color_space: str
    source: str | None
    source_channel: str | None


@dataclass(frozen=True)
class Constant(Record):
    """A UsdPreviewSurface input channel whose texture channel is constant, or whose texture gives
    its fallback (``source`` empty): the value authored for it."""

    target: str
    input: str
    value: float
    source: str
    source_channel: str


@dataclass(frozen=True)
class Folded(Record):
    """A source channel that is not a decoder output: ``constant`` (its stored ``value``), ``unread``
    (read at one point, whose ``value`` replaces it), ``no-alpha`` (the ``a`` of a file without
    alpha: 1) or ``duplicate`` (its texels equal ``same_as_source``'s ``same_as_channel``)."""

    source: str
    channel: str
    reason: str
    value: float | None = optional()
    same_as_source: str | None = optional()
    same_as_channel: str | None = optional()


@dataclass(frozen=True)
class Quality(Record):
    """Quality of a decoded texture set against its reference (bcfpipe.texset.metrics computes it):
    PSNR in dB over the mips counted in the mean and per mip (mip 0 first), per channel group;
    SSIM and FLIP at mip 0."""

    psnr: float
    psnr_per_mip: tuple[float, ...]
    psnr_per_group: dict[str, float]
    ssim: float | None
    ssim_per_group: dict[str, float]
    flip: float | None
    flip_per_group: dict[str, float]
    mips_in_mean: int
    covered_fraction: float | None = optional()
    psnr_covered: float | None = optional()
    psnr_per_mip_covered: tuple[float, ...] | None = optional()


@dataclass(frozen=True)
class Metrics(Record):
    """Quality of the exported files (DDS + fp16 decoder through onnxruntime) against the source."""

    psnr: float | None
    ssim: float | None
    flip: float | None
    float_psnr: float | None
    detail: Quality | None


@dataclass(frozen=True)
class Sizes(Record):
    """Bytes on disk of a built material, and of the sources it replaces."""

    features_bytes: int
    weights_bytes: int
    total_bytes: int
    source_bytes: int
    classic_bytes: int = 0  # --layout auto: the classic BC textures it ships


@dataclass(frozen=True)
class Outputs(Record):
    """Where a built material's files are: its folder and its record in the combined weights.bin
    (none for a layout of classic textures only)."""

    folder: str
    weights_index: int | None
    weights_offset: int | None
    weights_size: int | None


@dataclass(frozen=True)
class LayoutChoice(Record):
    """What --layout auto or --classic chose for a material (the folder's layout.json has every candidate)."""

    chosen: str
    classic: tuple[str, ...]
    profile: str | None
    reason: str
    size_bytes: int
    bc_size_bytes: int
    psnr: float
    bc_psnr: float
    margin_per_mip_db: tuple[float, ...]
    worst_margin_db: float | None = optional()  # over the mips the rule counts (>= 4 texels a side)
    # the shipped normal's (mean, p99) angle in degrees at mip 0 as it is read (layout.json normal_angular_error)
    normal_angle_deg: tuple[float, float] | None = optional()


@dataclass(frozen=True)
class RateAttempt(Record):
    """One training that rate control ran (bcfpipe.fit.rate)."""

    profile: str
    preset: str
    why: str  # probe, predicted, climb or best effort
    predicted_psnr: float | None
    psnr: float
    size_bytes: int
    train_seconds: float


@dataclass(frozen=True)
class RateControl(Record):
    """What --target-psnr chose for a material: the target, whether it was met, every attempt."""

    target_psnr: float
    met: bool
    psnr: float
    profile: str
    preset: str
    anchors: str  # probe or bench
    predicted_max: float | None
    seconds: float
    attempts: tuple[RateAttempt, ...]
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class Material(Record):
    """One material of the scene and what became of it (status built, constant, failed or skipped)."""

    path: str
    status: str
    aliases: tuple[str, ...] = ()
    job: str | None = None
    reason: str | None = None
    message: str = ""
    sources: tuple[Source, ...] = ()
    targets: tuple[Target, ...] = ()
    constants: tuple[Constant, ...] = ()
    folded: tuple[Folded, ...] = ()
    metrics: Metrics | None = None
    sizes: Sizes | None = None
    outputs: Outputs | None = None
    profile: str | None = optional()
    resolutions: tuple[int, ...] | None = optional()
    device: str | None = None
    warnings: tuple[str, ...] = ()
    preset: str | None = optional()
    target: RateControl | None = optional()
    layout: LayoutChoice | None = optional()  # --layout auto only

    _ORDER = ("path", "aliases", "job", "status")


@dataclass(frozen=True)
class Job(Record):
    """One training run, shared by ``materials``; ``content_hash`` names its inputs and settings."""

    name: str
    materials: tuple[str, ...]
    content_hash: str
    status: str
    reason: str | None
    device: str | None
    weights_index: int | None


@dataclass(frozen=True)
class WeightsRecord(Record):
    """One record of the combined weights.bin (bcfpipe.formats.weights)."""

    index: int
    offset: int
    size_bytes: int
    n_hidden: int
    n_out: int
    job: str


@dataclass(frozen=True)
class VariantSelection(Record):
    """A variant selection authored into the root layer."""

    prim: str
    set: str
    value: str


@dataclass(frozen=True)
class Stage(Record):
    """Stage metadata carried over to the root layer."""

    up_axis: str
    meters_per_unit: float
    default_prim: str | None


@dataclass(frozen=True)
class Totals(Record):
    """Counts and sizes over the whole build."""

    materials: int
    built: int
    constant: int
    failed: int
    skipped: int
    jobs: int
    trained: int
    features_bytes: int
    weights_bytes: int
    total_bytes: int
    source_bytes: int


@dataclass(frozen=True)
class Manifest(Record):
    """The manifest.json at the top of a build folder. It holds no times and no absolute paths:
    the same inputs and options give the same bytes (a build's timings are in its report)."""

    scene: str
    root_layer: str
    materials: tuple[Material, ...]
    overrides_layer: str = "overrides.usda"
    weights: str = WEIGHTS
    variants: tuple[tuple[str, ...], ...] = ()
    variant_selections: tuple[VariantSelection, ...] = ()
    all_materials: bool = False
    options: dict[str, Any] | None = None  # the build's job record, as its own to_json() writes it
    stage: Stage | None = None
    jobs: tuple[Job, ...] = ()
    weights_table: tuple[WeightsRecord, ...] = ()
    totals: Totals | None = None
    diagnostics: tuple[str, ...] = ()
    exit_code: int = 0
    format: str = FORMAT
    format_version: int = FORMAT_VERSION
    bcfpipe_version: str = field(default_factory=lambda: _version())

    _ORDER = ("format", "format_version", "bcfpipe_version", "scene", "root_layer", "overrides_layer", "weights",
              "variants", "variant_selections", "all_materials", "options", "stage", "materials")

    def built(self) -> list[Material]:
        return [m for m in self.materials if m.status == Status.BUILT]

    def failed(self) -> list[str]:
        return [m.path for m in self.materials if m.status == Status.FAILED]


def _version() -> str:
    return __version__


def read(folder: str | os.PathLike) -> Manifest:
    """``folder/manifest.json``; a missing, foreign or malformed file raises FormatError."""
    return read_record(Manifest, Path(folder) / FILE, FORMAT, FORMAT_VERSION, COMPATIBLE_VERSIONS, _upgrade)


def _upgrade(data: dict) -> dict:
    """A version 3, 4 or 5 manifest in version 6's keys (``options`` as the record those wrote)."""
    for m in data.get("materials") or ():
        if isinstance(m, dict):
            m.pop("shared_with", None)
    return data


def is_manifest(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` holds a bcfpipe build manifest (of any version)."""
    try:
        return json.loads((Path(folder) / FILE).read_text()).get("format") == FORMAT
    except (OSError, ValueError, AttributeError):
        return False


def write(folder: str | os.PathLike, manifest: Manifest) -> Path:
    path = Path(folder) / FILE
    atomic_write(path, manifest.dumps().encode())
    return path
