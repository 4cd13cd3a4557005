"""The build's option groups besides training (`config.TrainingOptions`), as KTX's tools compose
theirs: which materials a build models and what the scene needs (`Selection`), and where and how
its jobs run and what it writes besides OUT (`Execution`). Neither changes what a job trains
except through the plan: the selection through each job's record (resolution, coverage, anchors)."""
from __future__ import annotations

import concurrent.futures as cf
import os
from dataclasses import dataclass
from typing import Iterable, Mapping

from bcfpipe.formats.vocabulary import StrEnum


class ExecutorName(StrEnum):
    """Where the jobs train: local worker processes, or Ray tasks (`--executor`)."""

    LOCAL = "local"
    RAY = "ray"


@dataclass(frozen=True)
class Selection:
    """Which of the scene's materials a build models, and what the scene needs of them."""

    variants: Mapping[str, str] | Iterable[str] | None = None  # {set: value} or ("set=value", ...)
    all_materials: bool = False  # also materials bound to no rendered geometry
    materials: tuple[str, ...] = ()  # only these material prims (none: every one)
    texel_density: float | None = None  # px/m: each set resampled to what its meshes need
    coverage: bool = True  # train on the texels the bound meshes read
    bench: Mapping | None = None  # a `bcfpipe bench` report whose cells --target-psnr predicts from


@dataclass(frozen=True)
class Execution:
    """Where and how a build's jobs run, and what it writes besides OUT."""

    jobs: int | None = None  # the build's cores, at most N busy (executor.core_shares); default: one job per core, or per GPU
    executor: ExecutorName = ExecutorName.LOCAL
    ray_address: str | None = None  # with the Ray executor: the cluster (None: a Ray of the build's own)
    cache: str | os.PathLike | bool | None = None  # a folder; True/None the default one; False none
    force: bool = False  # replace the build of another scene in OUT
    depfile: str | os.PathLike | None = None  # write the files the result depends on there
    depfile_target: str | None = None  # the depfile's target (default: the root layer under OUT as given)
    pool: cf.Executor | None = None  # the local executor's process pool (default: one of its own)
