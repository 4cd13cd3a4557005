"""`bcfpipe.texset.heap.reused`: while a small set is fitted, a large array freed is reused from
the heap (no fresh pages faulted in for the next); a large set, and everything after, keeps glibc's
own policy, under which each such array is mapped afresh. `one_arena` extends that to threads.

Each measure runs in a fresh interpreter: in a test worker the heap holds whatever earlier tests'
fits left free there (with `one_arena`, which the CLI sets in-process, their threads' too), and a
large array can come from that free space under any policy."""
from __future__ import annotations

import subprocess
import sys

import pytest

from bcfpipe.texset import heap

SIZE = 64 << 20  # above glibc's own largest threshold (32 MiB), below `heap.THRESHOLD`

pytestmark = pytest.mark.skipif(heap._glibc() is None, reason="the heap's policy is glibc's mallopt")

_MEASURE = """
import resource, sys, threading
import numpy as np
from bcfpipe.texset import heap

def faults_of_second():
    # minor page faults of a SIZE-byte array written whole, made after one like it was freed
    a = np.ones({size}, np.uint8)
    del a
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones({size}, np.uint8)
    del b
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

{body}
"""


def _faults(body: str, *args: str) -> list[int]:
    """What ``body`` prints (integers), run in a fresh interpreter with `faults_of_second` defined."""
    p = subprocess.run([sys.executable, "-c", _MEASURE.format(size=SIZE, body=body), *args], capture_output=True,
                       text=True, check=True)
    return [int(x) for x in p.stdout.split()]


def test_a_small_sets_fit_reuses_its_freed_arrays_and_the_policy_is_restored():
    inside, after = _faults("with heap.reused(1024):\n    inside = faults_of_second()\n"
                            "print(inside, faults_of_second())")
    assert after >= 16  # mapped afresh: at least one fault per 2 MiB huge page, 4096 per 16 MiB otherwise
    assert inside * 8 < after


def test_a_large_set_keeps_glibcs_policy():
    (inside,) = _faults(f"with heap.reused({heap.MAX_VALUES + 1}):\n    print(faults_of_second())")
    assert inside >= 16


_ON_A_THREAD = """
if sys.argv[1] == "one":
    heap.one_arena()
faults = []
def work():
    with heap.reused(1024):
        faults.append(faults_of_second())
t = threading.Thread(target=work)
t.start()
t.join()
print(faults[0])
"""


def test_one_arena_lets_a_fits_threads_reuse_the_heap():
    """A thread's own arena maps a 64 MiB array afresh whatever `reused` says; with `one_arena`
    (as the command line and a build's worker set it, before their threads) it reuses the main heap's."""
    (own,), (one,) = _faults(_ON_A_THREAD, "own"), _faults(_ON_A_THREAD, "one")
    assert own >= 16
    assert one * 8 < own
