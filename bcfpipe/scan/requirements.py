"""What a scene requires (issue #18, item 5): per material, the outputs kept and folded, the texel
density, the profile a build would choose and the bytes it would write; and the total against
modelling everything (no folding, no density cap). `bcfpipe scan` prints it; its JSON keys are
listed in docs/build.md."""
from __future__ import annotations

from dataclasses import replace

from bcfpipe.formats.vocabulary import Decision, FeatureFormat, Layout
from bcfpipe.config import DEFAULT_HIDDEN, DEFAULT_PROFILE, LAYER_CHANNELS_OF, N_LAYERS, JobOptions, resolve_profile
from bcfpipe.formats.sizes import neural_bytes
from bcfpipe.formats.images import FLOAT_TYPES
from bcfpipe.scan.coverage import job_coverage
from bcfpipe.scan.density import density_options, job_size
from bcfpipe.scan.grouping import Grouping
from bcfpipe.scan.texture_sets import MaterialModel, decoder_index

def _job(mm: MaterialModel, members, options: JobOptions, predict=None) -> dict:
    """What `bcfpipe build` would do with this texture set, by the rules `plan` applies."""
    o = density_options(options, members)
    spec_sources = [mm.sources[p] for p in dict.fromkeys(path for _, path, _ in mm.specs)]
    size = max(job_size(spec_sources, None))
    w, h = job_size(spec_sources, o.resolution)
    side = max(w, h)
    profile, res = resolve_profile(o.profile, side) if side else (o.profile, ())
    n_out = len(decoder_index(mm.channels)[0]) if mm.channels else 0
    lows = [m.density.lowest_density for m in members if m.density and m.density.lowest_density]
    reached = min(lows) * side / size if lows and size else None
    covered = None
    if side:
        _, covered, _ = job_coverage(members, (w, h), mm.wrap)
        covered = 1.0 if covered is None and all(m.density and m.density.meshes and not m.density.notes
                                                 for m in members) else covered
    pred = None
    if side and n_out and predict is not None:  # what the default layout weighs, the bytes it can ship
        floats = [p for p, s in mm.sources.items() if s.format in FLOAT_TYPES]
        pred = predict(tuple(mm.specs), floats, w, h, o)
    neural = neural_bytes(res, N_LAYERS * LAYER_CHANNELS_OF[FeatureFormat(o.features)], o.hidden,
                          n_out) if res and n_out else 0
    return {"resolution": side, "width": w, "height": h, "profile": profile, "capped": o.resolution is not None,
            "texel_density_reached": reached, "covered_fraction": covered,
            "layout": pred.to_json() if pred else None,
            "estimated_min_bytes": pred.min_bytes if pred else neural,
            "estimated_bytes": pred.max_bytes if pred else neural}


def requirements(grouping: Grouping, everything: Grouping, profile: str = DEFAULT_PROFILE,
                 hidden: int = DEFAULT_HIDDEN, texel_density: float | None = None, predict=None) -> dict:
    """{"materials": {path: ...}, "totals": ...} for ``grouping`` (folded) against ``everything``
    (the same scan grouped without folding). ``predict``: `bcfpipe.layout.predict.predict_specs`
    (passed in: scan comes before layout), which sizes each set as the default layout ships it;
    without it a set is sized all neural."""
    options = JobOptions(profile=profile, preset="standard", device="cpu", hidden=hidden,
                         texel_density=texel_density, layout=Layout.AUTO)  # the build's default
    out: dict[str, dict] = {}
    total = low = 0
    for g in grouping.groups:
        job = _job(g.model, g.models, options, predict)
        total += job["estimated_bytes"]
        low += job["estimated_min_bytes"]
        for path, mm in zip(g.materials, g.models):
            out[path] = {"decision": Decision.MODEL, "texture_set": g.name, "outputs": len(mm.channels),
                         "folded": [f.to_dict() for f in mm.folded],
                         "density": mm.density.to_dict() if mm.density else None, **job,
                         "estimated_bytes": job["estimated_bytes"] if path == g.materials[0] else 0,
                         "estimated_min_bytes": job["estimated_min_bytes"] if path == g.materials[0] else 0}
    for path, mm in grouping.constant.items():
        out[path] = {"decision": Decision.CONSTANT, "texture_set": None, "outputs": 0,
                     "folded": [f.to_dict() for f in mm.folded],
                     "density": mm.density.to_dict() if mm.density else None, "resolution": 0, "width": 0, "height": 0,
                     "profile": None,
                     "capped": False, "texel_density_reached": None, "covered_fraction": None,
                     "layout": None, "estimated_min_bytes": 0, "estimated_bytes": 0}
    plain = replace(options, texel_density=None)
    every = sum(_job(g.model, g.models, plain, predict)["estimated_bytes"] for g in everything.groups)
    return {"materials": out, "totals": {
        "texture_sets": len(grouping.groups), "constant_materials": len(grouping.constant),
        "estimated_bytes": total, "estimated_min_bytes": low, "everything_texture_sets": len(everything.groups),
        "everything_estimated_bytes": every}}
