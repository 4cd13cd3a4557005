"""The ``BcfNeuralMaterialAPI`` schema plug-in (codeless: schemas/ holds only USD and JSON files).

Stages written by ``bcfpipe build`` open, compose and read back without the plug-in (every
attribute is authored with its type). Registering it makes USD aware of the schema: ``HasAPI``,
fallback values and the type checks of UsdValidation. Two ways:

* Environment (any USD tool, usdview, DCCs): ``export PXR_PLUGINPATH_NAME=<bcfpipe>/schemas``
  (``os.pathsep``-separated list; append to an existing value).
* In-process: ``bcfpipe.formats.usd_schema.register()`` *before* the first stage is opened or any schema is
  queried. USD's schema registry is built once per process, so a later registration is not seen
  (``register`` then returns False).

The ``BcfNeuralMaterial`` shader node (schemas/shaders/BcfNeuralMaterial.usda) that each built
material's ``bcf`` render context uses is registered with Sdr either through the environment,
by Sdr's own filesystem discovery (`shader_discovery_env`: any USD tool, no code), or
in-process by `register_shader_defs`.

``schemas/`` ships inside the package (``bcfpipe/schemas``, :mod:`bcfpipe.resources`): an installed
wheel and a checkout alike; ``BCFPIPE_SCHEMAS`` points elsewhere.
"""
from __future__ import annotations

import os
from pathlib import Path

from bcfpipe import resources

__all__ = ["SCHEMA", "SHADER_ID", "schema_dir", "plugin_path_env", "register", "is_registered",
           "shader_defs", "shader_discovery_env", "register_shader_defs"]

SCHEMA = "BcfNeuralMaterialAPI"
SHADER_ID = "BcfNeuralMaterial"  # the Sdr node of schemas/shaders/BcfNeuralMaterial.usda


def schema_dir() -> Path:
    """The folder holding plugInfo.json, generatedSchema.usda and schema.usda."""
    return resources.data_dir(resources.SCHEMA_DIR, "BCFPIPE_SCHEMAS", "plugInfo.json")


def plugin_path_env(existing: str | None = None) -> str:
    """A ``PXR_PLUGINPATH_NAME`` value that adds schemas/ to ``existing`` (default: the current one)."""
    existing = os.environ.get("PXR_PLUGINPATH_NAME", "") if existing is None else existing
    parts = [p for p in existing.split(os.pathsep) if p]
    d = str(schema_dir())
    return os.pathsep.join(parts + ([d] if d not in parts else []))


def is_registered() -> bool:
    """True when this process's USD schema registry knows BcfNeuralMaterialAPI."""
    from pxr import Usd  # lazy: start-up

    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(SCHEMA) is not None


def register() -> bool:
    """Register schemas/ with USD's plug-in registry; returns whether the schema is now usable
    (False when the schema registry was already built without it: see the module docstring)."""
    from pxr import Plug  # lazy: start-up

    Plug.Registry().RegisterPlugins(str(schema_dir()))
    return is_registered()


def shader_defs() -> Path:
    """schemas/shaders/BcfNeuralMaterial.usda: the Sdr definition of the BcfNeuralMaterial shader node."""
    return schema_dir() / "shaders" / f"{SHADER_ID}.usda"


def shader_discovery_env() -> dict[str, str]:
    """The environment that makes Sdr's filesystem discovery plug-in find the node in any USD
    process: it reads every ``.usda`` of the search path, takes the identifier from the file name
    and parses it with UsdShade's shader-definition parser (source type ``""``: the file's
    universal ``info:sourceAsset``). A plugInfo.json cannot add Sdr nodes without a compiled
    discovery plug-in (usdShaders has one), so PXR_PLUGINPATH_NAME alone is not enough."""
    return {"PXR_SDR_FS_PLUGIN_SEARCH_PATHS": str(shader_defs().parent), "PXR_SDR_FS_PLUGIN_ALLOWED_EXTS": "usda"}


def register_shader_defs() -> list[str]:
    """Add every shader of BcfNeuralMaterial.usda to this process's Sdr registry (idempotent);
    returns their identifiers: the in-process alternative to `shader_discovery_env` once the
    registry exists (node source type ``glsl``). A C++ host makes the same two calls
    (UsdShadeShaderDefUtils::GetDiscoveryResults, SdrRegistry::AddDiscoveryResult)."""
    from pxr import Sdr, Usd, UsdShade  # lazy: start-up

    path = shader_defs()
    stage = Usd.Stage.Open(str(path))
    registry = Sdr.Registry()
    ids = []
    for prim in stage.GetPseudoRoot().GetChildren():
        shader = UsdShade.Shader(prim)
        if not shader:
            continue
        ident = shader.GetIdAttr().Get() or prim.GetName()
        if not registry.GetShaderNodeByIdentifierAndType(ident, "glsl"):
            for result in UsdShade.ShaderDefUtils.GetDiscoveryResults(shader, stage.GetRootLayer().realPath):
                registry.AddDiscoveryResult(result)
        ids.append(ident)
    return ids


_COMPONENTS = {"r": 0, "g": 1, "b": 2, "x": 0, "y": 1, "z": 2}


def component_index(target: str) -> int | None:
    """The vector component a ``bcf:outputs:targets`` entry names (diffuseColor.g -> 1, normal.z -> 2),
    None for a scalar input."""
    return _COMPONENTS.get(target.rpartition(".")[2]) if "." in target else None
