"""`bcfpipe.texset.heap.reused`: while a small set is fitted, a large array freed is reused from
the heap (no fresh pages faulted in for the next); a large set, and everything after, keeps glibc's
own policy, under which each such array is mapped afresh."""
from __future__ import annotations

import resource

import numpy as np
import pytest

from bcfpipe.texset import heap

SIZE = 64 << 20  # above glibc's own largest threshold (32 MiB), below `heap.THRESHOLD`

pytestmark = pytest.mark.skipif(heap._glibc() is None, reason="the heap's policy is glibc's mallopt")


def _faults_of_second() -> int:
    """Minor page faults of a SIZE-byte array written whole, made after one like it was freed."""
    a = np.ones(SIZE, np.uint8)
    del a
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    b = np.ones(SIZE, np.uint8)
    del b
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


def test_a_small_sets_fit_reuses_its_freed_arrays_and_the_policy_is_restored():
    with heap.reused(1024):
        inside = _faults_of_second()
    after = _faults_of_second()
    assert after >= 16  # mapped afresh: at least one fault per 2 MiB huge page, 4096 per 16 MiB otherwise
    assert inside * 8 < after


def test_a_large_set_keeps_glibcs_policy():
    with heap.reused(heap.MAX_VALUES + 1):
        inside = _faults_of_second()
    assert inside >= 16


_ON_A_THREAD = """
import resource, sys, threading
import numpy as np
from bcfpipe.texset import heap
if sys.argv[1] == "one":
    heap.one_arena()
faults = []
def work():
    with heap.reused(1024):
        a = np.ones({size}, np.uint8)
        del a
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        b = np.ones({size}, np.uint8)
        del b
        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
t = threading.Thread(target=work)
t.start()
t.join()
print(faults[0])
"""


def test_one_arena_lets_a_fits_threads_reuse_the_heap():
    """A thread's own arena maps a 64 MiB array afresh whatever `reused` says; with `one_arena`
    (as the command line and a build's worker set it, before their threads) it reuses the main heap's."""
    import subprocess
    import sys

    def faults(mode: str) -> int:
        p = subprocess.run([sys.executable, "-c", _ON_A_THREAD.format(size=SIZE), mode], capture_output=True,
                           text=True, check=True)
        return int(p.stdout.split()[-1])

    own, one = faults("own"), faults("one")
    assert own >= 16
    assert one * 8 < own
