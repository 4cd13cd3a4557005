"""Scan a USD stage for the UsdPreviewSurface materials a neural model must replace.

`bcfpipe build` models only what the scene needs: the textured UsdPreviewSurface
materials that are bound to geometry that is actually rendered.  This module
composes the stage (with optional variant selections), reads every material's
shading network and decides, per material, ``model`` or ``skip`` with a reason
code.  It never modifies the input: variant selections go to the session layer.

Decisions (the first that applies wins):

=====================  ====================================================
reason                 when
=====================  ====================================================
``materialx-only``     no universal ``outputs:surface`` but ``outputs:mtlx:surface``,
                       or the universal surface is a MaterialX ``ND_*`` node
``not-preview-surface`` the universal surface is not a UsdPreviewSurface (or none)
``unbound``            no rendered geometry binds it (ignored with ``all_materials``)
``no-textures``        every UsdPreviewSurface input is a constant (or a primvar)
``unresolvable-file``  some texture's file is a ``<UDIM>`` pattern or time-sampled
                       without a default (or the texture output used is not
                       r/g/b/a/rgb).  One such texture skips the whole material:
                       a neural material replaces all of its textures at once.
                       A texture with no file, or whose file does not resolve,
                       gives its ``fallback`` instead, as Hydra does (a constant,
                       with a warning); a material whose every texture does so is
                       ``constant``.
``scan-error``         anything unexpected while reading that one material
``not-selected``       ``--material`` names other materials (checked first)
=====================  ====================================================

Choices worth knowing:

* Variants: ``SET=VALUE`` is applied on every prim that has a variant set ``SET``
  offering ``VALUE`` (prims whose set of that name lacks the value are left
  alone, so a name reused at several levels — the Vehicles kit's ``wheels`` —
  does what one means).  Selecting a variant can reveal nested variant sets, so
  selections are re-applied until nothing changes.  Variant sets inside
  instance prototypes cannot be edited and are not searched.
* Binding: a material is bound if a rendered Gprim (or one of its
  ``materialBind`` GeomSubsets) resolves to it under the ``preview`` purpose
  (what a real-time renderer uses; falls back to all-purpose bindings) or the
  ``full`` purpose.  Rendered = reachable through active, loaded, defined prims
  (instance proxies included), not under ``visibility = invisible`` nor under
  ``purpose`` ``proxy``/``guide`` (default-time values; animated visibility
  counts as visible), nor under a model drawn as cards/bounds/origin
  (``model:drawMode``, as UsdImaging applies it).
* Instancing: a material inside an instance is reported once per prototype
  material, at the first instance-proxy path; the other paths are ``aliases``.
* ``wrapS``/``wrapT`` default to ``useMetadata`` (UsdPreviewSurface spec), which
  renderers treat as ``repeat`` when the file carries no wrap metadata; the
  ``effective_wrap`` property applies that.
"""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from pxr import Ar, Usd, UsdGeom, UsdShade

from bcfpipe.formats.vocabulary import ColorSpace, Decision
from bcfpipe.scan.composition import (apply_variants, binding_variants, bound_materials, captured_diagnostics,
                                      composition_errors, definition_path, first_line, mtlx_assets, new_diagnostics,
                                      open_stage, rendered_gprims)
from bcfpipe.scan.density import MaterialDensity, material_bindings, material_density
from bcfpipe.scan.network import COLOR_INPUTS, WRAP_MODES, scan_input, shader_id, texture_targets
from bcfpipe.scan.results import (PREVIEW_SURFACE_INPUTS, ChannelUse, InputScan,
                                  MaterialScan, ScanError, StageScan)


