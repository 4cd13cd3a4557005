"""Step 1 of a build: the scanned scene as frozen, JSON-serialisable jobs, named by content hash."""
from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Iterable, Mapping

import xxhash

from bcfpipe.config import (CPU_PRESETS_LARGE, FIXED_T0_PRESETS, MODEL_FORMAT, PRESETS,
                            QUALITY_PRESETS, JobOptions, TrainingOptions, preset_for, resolve_profile, t0_of)
from bcfpipe.builder.options import Selection
from bcfpipe.errors import InputError
from bcfpipe.formats.images import FLOAT_TYPES
from bcfpipe.formats.vocabulary import T0, ColorSpace, Decision, wrap_axes
from bcfpipe.fit.rate import anchors_from_bench
from bcfpipe.scan.content import nonfinite_channels
from bcfpipe.scan.coverage import job_coverage
from bcfpipe.scan.density import density_options, job_size
from bcfpipe.scan.grouping import group_materials
from bcfpipe.scan.results import ScanError
from bcfpipe.scan.sources import SourceFile
from bcfpipe.scan.texture_sets import ConstantTarget, FoldedChannel, ModelChannel, decoder_index
from bcfpipe.texset.texture_set import SEMANTICS
from bcfpipe.train.devices import device_class

if TYPE_CHECKING:  # pxr and torch load lazily: `import bcfpipe` stays cheap
    from bcfpipe.scan.results import StageScan


OVERRIDES = "overrides.usda"
MATERIALS_DIR = "materials"

#: revision of the HDR output encoding (bcfpipe.texset.encoding), in the key of jobs with float sources;
#: 2: an HDR colour's classic group is BC6H_UF16 of its linear values, not BC1 (issue 50)
HDR_ENCODING = 2


class BuildError(InputError):
    """A build that cannot start: unreadable scene, bad option, or an OUT it must not replace."""


@dataclass(frozen=True)
class TargetMap:
    """One UsdPreviewSurface target of a material and the decoder output that drives it."""

    target: str  # diffuseColor.r, normal.x, roughness, ...
    input: str
    channel: int  # decoder output index (normal z included); -1: a constant, the value is ``bias``
    scale: float
    bias: float
    color_space: str  # "sRGB" or "raw"
    file: str | None  # None for the reconstructed normal.z
    file_channel: str | None


@dataclass(frozen=True)
class MaterialJob:
    """One training run (a texture set), shared by every material in ``materials``.

    Frozen and JSON-serialisable (`to_dict` / `from_dict`). ``options`` is the one record a worker
    trains from (`config.JobOptions`); ``content_hash`` covers everything the result depends on
    (`content_hash`): not paths, not the machine's thread count.
    """

    name: str
    materials: tuple[str, ...]
    specs: tuple[tuple[str, str, str], ...]  # (semantic, file, channels) for bcfpipe.texset
    channels: tuple[ModelChannel, ...]
    sources: tuple[SourceFile, ...]
    wrap: tuple[str, str]  # (S, T) addressing: repeat, clamp or mirror per axis
    options: JobOptions
    content_hash: str
    coverage: str | None = None  # packed level-0 mask at the job's size (bcfpipe.scan.coverage); None: all read
    covered_fraction: float | None = None
    anchors: tuple[tuple[str, str, float], ...] = ()  # --bench-data cells of this set: (profile, preset, psnr)
    vectors: tuple[tuple[str, tuple[int, ...]], ...] = ()  # TextureSet.vectors: colours its classic textures keep whole

    def to_dict(self) -> dict:
        return {**asdict(self), "options": self.options.to_json()}

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) the texture set trains at: the sources' common size, or the density cap's."""
        return job_size(self.sources, self.options.resolution)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "MaterialJob":
        d = dict(d)
        d["materials"] = tuple(d["materials"])
        d["wrap"] = tuple(str(w) for w in wrap_axes(d["wrap"]))
        d["specs"] = tuple(tuple(s) for s in d["specs"])
        d["channels"] = tuple(ModelChannel(**c) for c in d["channels"])
        d["sources"] = tuple(SourceFile(**s) for s in d["sources"])
        d["options"] = JobOptions.from_json(d["options"], "options")
        d["anchors"] = tuple(tuple(a) for a in d.get("anchors", ()))
        d["vectors"] = tuple((str(sem), tuple(int(c) for c in chans)) for sem, chans in d.get("vectors", ()))
        return cls(**d)


@dataclass(frozen=True)
class MaterialPlan:
    """What the build does with one scanned material."""

    path: str
    aliases: tuple[str, ...]
    decision: str  # model | constant | skip
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
    constants: tuple[ConstantTarget, ...] = ()  # inputs whose every channel is constant: authored as values
    folded: tuple[FoldedChannel, ...] = ()  # source channels that are not decoder outputs, and why

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
    options: JobOptions  # the build's, before any job's scene fields
    diagnostics: tuple[str, ...] = ()
    layers: tuple[str, ...] = ()  # every layer file the stage composed (for --depfile)
    folded_sources: tuple[SourceFile, ...] = ()  # files no job trains on: read for constants and duplicates

    @property
    def unused_classic(self) -> tuple[str, ...]:
        """The --classic semantics no job has a channel of (a typo, or a scene without them)."""
        have = {sem for j in self.jobs for sem, _, _ in j.specs}
        return tuple(s for s in (self.options.classic or ()) if s not in have)

    def job(self, name: str) -> MaterialJob:
        for j in self.jobs:
            if j.name == name:
                return j
        raise KeyError(name)

    @property
    def sources(self) -> dict[str, SourceFile]:
        return {s.path: s for s in (*(s for j in self.jobs for s in j.sources), *self.folded_sources)}

    def to_dict(self) -> dict:
        d = asdict(self)
        d["jobs"] = [j.to_dict() for j in self.jobs]
        d["options"] = self.options.to_json()
        return d


def _t0(sources: Mapping[str, SourceFile], options: JobOptions) -> int:
    """The T_0 side a job trains at: its profile, resolved against the set's size."""
    w, h = job_size(sources.values(), options.resolution)
    return resolve_profile(options.profile, max(w, h))[1][0]


