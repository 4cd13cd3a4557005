"""The optional extras (pyproject's ``[project.optional-dependencies]``): what ``build``, ``verify``
and ``render`` need is a base dependency; ``ray`` (``--executor ray``) and ``bench``
(``bcfpipe bench``'s figures) are not. A command that needs a missing one says so in one line that
names the extra (exit 2), before any work, never with a traceback."""
from __future__ import annotations

import importlib
from types import ModuleType

from bcfpipe.errors import Unavailable

__all__ = ["MissingExtra", "require"]


class MissingExtra(Unavailable):
    """An optional package is not installed (exit 2); the message names the extra to install."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """``module`` imported, or `MissingExtra`: "<what> needs <package>: pip install 'bcfpipe[<extra>]'"."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        package = module.partition(".")[0]
        raise MissingExtra(f"{what} needs {package} ({' '.join(str(e).split())}): "
                           f"pip install 'bcfpipe[{extra}]'") from None