def channel_uses(inputs: Iterable[InputScan]) -> tuple[ChannelUse, ...]:
    """The texture channels a model needs, one per (input, component), for usable textures."""
    uses: list[ChannelUse] = []
    for inp in inputs:
        tex = inp.texture
        if inp.kind != "texture" or tex is None or not tex.ok:
            continue
        for channel, target in texture_targets(inp.name, tex.channel):
            uses.append(ChannelUse(tex.resolved_path, channel, target, inp.name, tex.source_color_space))
    return tuple(uses)


def _fallback_text(tex) -> str:
    """The fallback components a texture's output reads, e.g. ``(0, 0, 1)`` for rgb."""
    letters = "rgb" if tex.channel == "rgb" else tex.channel
    values = [f"{tex.fallback_value(c):g}" for c in letters]
    return values[0] if len(values) == 1 else f"({', '.join(values)})"


def input_warnings(inputs: Iterable[InputScan]) -> tuple[str, ...]:
    """Notes about inputs a model will not reproduce exactly."""
    notes: list[str] = []
    for inp in inputs:
        tex = inp.texture
        if inp.kind in ("primvar", "unsupported"):
            notes.append(f"{inp.name}: {inp.detail} (not modelled)")
        elif inp.kind == "constant" and inp.detail:
            notes.append(f"{inp.name}: {inp.detail}")
        if tex is None:
            continue
        if tex.uses_fallback:
            notes.append(f"{inp.name}: {tex.problem}; its fallback {_fallback_text(tex)} is used, as Hydra does")
            continue
        if tex.st.kind == "constant":
            notes.append(f"{inp.name}: st not connected, texture sampled at {tex.st.value}")
        elif tex.st.kind == "other":
            notes.append(f"{inp.name}: unusual st source ({tex.st.detail})")
        if tex.animated_file and tex.ok:
            notes.append(f"{inp.name}: file is time-sampled; using its default value")
        if inp.name not in COLOR_INPUTS and inp.name != "normal" and tex.channel == "rgb":
            notes.append(f"{inp.name}: scalar input fed from rgb; reading .r")
        if inp.name not in COLOR_INPUTS and tex.channel != "a" and tex.source_color_space == ColorSpace.SRGB:
            notes.append(f"{inp.name}: non-colour data read from a texture tagged sRGB")
        for wrap in (tex.wrap_s, tex.wrap_t):
            if wrap not in WRAP_MODES:
                notes.append(f"{inp.name}: unknown wrap mode {wrap!r}")
    return tuple(notes)


def decide(
    surface_problem: tuple[str, str] | None,
    bound: bool,
    all_materials: bool,
    inputs: tuple[InputScan, ...],
) -> tuple[str, str | None, str]:
    """(decision, reason, message) for a material from its facts (first rule that applies)."""
    if surface_problem is not None:
        return Decision.SKIP, surface_problem[0], surface_problem[1]
    if not bound and not all_materials:
        return Decision.SKIP, "unbound", "not bound to any rendered geometry"
    textured = [i for i in inputs if i.kind == "texture"]
    if not textured:
        others = [i.name for i in inputs if i.kind != "constant"]
        tail = f"; {', '.join(others)} from primvars/other nodes" if others else ""
        return Decision.SKIP, "no-textures", f"no texture inputs (constants{tail})"
    bad = [i for i in textured if i.texture is not None and not i.texture.ok and not i.texture.uses_fallback]
    if bad:
        detail = "; ".join(f"{i.name}: {i.texture.problem}" for i in bad)  # type: ignore[union-attr]
        return Decision.SKIP, "unresolvable-file", detail
    names = ", ".join(i.name for i in textured)
    return Decision.MODEL, None, f"{len(textured)} textured input(s): {names}"