def content_hash(specs, sources: Mapping[str, SourceFile], wrap, options: JobOptions,
                 coverage_digest: str | None = None, anchors: tuple = (), vectors: tuple = ()) -> str:
    """The job's cache key: `config.MODEL_FORMAT`, the job's record (``options.keyed()``: every
    field but those that change nothing trained) and its inputs: the bytes of each source file
    (its XXH3-128) with the semantic and channels read from it, the addressing, the coverage mask's
    digest, the --bench-data anchors, the schedules the record's preset names (and with
    --target-psnr every one it may pick), and for float sources the HDR encoding's revision. Not in
    it: paths, times, meshes and transforms, and the UsdUVTexture scale, bias and colour space, which
    the USD layer applies to the decoded values (the model learns the stored texels).
    """
    fixed = t0_of(options) == T0.PCA
    payload = {
        "model_format": MODEL_FORMAT,
        "options": options.keyed(),
        "specs": [[sem, sources[path].xxh3_128, ch] for sem, path, ch in specs],
        "wrap": [str(w) for w in wrap_axes(wrap)],
        "coverage": coverage_digest,
        "anchors": [list(a) for a in anchors],
        "schedule": asdict(preset_for(options.preset, _t0(sources, options), options.device, fixed)),
    }
    if any(sources[path].format in FLOAT_TYPES for _, path, _ in specs):
        payload["hdr_encoding"] = HDR_ENCODING  # float sources may hold HDR channels (texset/encoding.py)
    if vectors:  # colours a classic texture keeps in their slots' order (TextureSet.vectors)
        payload["vectors"] = [[sem, list(chans)] for sem, chans in vectors]
    if options.target_psnr is not None:  # rate control picks among every preset, from these predictions
        payload["schedules"] = {name: asdict(PRESETS[name]) for name in QUALITY_PRESETS}
        payload["schedules_large"] = {name: asdict(p) for name, p in CPU_PRESETS_LARGE.items()}
        if fixed:
            payload["schedules_fixed_t0"] = {name: asdict(p) for name, p in FIXED_T0_PRESETS.items()}
    return xxhash.xxh3_128_hexdigest(json.dumps(payload, sort_keys=True).encode())


def _variants_dict(variants: Mapping[str, str] | Iterable[str] | None) -> dict[str, str]:
    if not variants:
        return {}
    if isinstance(variants, Mapping):
        return {str(k): str(v) for k, v in variants.items()}
    from bcfpipe.scan.composition import parse_variants  # lazy: start-up

    try:
        return parse_variants(variants)
    except ScanError as exc:
        raise BuildError(str(exc)) from None


def _resolve_device_name(device: str) -> str:
    try:
        return device_class(device)
    except (ValueError, RuntimeError) as exc:
        raise BuildError(str(exc)) from None


