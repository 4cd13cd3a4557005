"""Opening a stage (USD's warnings captured as one-line notes), applying variant selections, and
finding the rendered geometry and the materials it binds (the rules are in bcfpipe.scan.stage's
docstring)."""
from __future__ import annotations

import os
import re
from pathlib import Path
from contextlib import contextmanager
from typing import Iterable, Iterator, Mapping

from pxr import Tf, Usd, UsdGeom, UsdShade, UsdUtils

from bcfpipe.scan.results import ScanError


_MAX_VARIANT_PASSES = 16


def parse_variant(text: str) -> tuple[str, str]:
    """Split ``SET=VALUE`` (both non-empty) into (set, value)."""
    name, sep, value = text.partition("=")
    name, value = name.strip(), value.strip()
    if not sep or not name or not value:
        raise ScanError(f"bad variant {text!r}: expected SET=VALUE, e.g. modelVariant=Fancy")
    return name, value


def parse_variants(texts: Iterable[str]) -> dict[str, str]:
    """Repeated ``SET=VALUE`` as {set: value}; two values for one set are refused (a stage
    composes one selection per set, and the last would win unseen)."""
    out: dict[str, str] = {}
    for name, value in map(parse_variant, texts):
        if out.get(name, value) != value:
            raise ScanError(f"two values for variant set {name!r} ({out[name]!r} and {value!r}); "
                            "a stage composes one: pass one --variant per set")
        out[name] = value
    return out


def first_line(exc: BaseException) -> str:
    """The first non-empty line of an exception message (pxr errors are verbose)."""
    try:
        message = str(exc)
    except UnicodeDecodeError:  # a pxr error quoting bytes of a corrupt file that are not UTF-8
        message = "the file is not valid UTF-8 text (a corrupt or binary file?)"
    lines = [ln.strip() for ln in message.splitlines() if ln.strip()]
    text = lines[0] if lines else type(exc).__name__
    # Tf errors read "Error in '...' at line N in file F : 'the message'"
    if " : " in text and text.startswith("Error in"):
        text = text.split(" : ", 1)[1].strip("'")
    return text


