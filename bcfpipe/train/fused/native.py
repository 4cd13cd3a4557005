"""The C++ build of the fused step (step.cpp), its targets (targets.cpp), its Adam (adam.cpp) and
the first encode (bcfpipe/bc6h/quick.cpp):
compiled on first use for this machine's CPU into bcfpipe's cache (``kernels/``), loaded with
ctypes, and called with kernel.py's arguments, so :class:`bcfpipe.train.fused.step.FusedStep` can
run either.

The library's name hashes the source, the compiler's version and its flags; a build writes a
temporary file and renames it, so concurrent first uses never load half a library. Without a C++
compiler, or where the build or the load fails (a missing header, a broken install), :func:`load`
raises `NativeUnavailable` with one line saying why, and the numba kernel runs instead
(`bcfpipe.train.fused.step.default_backend`)."""
from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from bcfpipe.formats.atomic import write_atomically
from bcfpipe.pooltrace import trace_pool
from bcfpipe.process_env import kernels_dir

HERE = Path(__file__).parent
SOURCES = (HERE / "step.cpp", HERE / "targets.cpp", HERE / "adam.cpp", HERE.parent.parent / "bc6h" / "quick.cpp")
HEADERS = (HERE / "lanes.h",)
# -ffp-contract=off: no fused multiply-adds, so every product and sum rounds as torch's does;
# -fno-math-errno / -fno-trapping-math change no result, they let rounding calls inline
FLAGS = ("-O3", "-march=native", "-std=c++17", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math",
         "-shared", "-fPIC")

_f32p = ctypes.POINTER(ctypes.c_float)
_i32p = ctypes.POINTER(ctypes.c_int32)
_i64p = ctypes.POINTER(ctypes.c_int64)


class Args(ctypes.Structure):
    """step.cpp's ``Args``, field for field."""

    _fields_ = [(n, ctypes.c_int32) for n in ("fmt", "quantized", "sgn", "wrap", "C", "n_in", "hidden", "n_out")] + [
        ("a", ctypes.c_int64), ("b", ctypes.c_int64),
        ("uv", _f32p), ("target", _f32p), ("weight", _f32p), ("P", _f32p), ("X", _f32p), ("M", _i32p),
        ("slots", _i64p), ("blend", _f32p),
        ("plo", ctypes.c_float), ("phi", ctypes.c_float), ("loss_scale", ctypes.c_float), ("pad_", ctypes.c_float),
        ("w1", _f32p), ("b1", _f32p), ("w2", _f32p), ("b2", _f32p), ("out_scale", _f32p), ("out_bias", _f32p),
        ("gP", _f32p), ("gX", _f32p), ("gw1", _f32p), ("gb1", _f32p), ("gw2", _f32p), ("gb2", _f32p),
        ("feats_out", _f32p)]


class NativeUnavailable(RuntimeError):
    """No C++ compiler, or the build failed: the message says which, in one line."""


_lock = threading.Lock()
_lib: ctypes.CDLL | None = None


def _compiler() -> str:
    """$CXX, else g++, c++ or clang++ on the PATH."""
    named = os.environ.get("CXX")
    cxx = shutil.which(named) if named else (shutil.which("g++") or shutil.which("c++") or shutil.which("clang++"))
    if not cxx:
        raise NativeUnavailable(f"no C++ compiler ({named or 'g++'}) found (install g++, or set CXX)")
    return cxx


def library_path() -> Path:
    """Where this source, compiler and flag set's library lives in the cache."""
    cxx = _compiler()
    version = subprocess.run([cxx, "--version"], capture_output=True, text=True).stdout.splitlines()[:1]
    try:
        text = b"".join(p.read_bytes() for p in SOURCES + HEADERS)
    except OSError as e:  # the package lacks a source (an install that did not ship it)
        raise NativeUnavailable(f"the fused kernel's source {e.filename} is missing (reinstall bcfpipe)") from None
    key = hashlib.sha256(text + repr((cxx, version, FLAGS)).encode()).hexdigest()[:16]
    return Path(kernels_dir()) / f"bcf_step-{key}.so"


def _first_error(stderr: str) -> str:
    """The compiler's first error line (file:line: error: ...), else its last line: GCC ends its
    report with the source line and a caret, which say nothing alone."""
    lines = [ln.strip() for ln in stderr.strip().splitlines() if ln.strip()]
    for ln in lines:
        if "error" in ln.lower():
            return ln
    return lines[-1] if lines else "no message"


