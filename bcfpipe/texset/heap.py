"""Large arrays reused from the process's heap while a material is fitted, not mapped afresh (issue 58).

glibc serves an allocation above its mmap threshold (which it raises to at most 32 MiB as such
blocks are freed) with pages of its own, and returns them when the block is freed: the next array
of that size faults in new pages, which Linux zeroes first. A 2048² fit's temporaries are mostly
larger than that (a 2048² level of three float32 channels is 48 MiB): the water bottle's default fit at
draft spent 9.8 % of its CPU time in the kernel's ``clear_page_erms`` (``perf record``), about
4 CPU-s of 39. While `reused` holds, allocations up to `THRESHOLD` come from the heap and freed
ones are kept there (up to `KEEP` at its top) for the next: that fit took 19.3 s instead of
20.4-21.9 s, its system time 2.3 s instead of 4.1-5.3 s, at about the same peak (1.77-1.79 GB);
`--layout neural` on it 43.9 -> 37.3 s, its peak 1.94 -> 2.24 GB (docs/benchmarks.md).

The policy is the main heap's. A thread of its own arena grows it in heaps of at most 64 MiB and
maps anything larger afresh, whatever the thresholds: the BC@R encode beside the probe decodes
2048² levels of 64 MiB on its thread. `one_arena`, called before a process starts threads (the
command line, a build's worker), puts every thread's allocations on the main heap.

A set larger than `MAX_VALUES` keeps glibc's own policy: a heap that keeps what it frees can hold
blocks that no later request fits, and an 8K fit's peak memory is one of its limits.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import sys

MAX_VALUES = 2048 * 2048 * 16  # texels times channels of the largest set whose fit reuses its heap
THRESHOLD = 256 << 20  # bytes: larger allocations are still mapped (and returned) on their own
KEEP = 1 << 30  # bytes of freed memory the heap keeps at its top before it returns any
# glibc's own policy afterwards, as it stands once it has adjusted to large blocks (mallopt fixes both)
AFTER = (32 << 20, 64 << 20)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8  # malloc.h


def _glibc():
    """glibc's C library, or None (another libc, or not Linux)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        libc.gnu_get_libc_version  # noqa: B018 - glibc has it, musl has not
        return libc
    except (OSError, AttributeError):
        return None


@contextlib.contextmanager
def reused(values: int):
    """Within: allocations up to `THRESHOLD` from the heap, kept when freed, where a set of
    ``values`` (texels times channels) is at most `MAX_VALUES` and the C library is glibc; after:
    glibc's adjusted policy (`AFTER`), what the heap kept returned."""
    libc = _glibc() if values <= MAX_VALUES else None
    if libc is None:
        yield
        return
    libc.mallopt(_M_MMAP_THRESHOLD, THRESHOLD)
    libc.mallopt(_M_TRIM_THRESHOLD, KEEP)
    try:
        yield
    finally:
        libc.mallopt(_M_MMAP_THRESHOLD, AFTER[0])
        libc.mallopt(_M_TRIM_THRESHOLD, AFTER[1])
        libc.malloc_trim(0)


def one_arena() -> None:
    """Every thread made from now on allocates from the main heap (glibc's ``M_ARENA_MAX`` of 1),
    so that `reused` holds on the fit's threads too; threads that have allocated already keep their
    arenas. Nothing where the C library is not glibc."""
    libc = _glibc()
    if libc is not None:
        libc.mallopt(_M_ARENA_MAX, 1)