def open_stage(path: str | os.PathLike[str]) -> Usd.Stage:
    """Open a stage with all payloads loaded; ScanError if missing or unparsable."""
    p = Path(path)
    if not p.exists():
        raise ScanError(f"no such file: {p}")
    if p.is_dir():
        raise ScanError(f"not a USD file (a directory): {p}")
    try:
        stage = Usd.Stage.Open(str(p), Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise ScanError(f"cannot read stage {p}: {first_line(exc)}") from None
    if stage is None:
        raise ScanError(f"cannot read stage {p}")
    return stage


def composition_errors(stage: Usd.Stage) -> tuple[str, ...]:
    """One line per composition error (missing layers, bad references, ...)."""
    try:
        errors = stage.GetCompositionErrors()
    except Exception:  # noqa: BLE001 - older pxr without the API
        return ()
    return tuple(first_line(Exception(str(e))) for e in errors)


@contextmanager
def captured_diagnostics() -> Iterator[list[str]]:
    """Collect USD warnings/statuses (one line each) instead of letting them print to stderr."""
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    found: list[str] = []
    try:
        yield found
    finally:
        found.extend(first_line(Exception(d.commentary)) for d in delegate.TakeUncoalescedDiagnostics())
        del delegate


def new_diagnostics(found: Iterable[str], known: tuple[str, ...]) -> tuple[str, ...]:
    """Unique diagnostics that do not repeat a composition error."""
    unique = dict.fromkeys(d for d in found if not any(k in d for k in known))
    return tuple(unique)


def _variant_requests(
    stage: Usd.Stage, variants: Mapping[str, str]
) -> tuple[list[tuple[Usd.Prim, str, str]], dict[str, set[str]]]:
    """Selections still to author, and for each requested set the values seen on the stage."""
    todo: list[tuple[Usd.Prim, str, str]] = []
    offered: dict[str, set[str]] = {}
    for prim in stage.Traverse():
        vsets = prim.GetVariantSets()
        for name, value in variants.items():
            if not vsets.HasVariantSet(name):
                continue
            vset = vsets.GetVariantSet(name)
            names = set(vset.GetVariantNames())
            offered.setdefault(name, set()).update(names)
            if value in names and vset.GetVariantSelection() != value:
                todo.append((prim, name, value))
    return todo, offered


def apply_variants(stage: Usd.Stage, variants: Mapping[str, str]) -> tuple[tuple[str, str, str], ...]:
    """Select ``variants`` in the session layer on every prim offering them.

    Returns the (prim path, set, value) selections authored (a selection already
    in effect is not repeated).  Raises ScanError when
    a requested set/value exists nowhere on the composed stage.
    """
    applied: dict[tuple[str, str], str] = {}
    offered_all: dict[str, set[str]] = {}
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for _ in range(_MAX_VARIANT_PASSES):
            todo, offered = _variant_requests(stage, variants)
            for name, values in offered.items():
                offered_all.setdefault(name, set()).update(values)
            if not todo:
                break
            for prim, name, value in todo:
                prim.GetVariantSets().GetVariantSet(name).SetVariantSelection(value)
                applied[(str(prim.GetPath()), name)] = value
    for name, value in variants.items():
        values = offered_all.get(name)
        if not values:
            raise ScanError(f"variant set {name!r} not found on any prim")
        if value not in values:
            raise ScanError(
                f"variant {name}={value} not found: {name!r} offers {', '.join(sorted(values))}"
            )
    return tuple(sorted((p, s, v) for (p, s), v in applied.items()))


_HIDDEN_PURPOSES = frozenset({UsdGeom.Tokens.proxy, UsdGeom.Tokens.guide})


def _draws_stand_in(prim: Usd.Prim) -> bool:
    """True when a model is drawn as cards/bounds/origin instead of its geometry.

    Mirrors UsdImaging: a non-default (inherited) ``model:drawMode`` applies on
    component models and on models with ``model:applyDrawMode = true``.
    """
    if not prim.IsModel():
        return False
    api = UsdGeom.ModelAPI(prim)
    if api.ComputeModelDrawMode() == UsdGeom.Tokens.default_:
        return False
    return bool(api.GetModelApplyDrawModeAttr().Get()) or Usd.ModelAPI(prim).IsKind("component")


def _hides_subtree(prim: Usd.Prim) -> bool:
    """True when `prim` hides itself and its descendants (invisible, proxy/guide purpose, draw mode)."""
    if not prim.IsA(UsdGeom.Imageable):
        return False
    img = UsdGeom.Imageable(prim)
    if img.GetVisibilityAttr().Get() == UsdGeom.Tokens.invisible:
        return True
    if img.GetPurposeAttr().Get() in _HIDDEN_PURPOSES:
        return True
    return _draws_stand_in(prim)


def rendered_gprims(stage: Usd.Stage) -> list[Usd.Prim]:
    """Gprims a renderer draws (default/render purpose, visible), instance proxies included."""
    found: list[Usd.Prim] = []
    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        if _hides_subtree(prim):
            it.PruneChildren()
            continue
        if prim.IsA(UsdGeom.Gprim):
            found.append(prim)
    return found


def definition_path(prim: Usd.Prim) -> str:
    """The path identifying a prim's definition: its prototype prim for instance proxies."""
    if prim.IsInstanceProxy():
        return str(prim.GetPrimInPrototype().GetPath())
    return str(prim.GetPath())


def _binding_prims(gprims: Iterable[Usd.Prim]) -> list[Usd.Prim]:
    """The gprims plus their ``materialBind`` GeomSubsets."""
    prims: list[Usd.Prim] = []
    for g in gprims:
        prims.append(g)
        prims.extend(s.GetPrim() for s in UsdShade.MaterialBindingAPI(g).GetMaterialBindSubsets())
    return prims


def _binding_target(rel: Usd.Relationship) -> str | None:
    """The material path a binding relationship names (last target; collections list two)."""
    targets = rel.GetTargets() if rel else []
    return str(targets[-1]) if targets else None


def _bound(prims: list[Usd.Prim], purpose) -> list[tuple]:
    """(material, binding relationship) per prim; a prim whose binding is malformed (e.g.
    ``material:binding`` authored as an attribute, which USD raises on) binds nothing."""
    try:
        return list(zip(*UsdShade.MaterialBindingAPI.ComputeBoundMaterials(prims, purpose)))
    except Tf.ErrorException:
        out = []
        for prim in prims:
            try:
                out.append(UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial(purpose))
            except Tf.ErrorException:
                continue
        return out


def bound_materials(stage: Usd.Stage, gprims: list[Usd.Prim]) -> tuple[dict[str, set[str]], set[str]]:
    """Map definition path of each bound material to the purposes binding it; and dangling targets."""
    prims = _binding_prims(gprims)
    bound: dict[str, set[str]] = {}
    dangling: set[str] = set()
    if not prims:
        return bound, dangling
    for purpose in (UsdShade.Tokens.preview, UsdShade.Tokens.full):
        for mat, rel in _bound(prims, purpose):
            if mat:
                bound.setdefault(definition_path(mat.GetPrim()), set()).add(str(purpose))
            elif rel:
                target = _binding_target(rel)
                if target and not stage.GetPrimAtPath(target):
                    dangling.add(target)
    return bound, dangling


#: (prim, set, value) trials `binding_variants` makes at most: each recomposes part of the stage
MAX_VARIANT_TRIALS = 64


def binding_variants(stage: Usd.Stage, bound: Iterable[str]) -> tuple[tuple[tuple[str, str, tuple[str, ...]], ...], int]:
    """The variant selections that bind materials the current selections leave unbound:
    ((set, value, (material, ...)), ...) with the materials' definition paths; and how many
    (prim, set, value) choices were left untried (past ``MAX_VARIANT_TRIALS``). Each other value
    of each variant set is selected in the session layer, the bindings recomputed, and the
    selection put back, so the stage ends as it began."""
    choices: list[tuple[str, str, str, str]] = []
    for prim in stage.Traverse():
        vsets = prim.GetVariantSets()
        for name in vsets.GetNames():
            vset = vsets.GetVariantSet(name)
            current = vset.GetVariantSelection()
            choices.extend((str(prim.GetPath()), name, value, current)
                           for value in vset.GetVariantNames() if value != current)
    known = set(bound)
    found: dict[tuple[str, str], set[str]] = {}
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for path, name, value, current in choices[:MAX_VARIANT_TRIALS]:
            prim = stage.GetPrimAtPath(path)
            if not prim:
                continue
            vset = prim.GetVariantSets().GetVariantSet(name)
            vset.SetVariantSelection(value)
            now, _ = bound_materials(stage, rendered_gprims(stage))
            new = set(now) - known
            if new:
                found.setdefault((name, value), set()).update(new)
            prim = stage.GetPrimAtPath(path)
            prim.GetVariantSets().GetVariantSet(name).SetVariantSelection(current)
    return (tuple((s, v, tuple(sorted(m))) for (s, v), m in sorted(found.items())),
            max(0, len(choices) - MAX_VARIANT_TRIALS))


def counted(lines: Iterable[str]) -> list[str]:
    """Messages that differ only in the prim paths (``<...>``) and assets (``@...@``) they name
    reported once, with a count: ``Could not open asset @a.mtlx@ … </World/M1> (and 39 more
    like it)``."""
    groups: dict[str, list[str]] = {}
    for line in lines:
        groups.setdefault(re.sub(r"@[^@]*@", "@@", re.sub(r"<[^<>]*>", "<>", line)), []).append(line)
    return [members[0] + (f" (and {len(members) - 1} more like it)" if len(members) > 1 else "")
            for members in groups.values()]


def mtlx_assets(prim: Usd.Prim) -> tuple[str, ...]:
    """The MaterialX documents (.mtlx) a prim references or loads as a payload, as authored."""
    found: list[str] = []
    for spec in prim.GetPrimStack():
        for op in (spec.referenceList, spec.payloadList):
            for item in (*op.explicitItems, *op.prependedItems, *op.appendedItems, *op.addedItems):
                path = item.assetPath or ""
                if path.lower().endswith(".mtlx"):
                    found.append(path)
    return tuple(dict.fromkeys(found))


def mtlx_documents(messages: Iterable[str]) -> tuple[str, ...]:
    """The MaterialX documents (``@….mtlx@``) that composition errors say could not be opened."""
    found = (m.group(1) for line in messages for m in re.finditer(r"@([^@]*\.mtlx)@", line, re.IGNORECASE))
    return tuple(dict.fromkeys(found))