def plan(scene: str | os.PathLike, training: TrainingOptions = TrainingOptions(),
         selection: Selection = Selection(), *, facts=None) -> BuildPlan:
    """Scan ``scene`` and list what to train with ``training`` for the materials ``selection``
    picks. Reads the source textures (to hash them) but writes nothing. ``selection.texel_density``
    (px/m) caps each job's resolution at the smallest power of two that meets it on every member's
    most demanding mesh (never above the source); ``selection.coverage`` trains on the texels the
    bound meshes read (bcfpipe.scan.coverage). ``facts``: a bcfpipe.cache.facts.FactsStore, so that
    only textures whose bytes changed are decoded. With ``training.target_psnr`` rate control
    chooses each job's profile and preset (bcfpipe.fit.rate), from the cells of
    ``selection.bench`` (a `bcfpipe bench` report) for the jobs whose sources it measured. Raises
    `BuildError` for an unreadable stage, a damaged source or a bad option."""
    texel_density, bench = selection.texel_density, selection.bench
    if texel_density is not None and not (texel_density > 0 and texel_density < float("inf")):
        raise BuildError(f"--texel-density must be a positive number of px/m, got {texel_density}")
    options = JobOptions.of(training, _resolve_device_name(training.device),
                            texel_density=float(texel_density) if texel_density is not None else None,
                            coverage=bool(selection.coverage))
    from bcfpipe.scan.stage import scan_stage  # lazy: start-up

    vdict = _variants_dict(selection.variants)
    all_materials = selection.all_materials
    try:
        scan: StageScan = scan_stage(scene, vdict or None, all_materials=all_materials,
                                     materials=tuple(selection.materials))
    except ScanError as exc:
        raise BuildError(str(exc)) from None

    file_cache: dict = {}
    grouping = group_materials(scene, vdict, scan.materials, file_cache, facts=facts)
    _refuse_bad_sources(grouping, file_cache, training.fix_nonfinite)
    jobs = [_job(g, options, bench) for g in grouping.groups]
    job_by_name = {j.name: j for j in jobs}
    plans = [_material_plan(ms, grouping, job_by_name) for ms in scan.materials]
    return BuildPlan(
        scene=scan.path, root_layer=scan.root_layer,
        variants=tuple(sorted(vdict.items())),
        variant_selections=tuple(tuple(v) for v in scan.variant_selections),
        all_materials=all_materials, up_axis=scan.up_axis, meters_per_unit=scan.meters_per_unit,
        default_prim=scan.default_prim, materials=tuple(plans), jobs=tuple(jobs), options=options,
        diagnostics=tuple(scan.composition_errors) + tuple(scan.diagnostics),
        layers=scan.layers,
        folded_sources=_folded_sources(grouping, jobs),
    )


def _job(g, options: JobOptions, bench: Mapping | None) -> MaterialJob:
    """The job of one group of materials that share a texture set: its record (the density cap
    applied), coverage mask and cache key."""
    rep = g.model
    sources = {p: s for mm in g.models for p, s in mm.sources.items()}
    rep_sources = {p: sources[p] for p in dict.fromkeys(path for _, path, _ in rep.specs)}
    job_options = density_options(options, g.models)
    packed = fraction = cov_digest = None
    if options.coverage:
        packed, fraction, cov_digest = job_coverage(g.models, job_size(rep_sources.values(), job_options.resolution),
                                                    rep.wrap)
    anchors = _bench_anchors(bench, rep.specs) if options.target_psnr is not None and bench is not None else ()
    vectors = _vectors(g)
    return MaterialJob(
        name=g.name, materials=g.materials, specs=tuple(rep.specs), channels=tuple(rep.channels),
        sources=tuple(rep_sources.values()), wrap=rep.wrap, options=job_options,
        content_hash=content_hash(rep.specs, rep_sources, rep.wrap, job_options, cov_digest, anchors, vectors),
        coverage=packed, covered_fraction=fraction, anchors=anchors, vectors=vectors,
    )


def _vectors(g) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """The colours the group's materials read through a UsdUVTexture's rgb whose set channels no
    colour spec holds in r, g, b order (issue 57): a folded duplicate (b equal to g) or a grey file
    leaves generic channels, which a classic layout would pack as scalars, where USD could no longer
    read the colour from one output. (semantic, the set channel of each slot), once each."""
    colours = {s.usd_input: s.name for s in SEMANTICS.values() if s.kind == "color"}
    rep = g.model
    index = {c: i for i, c in enumerate(rep.channels)}
    whole, k = set(), 0
    for sem, _, letters in rep.specs:  # a set's channels follow its specs, one per letter
        if sem in colours.values() and len(letters) == 3:
            whole.add((k, k + 1, k + 2))
        k += len(letters)
    out: dict[tuple[int, ...], str] = {}
    for mm in g.models:
        by_target = {t.target: t for t in mm.targets}
        for name, sem in colours.items():
            comps = [by_target.get(f"{name}.{c}") for c in "rgb"]
            if all(t is not None and t.channel in index for t in comps):
                chans = tuple(index[t.channel] for t in comps)
                if chans not in whole:
                    out.setdefault(chans, sem)
    return tuple((sem, chans) for chans, sem in out.items())


