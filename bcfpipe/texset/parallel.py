"""Block encoding over the cores a job may use (issue 50: the default layout's BC encodes).

BC1/BC4/BC5/BC7 blocks are independent: a level cut into bands of whole block rows encodes to the
same bytes as the level at once, band by band in row order. ISPC's encoder releases the GIL, so
its bands run in threads. quicktex runs a level's blocks on OpenMP threads of its own runtime,
which `openmp_threads` bounds; it holds the GIL, so off the main thread (beside a training) its
bands run in worker processes instead (spawned: the callers hold torch's threads, which a fork
would copy half-started). A level whose blocks repeat is encoded as the mosaic of its distinct
blocks (`bcfpipe.texset.distinct_blocks`): the same bytes.

How many: `encode_workers()`, set per job by the build (`job_encode_workers`: its share of
``--jobs`` cores, or without ``--jobs`` the cores its parallel jobs leave to each, at least its
``--threads``) and by `train` (``--threads``, or every core), through `set_encode_workers`. With one
worker every encode runs inline, in the calling thread: no pool, no process (issue 58).
"""
from __future__ import annotations

import atexit
import contextlib
import ctypes
import multiprocessing as mp
import os
import sys
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np

from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset.distinct_blocks import encode_distinct

BAND_ROWS = 256  # texel rows per band: a multiple of 4, 2 MiB of RGBA at 2048 wide

_workers: int | None = None
_local = threading.local()  # a thread's own count (an encode beside a training: `workers`)
_pool: ProcessPoolExecutor | None = None
_pool_size = 0


def _cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def set_encode_workers(n: int | None) -> None:
    """Cores this process's encodes may use (None: every core of the machine)."""
    global _workers
    _workers = None if n is None else max(1, int(n))


def encode_workers() -> int:
    """Cores this thread's encodes may use: the thread's own count (`workers`), else the process's
    as set, else every core."""
    own = getattr(_local, "n", None)
    if own is not None:
        return own
    return _workers if _workers is not None else _cores()


@contextlib.contextmanager
def workers(n: int, beside: bool = False):
    """Encodes of this thread use ``n`` cores meanwhile (the others train). ``beside``: a training
    runs on another thread of this process meanwhile, so quicktex's bands go to worker processes
    even here on the main thread, even with one worker (`quicktex_level`)."""
    before = getattr(_local, "n", None), getattr(_local, "beside", False)
    _local.n, _local.beside = max(1, int(n)), beside or before[1]
    if _off_main_thread() or beside:
        trace_pool("encode-beside-training", _local.n)
    try:
        yield
    finally:
        _local.n, _local.beside = before


def _off_main_thread() -> bool:
    """A thread beside the main one: quicktex, which holds the GIL, must not run in it, or the
    main thread's training stalls."""
    return threading.current_thread() is not threading.main_thread()


def _beside_training() -> bool:
    """This thread encodes while a training runs on another thread (`workers`' ``beside``)."""
    return getattr(_local, "beside", False)


BACKGROUND_NICE = 10  # the nice value of work that fills the cores a fit's main thread leaves


def background() -> None:
    """This thread, and the threads and processes it starts, yield the cores to the process's other
    threads (Linux: its own nice value, `BACKGROUND_NICE`; elsewhere nothing): work beside a step
    that the fit waits for, such as BC@R's encode beside the layout's probe."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BACKGROUND_NICE)


def job_encode_workers(threads: int, parallel_jobs: int, cores: int | None = None) -> int:
    """A job's encode workers: ``cores`` (the build's ``--jobs``) shared among the
    ``parallel_jobs`` that run at once, at least 1 (the job's ``threads`` fit in that share: the
    build makes them). Without ``cores`` (no ``--jobs``): the machine's cores so shared, and never
    fewer than the job's own ``threads``."""
    share = (_cores() if cores is None else max(1, int(cores))) // max(1, int(parallel_jobs))
    return max(1, share) if cores is not None else max(1, int(threads), share)


