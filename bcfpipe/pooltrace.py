"""A record of every pool and thread group a run opens, for tests and for checking what a build
uses (issue 58: ``--jobs N`` bounds every process and thread).

With ``BCFPIPE_TRACE_POOLS=<file>`` in the environment (worker processes inherit it), each place
that opens a pool or sets a thread count appends one JSON line to the file: ``kind`` (what),
``workers`` (how many threads or processes it may run at once) and ``pid``. Without it nothing is
written and nothing is imported. Kinds: ``job-pool`` (the build's training worker processes),
``progress-queue`` (the build's progress queue server process), ``torch-intra-op``,
``torch-inter-op``, ``oiio`` (OpenImageIO's ``threads``), ``encode-share`` (the cores a job's
encodes may use), ``encode-process-pool`` (quicktex bands beside a training), ``quicktex-openmp`` (quicktex's own
OpenMP threads on the main thread), ``disk-bytes-thread`` (zstd sizes aside), ``encode-thread-pool`` (ISPC bands),
``encode-beside-training`` (an encode in a thread beside a training), ``fused-thread-pool`` and
``numba`` (the fused training kernel's chunks), ``bc6h-thread-pool`` (BC6H fitting chunks),
``ssim-thread-pool`` and ``flip-thread-pool`` (evaluation), ``onnxruntime`` (an inference session's intra-op threads),
``speculative-training`` (the layout's likeliest training beside the probe), ``quality-estimate-aside``
(the BC7 quality set's estimate) and ``bc-encode-beside-probe`` (BC@R's full encode beside the probe).
"""
from __future__ import annotations

import json
import os

TRACE_ENV = "BCFPIPE_TRACE_POOLS"


def trace_pool(kind: str, workers: int, **extra) -> None:
    """Append ``{"kind", "workers", "pid", **extra}`` to $BCFPIPE_TRACE_POOLS, when it is set."""
    path = os.environ.get(TRACE_ENV)
    if not path:
        return

    line = json.dumps({"kind": kind, "workers": int(workers), "pid": os.getpid(), **extra}) + "\n"
    # one write in append mode: the lines of concurrent processes do not interleave
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line.encode())
    finally:
        os.close(fd)
