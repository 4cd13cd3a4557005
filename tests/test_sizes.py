"""The one byte estimator (bcfpipe/formats/sizes.py, issue 51) against the arithmetic of the three it
replaced, for every profile, both feature formats and several decoder shapes: rate control's
feature blocks (`train/rate._feature_bytes`) and scan's file bytes (`scan/requirements.estimated_bytes`)
are kept exactly; the layout rule's `neural_bytes` (no DDS headers, the record as 2 bytes a value
plus 64) was 552 bytes short of the files, 554 with an odd number of values, and is now the
files' bytes. tests/test_build.py::test_size_estimate_equals_a_real_build compares with a build."""
from __future__ import annotations

import math

import pytest

from bcfpipe.config import LAYER_CHANNELS_OF, N_LAYERS, PROFILE_NAMES, PROFILES, mip_count, resolve_profile
from bcfpipe.formats import dds, weights
from bcfpipe.formats.sizes import feature_bytes, feature_levels, neural_bytes
from bcfpipe.formats.vocabulary import FeatureFormat


def _resolutions() -> list[tuple[int, ...]]:
    """Every profile resolved for sources small and large (auto-N included), and mip splits."""
    out = {tuple(resolve_profile(name, side)[1]) for name in PROFILE_NAMES for side in (4, 8, 100, 512, 1000, 4096)}
    out |= {(t, t, t, t // 2) for t in (8, 16, 64, 256)}
    return sorted(out)


def _rate_feature_bytes(resolutions) -> int:
    """train/rate._feature_bytes as it was: 16 bytes per 4x4 block while the side is at least 4."""
    total = 0
    for r in resolutions:
        while r >= 4:
            total += (r // 4) ** 2 * 16
            r //= 2
    return total


def _scan_estimated_bytes(resolutions, n_out: int, hidden: int, n_in: int) -> int:
    """scan/requirements.estimated_bytes as it was: headers, mips by config.mip_count, the record."""
    features = sum(dds.HEADER_BYTES + sum(max(4, r >> k) ** 2 for k in range(mip_count(r))) for r in resolutions)
    return features + weights.record_size(weights.record_halves(n_in, hidden, n_out))


def _layout_neural_bytes(resolutions, n_in: int, hidden: int, n_out: int) -> int:
    """layout/predict.neural_bytes as it was: blocks only, and 2 bytes a record value plus 64."""
    return _rate_feature_bytes(resolutions) + 2 * (n_in * hidden + hidden + hidden * n_out + 3 * n_out) + 64


CASES = [(res, fmt, n_out, hidden) for res in _resolutions() for fmt in FeatureFormat
         for n_out in (1, 4, 9, 11) for hidden in (16, 32)]


def test_the_cases_cover_every_profile():
    resolutions = {res for res, *_ in CASES}
    assert set(PROFILES.values()) <= resolutions and {(4, 4, 4, 4), (8, 4, 4, 4)} <= resolutions
    assert len(CASES) == 16 * len(resolutions) >= 16 * 10


@pytest.mark.parametrize("res", _resolutions())
def test_feature_bytes_are_rate_controls(res):
    assert feature_bytes(res) == _rate_feature_bytes(res)
    assert feature_bytes(res, headers=True) == _rate_feature_bytes(res) + N_LAYERS * dds.HEADER_BYTES
    assert all(len(feature_levels(r)) == mip_count(r) and feature_levels(r)[-1] == 4 for r in res)


def test_neural_bytes_are_scans_and_the_layout_rule_was_short_by_552_or_554():
    shortfall = set()
    for res, fmt, n_out, hidden in CASES:
        n_in = N_LAYERS * LAYER_CHANNELS_OF[fmt]
        exact = neural_bytes(res, n_in, hidden, n_out)
        assert exact == _scan_estimated_bytes(res, n_out, hidden, n_in), (res, fmt, n_out, hidden)
        short = exact - _layout_neural_bytes(res, n_in, hidden, n_out)
        assert short == 552 + 2 * (n_out % 2), (res, fmt, n_out, hidden)  # 4 headers - 40; the record's pad
        shortfall.add(short)
    assert shortfall == {552, 554}


def test_an_hdr_record_adds_a_value_per_output():
    res, n_in, hidden = (512, 256, 128, 64), 12, 16
    for n_out in (1, 4, 9, 11):
        v1, v2 = neural_bytes(res, n_in, hidden, n_out), neural_bytes(res, n_in, hidden, n_out, version=2)
        assert v2 - v1 == 2 * n_out - 2 * (n_out % 2)  # v1's pad (an odd count of values) is v2's log_gain
        assert v2 - feature_bytes(res, headers=True) == weights.RECORD_HEADER.size + 4 * math.ceil(
            weights.record_halves(n_in, hidden, n_out, 2) / 2)