def bands(px: np.ndarray, rows: int = BAND_ROWS) -> list[np.ndarray]:
    """``px`` (H, W, 4) cut into bands of ``rows`` texel rows (H a multiple of 4)."""
    return [px[y:y + rows] for y in range(0, px.shape[0], rows)]


def release_workers() -> None:
    """End the encode worker processes (a build's job calls it when done: a pool worker exits
    without running atexit)."""
    global _pool, _pool_size
    if _pool is not None:
        _pool.shutdown(wait=True, cancel_futures=True)
    _pool, _pool_size = None, 0


def _process_pool(n: int) -> ProcessPoolExecutor:
    """A spawn pool of ``n`` workers, kept for the process's later encodes, started at once."""
    global _pool, _pool_size
    with _pool_lock:
        if _pool is None or _pool_size != n:
            release_workers()
            _pool, _pool_size = ProcessPoolExecutor(n, mp_context=mp.get_context("spawn")), n
            trace_pool("encode-process-pool", n)
            atexit.register(release_workers)
            with _bare_main():  # a spawn pool starts a worker per task submitted while none is idle
                for f in [_pool.submit(int) for _ in range(n)]:
                    f.result()
        return _pool


_pool_lock = threading.Lock()


def start_workers(n: int) -> threading.Thread:
    """Start `_process_pool`'s ``n`` workers now, on a thread of their own (returned) at `background`
    priority, which they inherit: a fit that will encode BC@R beside its probe starts them while its
    set loads on one core (each worker's start-up is 0.3 s of a core), and finds them up."""
    def start() -> None:
        background()
        _process_pool(n)

    thread = threading.Thread(target=start, name="bcfpipe-encode-workers", daemon=True)
    thread.start()
    return thread


_main_lock = threading.Lock()


@contextlib.contextmanager
def _bare_main():
    """Workers spawned meanwhile do not run the main script's imports (the CLI's: 0.6 s in each
    worker), which they do not need: spawn imports the main module that ``__main__`` names."""
    main = sys.modules.get("__main__")
    with _main_lock:
        saved = {k: main.__dict__[k] for k in ("__file__", "__spec__") if main is not None and k in main.__dict__}
        try:
            if "__spec__" in saved:
                main.__spec__ = None
            if "__file__" in saved:
                del main.__file__
            yield
        finally:
            for k, v in saved.items():
                setattr(main, k, v)


def _quicktex_band(codec: str, raw: bytes, width: int, height: int) -> bytes:
    """One band's quicktex blocks (runs in a worker process)."""
    import quicktex  # lazy: start-up

    openmp_threads(1)  # the pool's processes are the band's parallelism
    return _encoder(codec).encode(quicktex.RawTexture.frombytes(raw, width, height)).tobytes()


def _encoder(codec: str):
    """This thread's encoder for ``codec``, made once: a level-13 BC1 encoder builds its tables in
    10 ms, as long as a 512² level takes to encode (the layout's sampled estimates encode dozens)."""
    made = _local.__dict__.setdefault("encoders", {})
    if codec not in made:
        made[codec] = make_quicktex_encoder(codec)
    return made[codec]


def make_quicktex_encoder(codec: str):
    """quicktex's encoder for ``codec``: 'bc1 level N', 'bc4 channel 0' or 'bc5 channels 0 1'."""
    if codec.startswith("bc1 level "):
        from quicktex.s3tc.bc1 import BC1Encoder  # lazy: start-up

        return BC1Encoder(int(codec.rsplit(" ", 1)[1]))
    if codec == "bc4 channel 0":
        from quicktex.s3tc.bc4 import BC4Encoder  # lazy: start-up

        return BC4Encoder(0)
    if codec == "bc5 channels 0 1":
        from quicktex.s3tc.bc5 import BC5Encoder  # lazy: start-up

        return BC5Encoder(0, 1)
    raise ValueError(f"unknown quicktex codec {codec!r}")