def _material_plan(ms, grouping, job_by_name: Mapping[str, MaterialJob]) -> MaterialPlan:
    """What the build does with one scanned material: skip it, author its constants, or map its
    inputs to its job's decoder outputs."""
    decision, reason, message = grouping.outcome(ms)
    if decision == Decision.SKIP or reason == "failed":
        return MaterialPlan(ms.path, ms.aliases, decision, reason, message, warnings=tuple(ms.warnings))
    if decision == Decision.CONSTANT:
        mm = grouping.constant[ms.path]
        return MaterialPlan(
            ms.path, ms.aliases, Decision.CONSTANT, None, message,
            fallback_surface=ms.surface_shader, sources=tuple(mm.sources), warnings=tuple(mm.warnings),
            constants=tuple(mm.constants), folded=tuple(mm.folded))
    group, mm = grouping.group_of(ms.path)
    job = job_by_name[group.name]
    index, z = decoder_index(job.channels)
    targets: list[TargetMap] = []
    for t in mm.targets:
        targets.append(TargetMap(t.target, t.input, index[t.channel], t.scale, t.bias, t.color_space,
                                 t.channel.file, t.channel.channel))
        if t.target == "normal.y" and z is not None:
            targets.append(TargetMap("normal.z", t.input, z, 1.0, 0.0, ColorSpace.RAW, None, None))
    modelled_inputs = {t.input for t in targets}
    # a constant component of an input that is otherwise modelled stays a target: channel -1
    targets += [TargetMap(c.target, c.input, -1, 0.0, c.value, ColorSpace.RAW, c.file, c.file_channel)
                for c in mm.constants if c.input in modelled_inputs]
    prim, scale, rot, trans = mm.st
    return MaterialPlan(
        ms.path, ms.aliases, Decision.MODEL, None, ms.message, job=job.name, targets=tuple(targets),
        fallback_surface=ms.surface_shader, st_primvar=prim, st_scale=tuple(scale), st_rotation=float(rot),
        st_translation=tuple(trans), sources=tuple(mm.sources), warnings=tuple(mm.warnings),
        constants=tuple(c for c in mm.constants if c.input not in modelled_inputs), folded=tuple(mm.folded))


def source_problems(grouping, file_cache: dict, fix_nonfinite: bool = False) -> list[str]:
    """Why a build refuses its sources, one line each: a damaged file, or a float file with NaN/Inf
    texels (without --fix-nonfinite). `scan` asks the same (its ``file_cache`` read the texels)."""
    problems = list(dict.fromkeys(grouping.unreadable.values()))
    if not fix_nonfinite:
        models = [*(mm for g in grouping.groups for mm in g.models), *grouping.constant.values()]
        for path in dict.fromkeys(p for mm in models for p in mm.sources):
            bad = nonfinite_channels(path, file_cache)
            if bad:
                problems.append(f"{path}: NaN/Inf texels in channel(s) {', '.join(bad)}; "
                                "use --fix-nonfinite to replace them")
    return problems


def refusal(problems: list[str]) -> BuildError:
    """The one-line error (exit code 2) that `problems` (`source_problems`, not empty) make."""
    more = f" (and {len(problems) - 1} more problem(s) with other sources)" if len(problems) > 1 else ""
    return BuildError(problems[0] + more)


def _refuse_bad_sources(grouping, file_cache: dict, fix_nonfinite: bool) -> None:
    """Refuse bad sources before anything trains: one line naming the user's file, exit code 2
    (maketx --checknan)."""
    problems = source_problems(grouping, file_cache, fix_nonfinite)
    if problems:
        raise refusal(problems)


def _bench_anchors(bench: Mapping, specs) -> tuple[tuple[str, str, float], ...]:
    """The bench report's measured cells for a job, matched by source file names and channels."""
    names = [f"{sem}={os.path.basename(path)}:{ch}" for sem, path, ch in specs]
    return tuple(sorted((p, q, v) for (p, q), v in anchors_from_bench(bench, names).items()))


def _folded_sources(grouping, jobs: Iterable[MaterialJob]) -> tuple[SourceFile, ...]:
    """Files the materials read that no job trains on (constant or duplicate channels): the build
    depends on them all the same."""
    trained = {s.path for j in jobs for s in j.sources}
    models = [*(mm for g in grouping.groups for mm in g.models), *grouping.constant.values()]
    found = {p: s for mm in models for p, s in mm.sources.items() if p not in trained}
    return tuple(found[p] for p in sorted(found))
