"""The build report (``bcfpipe build --json``): what this run did, from the manifest it wrote and
what each job's worker or the cache reported."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

from bcfpipe.formats.vocabulary import CacheUse, Status
from bcfpipe.builder.executor import JobResult
from bcfpipe.formats import manifest as mfst
from bcfpipe.formats import report as rep


def material_files(m: mfst.Material, manifest: mfst.Manifest, files: Sequence[str]) -> tuple[str, ...]:
    """A built material's files in OUT: its folder's files, then the shared ones it needs."""
    if m.status == Status.CONSTANT:
        return (manifest.overrides_layer, manifest.root_layer)
    if m.outputs is None:
        return ()
    own = sorted(f for f in files if f.startswith(m.outputs.folder + "/"))
    return (*own, manifest.weights, manifest.overrides_layer, manifest.root_layer)


def headline_psnr(m: mfst.Material) -> float | None:
    """The PSNR a user reads: over the texels the scene reads when a coverage mask applied, else
    over every texel."""
    q = m.metrics.detail if m.metrics else None
    if q is not None and q.psnr_covered is not None:
        return q.psnr_covered
    return m.metrics.psnr if m.metrics else None


@dataclass(frozen=True)
class BuildFacts:
    """What a build did besides its manifest and its jobs' results, as the report states it: OUT
    as given (``out``), every file in it (``files``) and those this build wrote (``written``), the
    cache folder (None: no cache) and the damaged entries it skipped, the wall time, the depfile
    written (or None) and the executor ("local" is left out of the report)."""

    out: str
    files: Sequence[str]
    written: Sequence[str]
    cache_root: str | None
    damaged: Sequence[str]
    wall_seconds: float
    depfile: str | None
    executor: str = "local"


def make_report(manifest: mfst.Manifest, results: Mapping[str, JobResult], facts: BuildFacts) -> rep.BuildReport:
    """The build report of ``manifest``, with each job's ``results`` and the run's ``facts``."""
    out, files, written = facts.out, facts.files, facts.written
    mats = []
    for m in manifest.materials:
        r = results.get(m.job) if m.job else None
        q = m.metrics.detail if m.metrics else None
        res = r.result if r is not None and r.status == Status.BUILT else None
        train = res.train_seconds if res is not None else None
        encode = res.encode_seconds if res is not None else None
        mats.append(rep.MaterialReport(
            path=m.path, status=m.status, reason=m.reason, job=m.job,
            cache=r.cache if r is not None and m.status == Status.BUILT else None,
            psnr=headline_psnr(m), psnr_per_mip=(q.psnr_per_mip_covered or q.psnr_per_mip) if q else None,
            train_seconds=round(train, 3) if train is not None else None,
            seconds=round(r.seconds, 3) if r is not None else None,
            total_bytes=m.sizes.total_bytes if m.sizes else None,
            files=material_files(m, manifest, files), folded=m.folded,
            attempts=r.attempts if r is not None and r.attempts > 1 else None, layout=m.layout,
            encode_seconds=round(encode, 3) if encode is not None else None))
    built = [r for r in results.values() if r.status == Status.BUILT]
    hits = sum(1 for r in built if r.cache == CacheUse.HIT)
    trained = [r.result for r in built if r.cache != CacheUse.HIT and r.result is not None]
    t = manifest.totals
    return rep.BuildReport(
        out=out, root_layer=str(Path(out) / manifest.root_layer), manifest=str(Path(out) / mfst.FILE),
        exit_code=manifest.exit_code,
        cache=rep.CacheReport(facts.cache_root is not None, facts.cache_root, hits,
                              sum(1 for r in results.values() if r.cache == CacheUse.MISS), tuple(facts.damaged)),
        totals=rep.ReportTotals(
            materials=t.materials, built=t.built, constant=t.constant, failed=t.failed, skipped=t.skipped, jobs=t.jobs,
            trained=len(trained), cached=hits,
            train_seconds=round(sum(t.train_seconds for t in trained), 3),
            wall_seconds=round(facts.wall_seconds, 3), total_bytes=t.total_bytes, written_files=len(written),
            encode_seconds=round(sum(t.encode_seconds or 0.0 for t in trained), 3)),
        materials=tuple(mats), written=tuple(written), depfile=facts.depfile,
        executor=facts.executor if facts.executor != "local" else None)