def quicktex_level(codec: str, px: np.ndarray, block_bytes: int) -> np.ndarray:
    """A padded (H, W, 4) uint8 level's blocks, (n, block_bytes) uint8 in row-major order, by
    quicktex's ``codec``; BC1's each distinct block once (`distinct_blocks`: BC4 and BC5 take
    0.3 µs a block, as long as finding the distinct ones)."""
    if not codec.startswith("bc1"):
        return _quicktex_level(codec, px, block_bytes)
    return encode_distinct(lambda p: _quicktex_level(codec, p, block_bytes), px)


def _quicktex_level(codec: str, px: np.ndarray, block_bytes: int) -> np.ndarray:
    """`quicktex_level` of every block. On the main thread inline, on `encode_workers()` OpenMP threads (quicktex
    runs a level's blocks on its own OpenMP runtime, every core unless told: `openmp_threads`).
    Off the main thread (an encode beside a training), where quicktex would hold the GIL for the
    whole level: with more than one worker in bands over that many processes of one thread each;
    with one, inline on one thread (a thread beside a training takes its turns on the GIL). On
    any thread where a training runs beside (`workers`' ``beside``: the likeliest training, started
    before BC@R's encode), in processes even with one worker: the training's thread would
    otherwise wait for the GIL through each whole level."""
    import quicktex  # lazy: start-up

    n = encode_workers()
    h, w = px.shape[:2]
    if (n > 1 and _off_main_thread()) or _beside_training():
        pool = _process_pool(n)
        futures = [pool.submit(_quicktex_band, codec, np.ascontiguousarray(b).tobytes(), w, b.shape[0])
                   for b in bands(px)]
        raw = b"".join(f.result() for f in futures)
    else:
        openmp_threads(n)
        raw = _encoder(codec).encode(quicktex.RawTexture.frombytes(px.tobytes(), w, h)).tobytes()
    return np.frombuffer(raw, np.uint8).reshape(-1, block_bytes).copy()


def openmp_threads(n: int) -> None:
    """quicktex's OpenMP runtime (the libgomp its wheel ships) runs this thread's next encodes on
    ``n`` threads. Without it every encode takes every core, whatever ``--jobs`` says. Where torch
    is loaded, quicktex's and FLIP's parallel regions follow torch's intra-op count as well
    (measured: a 2048² level 5.5 s with torch at 1 thread, 3.0 s at 2, whatever this says), so a
    build's job sets torch's count to its share outside a training (`bcfpipe.builder.executor`)."""
    global _gomp
    if _gomp is None:
        import _quicktex  # noqa: F401  # loads its OpenMP runtime - lazy: start-up

        try:
            with open("/proc/self/maps") as f:
                paths = {line.split()[-1] for line in f if "quicktex" in line and "gomp" in line}
        except OSError:  # not Linux: quicktex's runtime keeps its own default
            paths = set()
        _gomp = [ctypes.CDLL(p) for p in sorted(paths)]
    if _gomp and n != getattr(_local, "omp", 0):  # OpenMP's thread count is each calling thread's own
        for lib in _gomp:
            lib.omp_set_num_threads(int(n))
        _local.omp = n
        trace_pool("quicktex-openmp", n)


_gomp: list | None = None


def map_threads(fn: Callable, items, kind: str) -> list:
    """``fn`` over ``items``, in order, on `encode_workers()` threads (``fn`` releases the GIL: a
    compiled kernel's band); ``kind`` names the pool for `trace_pool`."""
    items = list(items)
    n = min(encode_workers(), len(items))
    if n > 1:
        trace_pool(kind, n)
        with ThreadPoolExecutor(n) as pool:
            return list(pool.map(fn, items))
    return list(map(fn, items))


def threaded_bands(encode_band: Callable[[np.ndarray], bytes], px: np.ndarray, block_bytes: int) -> np.ndarray:
    """A padded level's blocks by ``encode_band`` (an encoder that releases the GIL), its bands
    over `encode_workers()` threads, each distinct block once (`distinct_blocks`)."""
    def every(p: np.ndarray) -> np.ndarray:
        raw = b"".join(map_threads(encode_band, bands(p), "encode-thread-pool"))
        return np.frombuffer(raw, np.uint8).reshape(-1, block_bytes).copy()

    return encode_distinct(every, px)