def _surface(material: UsdShade.Material) -> tuple[UsdShade.Shader | None, tuple[str, str] | None]:
    """The universal surface shader and, if it is not a usable UsdPreviewSurface, (reason, message)."""
    shader, _, _ = material.ComputeSurfaceSource("")
    mtlx = mtlx_assets(material.GetPrim())
    if not shader and mtlx:
        return None, ("materialx-only", f"defined in the MaterialX document {Path(mtlx[0]).name}, which bcfpipe "
                                        "does not read")
    if not shader:
        names = [o.GetBaseName() for o in material.GetSurfaceOutputs() if o.HasConnectedSource()]
        contexts = sorted({n.split(":")[0] for n in names if ":" in n})
        if "mtlx" in contexts:
            return None, ("materialx-only", "only a MaterialX surface (outputs:mtlx:surface)")
        if contexts:
            return None, ("not-preview-surface", f"only render-context surfaces: {', '.join(contexts)}")
        return None, ("not-preview-surface", "no surface shader")
    sid = shader_id(shader.GetPrim())
    if sid == "UsdPreviewSurface":
        return shader, None
    if sid and sid.startswith("ND_"):
        return shader, ("materialx-only", f"surface is the MaterialX node {sid}")
    return shader, ("not-preview-surface", f"surface shader is {sid or 'not identified by info:id'}")


def scan_material(
    material: UsdShade.Material,
    bound_purposes: tuple[str, ...],
    all_materials: bool,
    aliases: tuple[str, ...] = (),
) -> MaterialScan:
    """Read one material's UsdPreviewSurface network and decide model/skip."""
    path = str(material.GetPath())
    bound = bool(bound_purposes)
    shader, problem = _surface(material)
    sid = shader_id(shader.GetPrim()) if shader else None
    inputs: tuple[InputScan, ...] = ()
    if shader is not None and problem is None:
        inputs = tuple(scan_input(shader, name) for name in PREVIEW_SURFACE_INPUTS)
    decision, reason, message = decide(problem, bound, all_materials, inputs)
    return MaterialScan(
        path=path,
        decision=decision,
        reason=reason,
        message=message,
        bound=bound,
        bound_purposes=bound_purposes,
        aliases=aliases,
        surface_shader=str(shader.GetPath()) if shader else None,
        shader_id=sid,
        inputs=inputs,
        channel_uses=channel_uses(inputs) if decision == Decision.MODEL else (),
        warnings=input_warnings(inputs),
    )


def _error_scan(
    path: str, exc: BaseException, bound_purposes: tuple[str, ...], aliases: tuple[str, ...]
) -> MaterialScan:
    """A skip for a material whose scan raised."""
    return MaterialScan(
        path=path,
        decision=Decision.SKIP,
        reason="scan-error",
        message=f"scan-error: {first_line(exc)}",
        bound=bool(bound_purposes),
        bound_purposes=bound_purposes,
        aliases=aliases,
    )


def material_prims(stage: Usd.Stage) -> dict[str, list[Usd.Prim]]:
    """Material prims by definition path (instance proxies of one prototype grouped), in traversal order."""
    groups: dict[str, list[Usd.Prim]] = {}
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if prim.IsA(UsdShade.Material):
            groups.setdefault(definition_path(prim), []).append(prim)
    return groups


def _stage_facts(stage: Usd.Stage) -> dict[str, Any]:
    """upAxis, metersPerUnit, defaultPrim and root layer of a stage."""
    default_prim = stage.GetDefaultPrim()
    layer = stage.GetRootLayer()
    return {
        "root_layer": layer.realPath or layer.identifier,
        "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
        "meters_per_unit": float(UsdGeom.GetStageMetersPerUnit(stage)),
        "default_prim": str(default_prim.GetPath()) if default_prim else None,
    }


def used_files(stage: Usd.Stage) -> tuple[str, ...]:
    """The files of every layer the stage composed (sublayers, references, payloads, clips, the
    session layer excluded); a layer inside a package is its package file (the .usdz)."""
    files = set()
    for layer in stage.GetUsedLayers():
        if layer.anonymous or not layer.realPath:
            continue
        real = layer.realPath
        if Ar.IsPackageRelativePath(real):
            real = Ar.SplitPackageRelativePathOuter(real)[0]
        files.add(os.path.normpath(real))
    return tuple(sorted(files))


