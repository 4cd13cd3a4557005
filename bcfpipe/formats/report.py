"""The build report: what ``bcfpipe build --json`` prints on stdout, one JSON object.

Unlike manifest.json (the build's deterministic description, written into OUT), the report says
what this run did: cache hits and misses, times, and which files it wrote. Its key names are a
fixed interface for build tools (schemas/report.schema.json); new keys may be added, none renamed.
"""
from __future__ import annotations

from dataclasses import dataclass

from bcfpipe.formats.vocabulary import CacheUse
from bcfpipe.formats.manifest import Folded, LayoutChoice
from bcfpipe.formats.record import Record, optional

FORMAT = "bcfpipe-build-report"
FORMAT_VERSION = 1
CACHE_STATES = (CacheUse.HIT, CacheUse.MISS)


@dataclass(frozen=True)
class MaterialReport(Record):
    """One material: its status, whether its trained material came from the cache, and its
    figures (PSNR of the exported files, per mip too; sizes; times)."""

    path: str
    status: str
    reason: str | None
    job: str | None
    cache: str | None
    psnr: float | None
    psnr_per_mip: tuple[float, ...] | None
    train_seconds: float | None
    seconds: float | None
    total_bytes: int | None
    files: tuple[str, ...]
    folded: tuple[Folded, ...] = ()
    attempts: int | None = optional()  # only when its job ran more than once (a worker died)
    layout: LayoutChoice | None = optional()  # --layout auto: what was chosen against BC@R, and why
    encode_seconds: float | None = None  # BC@R and its repacks encoded and measured (a layout fit), apart from train


@dataclass(frozen=True)
class CacheReport(Record):
    """The cache this run used: where it is, and how its lookups went."""

    enabled: bool
    root: str | None
    hits: int
    misses: int
    damaged: tuple[str, ...]


@dataclass(frozen=True)
class ReportTotals(Record):
    """Counts, sizes and times of this run."""

    materials: int
    built: int
    constant: int
    failed: int
    skipped: int
    jobs: int
    trained: int
    cached: int
    train_seconds: float
    wall_seconds: float
    total_bytes: int
    written_files: int
    encode_seconds: float = 0.0  # BC@R and repacks encoded and measured in this run (sum over jobs)


@dataclass(frozen=True)
class BuildReport(Record):
    """What one ``bcfpipe build`` run did."""

    out: str
    root_layer: str
    manifest: str
    exit_code: int
    cache: CacheReport
    totals: ReportTotals
    materials: tuple[MaterialReport, ...]
    written: tuple[str, ...]
    depfile: str | None = None
    verify_exit_code: int | None = optional()
    executor: str | None = optional()  # "ray" when the jobs ran on Ray; absent for the local pool
    format: str = FORMAT
    format_version: int = FORMAT_VERSION

    _ORDER = ("format", "format_version", "out", "root_layer", "manifest", "exit_code")
