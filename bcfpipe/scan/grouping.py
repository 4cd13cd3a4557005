"""The modelled materials of a scan grouped by texture set: materials whose channels and
addressing are identical train once (one job), and the one outcome (model, constant or skip, with
its reason) that `scan`, `plan` and `build` all report for each material."""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Mapping, Sequence

from bcfpipe.errors import one_line
from bcfpipe.formats.images import ImageReadError
from bcfpipe.formats.vocabulary import Decision
from bcfpipe.scan.texture_sets import Canonical, MaterialModel, material_model

if TYPE_CHECKING:
    from bcfpipe.scan.results import MaterialScan


def instance_proxies(scene, variants: Mapping[str, str], paths: Sequence[str]) -> set[str]:
    """Which of ``paths`` are instance proxies on the composed stage (overrides cannot reach them)."""
    if not paths:
        return set()
    from bcfpipe.scan.composition import apply_variants, captured_diagnostics, open_stage  # lazy: start-up

    with captured_diagnostics():  # the scan reported them already: not again, raw, on stderr
        stage = open_stage(scene)
        if variants:
            apply_variants(stage, variants)
    out = set()
    for p in paths:
        prim = stage.GetPrimAtPath(p)
        if prim and prim.IsInstanceProxy():
            out.add(p)
    return out


INSTANCED_MESSAGE = "inside an instance: instance proxies cannot take an API schema override"


def job_name(material_path: str, taken: set[str]) -> str:
    """A folder-safe, case-insensitively unique name for the texture set first used by ``material_path``."""
    base = re.sub(r"[^A-Za-z0-9_.-]+", "_", material_path.rstrip("/").rsplit("/", 1)[-1]) or "material"
    name, n = base, 2
    while name.lower() in taken:
        name, n = f"{base}_{n}", n + 1
    taken.add(name.lower())
    return name


@dataclass(frozen=True)
class TextureSetGroup:
    """Materials whose texture sets are identical (same files and channels, same addressing):
    one training job serves them all. ``models`` are the members' own models, in ``materials`` order."""

    name: str
    materials: tuple[str, ...]
    models: tuple[MaterialModel, ...]

    @property
    def model(self) -> MaterialModel:
        """The representative: the first member's channels, specs and addressing."""
        return self.models[0]

    def to_dict(self) -> dict:
        m = self.model
        return {"name": self.name, "materials": list(self.materials), "wrap": m.wrap,
                "channels": [{"file": c.file, "channel": c.channel, "kind": c.kind} for c in m.channels],
                "folded": [f.to_dict() for f in m.folded]}


@dataclass(frozen=True)
class Grouping:
    """The modelled materials of a scan, as texture-set groups; ``instanced`` ones cannot be
    overridden, ``failed`` ones ({path: message}) had unreadable textures, and ``constant`` ones
    ({path: model}) have only constant channels, so their values replace them and nothing trains.
    ``unreadable`` ({path: message}, a subset of ``failed``) are those whose image is damaged or
    missing: the user's to fix, and a build refuses them (exit code 2)."""

    groups: tuple[TextureSetGroup, ...]
    instanced: frozenset[str]
    failed: Mapping[str, str]
    constant: Mapping[str, MaterialModel] = field(default_factory=dict)  # every channel folded: nothing to train
    unreadable: Mapping[str, str] = field(default_factory=dict)

    def model_of(self, material: str) -> MaterialModel | None:
        """The material's model (grouped or constant), None when it is not modelled."""
        if material in self.constant:
            return self.constant[material]
        try:
            return self.group_of(material)[1]
        except KeyError:
            return None

    def outcome(self, ms: "MaterialScan") -> tuple[str, str | None, str]:
        """(decision, reason, message) of a scanned material: the one answer `scan`, `plan` and
        `build` all give. A skip keeps the scan's reason; ``instanced`` skips; ``failed`` is a
        material to model whose textures could not be read."""
        if ms.decision != Decision.MODEL:
            return Decision.SKIP, ms.reason, ms.message
        if ms.path in self.instanced:
            return Decision.SKIP, "instanced", INSTANCED_MESSAGE
        if ms.path in self.failed:
            return Decision.MODEL, "failed", self.failed[ms.path]
        if ms.path in self.constant:
            n = len(self.constant[ms.path].constants)
            return Decision.CONSTANT, None, f"every textured input is constant: {n} value(s) authored, nothing trained"
        return Decision.MODEL, None, ms.message

    def group_of(self, material: str) -> tuple[TextureSetGroup, MaterialModel]:
        for g in self.groups:
            if material in g.materials:
                return g, g.models[g.materials.index(material)]
        raise KeyError(material)


def group_materials(scene, variants: Mapping[str, str], materials: Sequence["MaterialScan"],
                    file_cache: dict | None = None, digest: bool = True, fold: bool = True, facts=None) -> Grouping:
    """Group the materials decided ``model`` by texture set (channels and addressing); opens each
    texture once (its header, and with ``digest`` its bytes for the hash; with ``fold`` its texels,
    to fold constant channels and merge duplicates; all cached in ``file_cache``). ``facts``: a
    bcfpipe.cache.facts.FactsStore; a file whose bytes it has seen is not decoded again."""
    modelled = [ms for ms in materials if ms.decision == Decision.MODEL]
    instanced = frozenset(instance_proxies(scene, variants, [m.path for m in modelled]))
    cache = {} if file_cache is None else file_cache
    canonical = Canonical()
    by_key: dict[tuple, list[tuple[str, MaterialModel]]] = {}
    failed: dict[str, str] = {}
    unreadable: dict[str, str] = {}
    constant: dict[str, MaterialModel] = {}
    for ms in modelled:
        if ms.path in instanced:
            continue
        try:
            mm = material_model(ms, cache, digest, canonical, fold, facts)
        except ImageReadError as exc:
            failed[ms.path] = f"cannot read textures: {one_line(exc)}"
            unreadable[ms.path] = str(exc)
            continue
        except Exception as exc:  # noqa: BLE001 - an unexpected failure fails this material only
            failed[ms.path] = f"cannot read textures: {one_line(exc)}"
            continue
        if not mm.channels:
            constant[ms.path] = mm
            continue
        by_key.setdefault((frozenset(mm.channels), mm.wrap), []).append((ms.path, mm))
    taken: set[str] = set()
    groups = tuple(TextureSetGroup(job_name(members[0][0], taken), tuple(p for p, _ in members),
                                   tuple(m for _, m in members)) for members in by_key.values())
    return Grouping(groups, instanced, failed, constant, unreadable)
