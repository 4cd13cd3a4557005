"""Which device class (cpu or cuda) a ``--device`` choice trains on, without importing torch when
the answer is plain: a CPU-only torch build cannot train on CUDA. A no-op rebuild that finds
everything in the cache then never pays torch's import time."""
from __future__ import annotations

from importlib import metadata


def _cpu_only_torch() -> bool:
    """True when the installed torch is a CPU build (its version says +cpu)."""
    try:
        return metadata.version("torch").endswith("+cpu")
    except metadata.PackageNotFoundError:
        return False


def device_class(name: str) -> str:
    """'cpu' or 'cuda' for ``name`` ('auto', 'cpu', 'cuda', 'cuda:N', ...); ValueError when CUDA is
    asked for and torch has none."""
    if name == "cpu":
        return "cpu"
    if _cpu_only_torch():
        if name == "auto":
            return "cpu"
        if name.startswith("cuda"):
            raise ValueError("--device cuda requested but torch has no CUDA device (a CPU build of torch)")
    from bcfpipe.train.trainer import resolve_device  # lazy: start-up

    return resolve_device(name).type


def device_name(name: str) -> str:
    """The device ``name`` trains on, as torch names it ('cpu', 'cuda', 'cuda:1'), with torch
    imported only where CUDA is possible (`device_class`)."""
    if device_class(name) == "cpu":
        return "cpu"
    from bcfpipe.train.trainer import resolve_device  # lazy: start-up

    return str(resolve_device(name))
