"""The data folders that ship inside the package: ``glsl/`` (the runtime decoder and the renderer's
shaders), ``decoders/`` (that decoder as SPIR-V, HLSL and Metal: `bcfpipe shaders`' output) and
``schemas/`` (the USD schema plug-in, the BcfNeuralMaterial Sdr node, the JSON Schemas).

They are found next to this module, so an installed wheel, an sdist build and an editable checkout
read the same files; the repository's top-level ``glsl`` and ``schemas`` are links to these.
``BCFPIPE_GLSL_DIR``, ``BCFPIPE_DECODERS`` and ``BCFPIPE_SCHEMAS`` override them (a host that keeps
its own copies).
"""
from __future__ import annotations

import os
from pathlib import Path

from bcfpipe.errors import Unavailable

__all__ = ["PACKAGE_DIR", "GLSL_DIR", "DECODER_DIR", "SCHEMA_DIR", "MissingData", "data_dir"]

PACKAGE_DIR = Path(__file__).resolve().parent
GLSL_DIR = PACKAGE_DIR / "glsl"
DECODER_DIR = PACKAGE_DIR / "decoders"
SCHEMA_DIR = PACKAGE_DIR / "schemas"


class MissingData(Unavailable):
    """A shipped data folder is not where it should be (exit 2, one line)."""


def data_dir(shipped: Path, env: str, marker: str) -> Path:
    """``$env`` when set and holding ``marker``, else the ``shipped`` folder when it holds it;
    `MissingData` (one line, naming the variable) otherwise."""
    override = os.environ.get(env)
    for d in ([Path(override)] if override else []) + [shipped]:
        if (d / marker).is_file():
            return d
    where = f"{env}={override} and " if override else ""
    raise MissingData(f"{marker} is in neither {where}{shipped} (a broken install? "
                            f"reinstall bcfpipe, or set {env} to the folder with {marker})")
