"""The ``BcfNeuralMaterialAPI`` schema plug-in (codeless: schemas/ holds only USD and JSON files).

Stages written by ``bcfpipe build`` open, compose and read back without the plug-in (every
attribute is authored with its type). Registering it makes USD aware of the schema: ``HasAPI``,
fallback values and the type checks of UsdValidation. Two ways:

* Environment (any USD tool, usdview, DCCs): ``export PXR_PLUGINPATH_NAME=<bcfpipe>/schemas``
  (``os.pathsep``-separated list; append to an existing value).
* In-process: ``bcfpipe.schema.register()`` *before* the first stage is opened or any schema is
  queried. USD's schema registry is built once per process, so a later registration is not seen
  (``register`` then returns False).

``schemas/`` is found next to the ``bcfpipe`` package (a source checkout or an editable install),
or wherever ``BCFPIPE_SCHEMAS`` points.
"""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["SCHEMA", "schema_dir", "plugin_path_env", "register", "is_registered"]

SCHEMA = "BcfNeuralMaterialAPI"


def schema_dir() -> Path:
    """The folder holding plugInfo.json, generatedSchema.usda and schema.usda."""
    env = os.environ.get("BCFPIPE_SCHEMAS")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "schemas")
    for c in candidates:
        if (c / "plugInfo.json").is_file():
            return c
    raise FileNotFoundError("bcfpipe schemas/ not found (set BCFPIPE_SCHEMAS to the folder with plugInfo.json)")


def plugin_path_env(existing: str | None = None) -> str:
    """A ``PXR_PLUGINPATH_NAME`` value that adds schemas/ to ``existing`` (default: the current one)."""
    existing = os.environ.get("PXR_PLUGINPATH_NAME", "") if existing is None else existing
    parts = [p for p in existing.split(os.pathsep) if p]
    d = str(schema_dir())
    return os.pathsep.join(parts + ([d] if d not in parts else []))


def is_registered() -> bool:
    """True when this process's USD schema registry knows BcfNeuralMaterialAPI."""
    from pxr import Usd

    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(SCHEMA) is not None


def register() -> bool:
    """Register schemas/ with USD's plug-in registry; returns whether the schema is now usable
    (False when the schema registry was already built without it: see the module docstring)."""
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(schema_dir()))
    return is_registered()