def _build(cxx: str, path: Path) -> None:
    """Compile the sources into ``path`` through a temporary file beside it (renamed when whole)."""
    def compile_to(tmp: Path) -> None:
        r = subprocess.run([cxx, *FLAGS, "-o", str(tmp), *map(str, SOURCES)], capture_output=True, text=True)
        if r.returncode != 0:
            raise NativeUnavailable(f"building the fused kernel failed: {_first_error(r.stderr)}")

    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, compile_to, suffix=".so")


def _open() -> ctypes.CDLL:
    """The library from the cache, built there first if needed. Where the cache cannot take it
    (full, read-only), it is built in a temporary folder, loaded, and the folder removed."""
    cxx, path = _compiler(), library_path()
    if path.exists():
        return ctypes.CDLL(str(path))
    try:
        _build(cxx, path)
        return ctypes.CDLL(str(path))
    except (OSError, NativeUnavailable):
        with tempfile.TemporaryDirectory(prefix="bcfpipe-kernel-") as d:
            _build(cxx, Path(d) / path.name)  # a compiler error is raised from here
            return ctypes.CDLL(str(Path(d) / path.name))  # stays mapped once the folder is gone


def load() -> ctypes.CDLL:
    """The compiled kernel, built into the cache on first use (a few seconds); the training goes
    on where the cache cannot take it, and the next one builds again. `NativeUnavailable` (one
    line) for anything that keeps it from running here: no compiler, a failed build, a library
    that does not load."""
    global _lib
    with _lock:
        if _lib is not None:
            return _lib
        try:
            lib = _open()
        except OSError as e:  # a compiler that cannot run, a library the loader refuses
            raise NativeUnavailable(f"the fused kernel cannot be built or loaded: {' '.join(str(e).split())}") from None
        lib.bcf_step.argtypes = [ctypes.POINTER(Args)]
        lib.bcf_step.restype = ctypes.c_double
        lib.bcf_features.argtypes = [ctypes.POINTER(Args)]
        lib.bcf_features.restype = None
        vp, i32, i64, f32 = ctypes.c_void_p, ctypes.c_int, ctypes.c_int64, ctypes.c_float
        lib.bcf_bicubic.argtypes = [vp, i32, i32, i32, vp, i64, i32, f32, f32, vp]
        lib.bcf_bicubic.restype = None
        lib.bcf_centres.argtypes = [vp, vp, i32, i32, i32, vp, i64, f32, vp, vp]
        lib.bcf_centres.restype = None
        lib.bcf_centre_rows.argtypes = [vp, i32, i32, i32, vp, i64, f32, vp, vp]
        lib.bcf_centre_rows.restype = None
        f64 = ctypes.c_double
        lib.bcf_adam.argtypes = [vp, vp, i32, i64, vp, vp, i64, f64, f64, f64, f64, i64, f32, f32]
        lib.bcf_adam.restype = None
        lib.bcf_bc6h_quick.argtypes = [vp, i64, i32, i32, i32, vp, vp, vp, vp, vp, vp, vp]
        lib.bcf_bc6h_quick.restype = None
        _lib = lib
        return lib


def block_masks(M: np.ndarray) -> np.ndarray:
    """kernel.py's per-texel BC6H subsets (uint8, 16 per block) as one int32 per block, bit p for
    texel p: one gather per tap instead of sixteen bytes."""
    M = np.concatenate([M, np.zeros(-M.size % 16, M.dtype)])
    bits = M.reshape(-1, 16).astype(np.int32) << np.arange(16, dtype=np.int32)
    return np.ascontiguousarray(bits.sum(1, dtype=np.int32))


def _p(a: np.ndarray | None, t=_f32p):
    return None if a is None or a.size == 0 else a.ctypes.data_as(t)


def _args(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, **kw):
    a = Args(fmt=fmt, quantized=int(quantized), sgn=int(signed), wrap=int(wrap), C=C,
             uv=_p(uv), P=_p(P), X=_p(X), M=_p(M, _i32p), slots=_p(slots, _i64p), blend=_p(blend),
             plo=float(plo), phi=float(phi))
    for k, v in kw.items():
        setattr(a, k, v)
    return a


