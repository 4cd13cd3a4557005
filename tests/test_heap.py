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