def _density(ms: MaterialScan, bindings, meters_per_unit: float) -> MaterialDensity:
    """World and uv areas of the meshes bound to ``ms``, through its first texture's st primvar
    and UsdTransform2d scale (the ones the model uses)."""
    tex = ms.texture_inputs[0].texture if ms.texture_inputs else None
    st = tex.st if tex is not None else None
    if st is None or st.kind not in ("primvar", "transform2d") or not st.varname:
        return MaterialDensity(notes=("st is not read from a primvar: no texel density",))
    return material_density(bindings, st.varname, meters_per_unit, (0, 0), st.transform)


def _select(scans: list[MaterialScan], wanted: Sequence[str]) -> list[MaterialScan]:
    """``scans`` with every material that ``wanted`` does not name (by path or instance alias)
    skipped as ``not-selected``; a name that matches no material is a ScanError."""
    names = {m.path for m in scans} | {a for m in scans for a in m.aliases}
    unknown = [w for w in wanted if w.rstrip("/") not in names]
    if unknown:
        raise ScanError(f"--material {unknown[0]}: no material at that path on the composed stage "
                        f"(`bcfpipe scan` lists the {len(scans)} there)")
    keep = {w.rstrip("/") for w in wanted}
    return [m if m.path in keep or keep.intersection(m.aliases) else
            replace(m, decision=Decision.SKIP, reason="not-selected", message="not named by --material",
                    channel_uses=(), density=None)
            for m in scans]


def scan_stage(
    path: str | os.PathLike[str],
    variants: Mapping[str, str] | None = None,
    all_materials: bool = False,
    materials: Sequence[str] = (),
    binding_variants_too: bool = False,
) -> StageScan:
    """Compose the stage at `path`, apply `variants`, and decide model/skip for every material;
    with ``materials`` (paths), every other material is skipped as ``not-selected``. With
    ``binding_variants_too``, also try the other variant selections for materials they would bind
    (what `bcfpipe scan` lists; it recomposes the stage per choice, so builds do not ask for it).

    Raises ScanError only for stage-level problems (missing or unparsable file,
    unknown variant or material); per-material problems become skips.
    """
    with captured_diagnostics() as found:
        stage = open_stage(path)
        selections = apply_variants(stage, variants) if variants else ()
        gprims = rendered_gprims(stage)
        bound, dangling = bound_materials(stage, gprims)
        scans: list[MaterialScan] = []
        bindings = material_bindings(stage, gprims)
        mpu = float(UsdGeom.GetStageMetersPerUnit(stage))
        for key, prims in material_prims(stage).items():
            purposes = tuple(sorted(bound.get(key, ())))
            aliases = tuple(str(p.GetPath()) for p in prims[1:])
            try:
                ms = scan_material(UsdShade.Material(prims[0]), purposes, all_materials, aliases)
                if ms.decision == Decision.MODEL:
                    ms = replace(ms, density=_density(ms, bindings.get(key, []), mpu))
                scans.append(ms)
            except Exception as exc:  # noqa: BLE001 - one bad material must not stop the scan
                scans.append(_error_scan(str(prims[0].GetPath()), exc, purposes, aliases))
        variant_bindings, untried = binding_variants(stage, bound) if binding_variants_too else ((), 0)
    if materials:
        scans = _select(scans, materials)
    errors = composition_errors(stage)
    return StageScan(
        path=str(Path(path).resolve()),
        variant_selections=selections,
        all_materials=all_materials,
        rendered_gprims=len(gprims),
        materials=tuple(scans),
        dangling_bindings=tuple(sorted(dangling)),
        composition_errors=errors,
        diagnostics=new_diagnostics(found, errors),
        layers=used_files(stage),
        binding_variants=variant_bindings,
        variants_untried=untried,
        **_stage_facts(stage),
    )