def step(fmt, quantized, signed, wrap, n_chunks, uv, target, weight, P, X, M, slots, blend, C, plo, phi, utab,
         uslope, w3, w3s, w1, b1, w2, b2, out_scale, out_bias, loss_scale, gP, gX, gw1, gb1, gw2, gb2):
    """kernel.step's contract: samples in ``n_chunks`` fixed ranges, each (on its own thread when
    there are several; ctypes releases the GIL) into its own row of the g* buffers; returns the
    per-chunk sums of squared errors. ``M`` is :func:`block_masks`'. The BC6H tables are arithmetic
    in step.cpp; ``utab`` ... ``w3s`` are accepted for kernel.py's signature."""
    lib = load()
    uv, target, weight, w1, w2 = (np.ascontiguousarray(a) for a in (uv, target, weight, w1, w2))
    N = uv.shape[0]
    common = dict(n_in=w1.shape[1], hidden=w1.shape[0], n_out=w2.shape[0], target=_p(target),
                  weight=_p(weight), loss_scale=float(loss_scale), w1=_p(w1), b1=_p(b1), w2=_p(w2), b2=_p(b2),
                  out_scale=_p(out_scale), out_bias=_p(out_bias))

    def run(q: int) -> float:
        a = _args(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, a=N * q // n_chunks,
                  b=N * (q + 1) // n_chunks, gP=_p(gP[q]), gX=_p(gX[q]), gw1=_p(gw1[q]), gb1=_p(gb1[q]),
                  gw2=_p(gw2[q]), gb2=_p(gb2[q]), **common)
        return lib.bcf_step(ctypes.byref(a))

    if n_chunks == 1:
        return np.array([run(0)])
    return np.array(list(_pool(n_chunks).map(run, range(n_chunks))))


_pools: dict[int, ThreadPoolExecutor] = {}


def _pool(n: int) -> ThreadPoolExecutor:
    """One lasting pool per chunk count: a step is milliseconds, a pool's start is not free."""
    with _lock:
        if n not in _pools:
            _pools[n] = ThreadPoolExecutor(n, thread_name_prefix="bcf-fused")
            trace_pool("fused-thread-pool", n)
        return _pools[n]


def features(fmt, quantized, signed, wrap, uv, P, X, M, slots, blend, C, plo, phi, utab, uslope, w3, w3s):
    """kernel.features' contract: the (N, layers C) features the step feeds the MLP."""
    lib = load()
    out = np.zeros((uv.shape[0], len(blend) * C), np.float32)
    a = _args(fmt, quantized, signed, wrap, np.ascontiguousarray(uv), P, X, M, slots, blend, C, plo, phi, a=0,
              b=uv.shape[0], n_in=out.shape[1], feats_out=_p(out))
    lib.bcf_features(ctypes.byref(a))
    return out


def bicubic_into(tex: np.ndarray, uv: np.ndarray, wrap: int, a: float, t: float, out: np.ndarray) -> None:
    """targets.py's ``_bicubic_into``: out = bicubic(tex, uv), or lerp(out, it, t) when t >= 0."""
    lib = load()
    tex, uv = np.ascontiguousarray(tex, np.float32), np.ascontiguousarray(uv, np.float32)
    c, h, w = tex.shape
    lib.bcf_bicubic(tex.ctypes.data, c, h, w, uv.ctypes.data, uv.shape[0], int(wrap), a, t, out.ctypes.data)


def centres(mip: np.ndarray, up: np.ndarray | None, ids: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """(uv (n, 2), target (n, c)) at the texel centres ``ids`` of ``mip`` (c, h, w), lerped towards
    ``up`` (c, h w) by t as reference.CentreTargets.batch does."""
    lib = load()
    c, h, w = mip.shape
    ids = np.ascontiguousarray(ids, np.int64)
    uv, target = np.empty((ids.size, 2), np.float32), np.empty((ids.size, c), np.float32)
    lib.bcf_centres(np.ascontiguousarray(mip).ctypes.data, None if up is None else np.ascontiguousarray(up).ctypes.data,
                    c, h, w, ids.ctypes.data, ids.size, t if up is not None else 0.0, uv.ctypes.data, target.ctypes.data)
    return uv, target


def centre_rows(rows: np.ndarray, h: int, w: int, ids: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`centres` from a level kept texel by texel, ``rows`` (h w, 2 c) = [mip | up]."""
    lib = load()
    c = rows.shape[1] // 2
    ids = np.ascontiguousarray(ids, np.int64)
    uv, target = np.empty((ids.size, 2), np.float32), np.empty((ids.size, c), np.float32)
    lib.bcf_centre_rows(np.ascontiguousarray(rows).ctypes.data, c, h, w, ids.ctypes.data, ids.size, max(t, 0.0),
                        uv.ctypes.data, target.ctypes.data)
    return uv, target


def adam(p: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray, lr: float, betas: tuple[float, float],
         eps: float, step: int, lo: float, hi: float) -> None:
    """adam.cpp over one level: ``p``, ``m``, ``v`` are 1-d views of it, ``g`` its (chunks, n)
    gradient rows (a view with the storage's row stride)."""
    lib = load()
    rows, n = g.shape
    lib.bcf_adam(p.ctypes.data, g.ctypes.data, rows, g.strides[0] // 4, m.ctypes.data, v.ctypes.data, n, lr,
                 betas[0], betas[1], eps, step, lo, hi)
