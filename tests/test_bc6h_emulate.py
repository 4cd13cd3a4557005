"""Differentiable BC6H mode-10 emulation (bcfpipe.bc6h.emulate) against the bit-exact decoder."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bcfpipe.bc6h import emulate, mode10
from bcfpipe.bc6h.decode import decode_to_u16
from bcfpipe.bc6h.tables import WEIGHTS3

N_EXACT = 100_000


def _random_params(rng, n, signed):
    lo, hi = (-32, 31) if signed else (0, 63)
    e = rng.integers(lo, hi + 1, (n, 4, 3))
    # a third of the blocks use only the range ends and their neighbours (special cases
    # of unquantize: 0, 63 / +-31, -32) so they are well covered
    edge = np.array([lo, lo + 1, hi - 1, hi, 0, 1] if signed else [lo, lo + 1, hi - 1, hi])
    sel = rng.random(n) < 1 / 3
    e[sel] = rng.choice(edge, (int(sel.sum()), 4, 3))
    idx = rng.integers(0, 8, (n, 16))
    part = rng.integers(0, 32, n)
    return e, idx, part


@pytest.mark.parametrize("signed", [False, True])
def test_bit_exact_at_quantized_parameters(signed):
    rng = np.random.default_rng(1234 + signed)
    e, idx, part = _random_params(rng, N_EXACT, signed)
    blocks = mode10.pack(e, idx, part, signed=signed)
    ref = decode_to_u16(blocks, signed=signed)  # (n, 16, 3) half bits, independent decoder
    ref_f32 = ref.view(np.float16).astype(np.float32)
    for quantized in (False, True):
        E, X, M, _ = emulate.from_blocks(blocks, signed=signed)
        with torch.no_grad():
            out = emulate.decode_blocks(E, X, M, signed=signed, quantized=quantized).numpy()
        assert out.dtype == np.float32 and out.shape == (N_EXACT, 16, 3)
        mismatches = int((out.astype(np.float16).view(np.uint16) != ref).sum())
        assert mismatches == 0, f"{mismatches} differing halves (quantized={quantized})"
        # and exactly representable: no rounding happened in the float16 conversion
        assert np.array_equal(out, ref_f32)
    # the unpacked parameters (anchor-canonical) and the original ones decode the same
    E2, X2, M2, _ = emulate.from_params(e, idx, part)
    with torch.no_grad():
        out2 = emulate.decode_blocks(E2, X2, M2, signed=signed).numpy()
    assert np.array_equal(out2, ref_f32)


def test_eq8_is_the_half_bitcast_including_subnormals():
    y = np.arange(0, 31744)
    want = y.astype(np.uint16).view(np.float16).astype(np.float32)
    got = emulate.half_from_bits(torch.tensor(y, dtype=torch.float32)).numpy()
    assert np.array_equal(got, want)
    # signed: sign-magnitude
    got_neg = emulate.half_from_bits(torch.tensor(-y, dtype=torch.float32)).numpy()
    assert np.array_equal(got_neg, -want)
    # the paper's own h(y) = max(floor((y-1)/1024) - 1, 0) agrees at every integer
    yf = y.astype(np.float64)
    h_paper = np.maximum(np.floor((yf - 1) / 1024) - 1, 0)
    assert np.array_equal(2.0 ** (h_paper - 14) * (yf / 1024 - h_paper), want.astype(np.float64))
    # between integers: the linear interpolant of the bit-cast (continuous, monotone)
    mid = emulate.half_from_bits(torch.tensor(y[:-1] + 0.5, dtype=torch.float64)).numpy()
    assert np.allclose(mid, (want[:-1].astype(np.float64) + want[1:]) / 2, rtol=1e-12, atol=0)


@pytest.mark.parametrize("signed", [False, True])
def test_unquantize_matches_spec_and_is_continuous(signed):
    codes, u = mode10.unquantize_table(signed)
    got = emulate.unquantize(torch.tensor(codes, dtype=torch.float64), signed=signed).numpy()
    assert np.array_equal(got, u.astype(np.float64))
    if not signed:
        # spec formula for the ordinary codes; 0 -> 0 and 63 -> 0xFFFF
        assert u[0] == 0 and u[63] == 0xFFFF
        assert all(u[e] == ((e << 16) + 0x8000) >> 6 for e in range(1, 63))
    else:
        assert u[0] == -0x7FFF and u[1] == -0x7FFF and u[-1] == 0x7FFF and u[32] == 0
    x = torch.linspace(float(codes[0]), float(codes[-1]), 2001, dtype=torch.float64)
    v = emulate.unquantize(x, signed=signed).numpy()
    assert np.all(np.diff(v) >= 0)  # monotone, no jumps beyond the table's own steps
    assert np.max(np.abs(np.diff(v))) <= 1536 * (x[1] - x[0]).item() + 1e-6


def test_index_weight_mapping():
    k = torch.arange(8, dtype=torch.float64)
    w = emulate.index_weight(k / 7.0)
    assert torch.equal(w, torch.tensor(WEIGHTS3, dtype=torch.float64))
    # float32 k/7 also hits the weights exactly (snapping)
    w32 = emulate.index_weight((torch.arange(8, dtype=torch.float32) / 7.0))
    assert torch.equal(w32, torch.tensor(WEIGHTS3, dtype=torch.float32))
    x = torch.linspace(0, 1, 701, dtype=torch.float64)
    wx = emulate.index_weight(x)
    assert torch.all(wx[1:] >= wx[:-1]) and wx[0] == 0 and wx[-1] == 64
    # linear between the knots
    mid = emulate.index_weight((k[:-1] + 0.5) / 7.0)
    assert torch.allclose(mid, (w[:-1] + w[1:]) / 2)
    # quantization = round(7x)
    wq = emulate.index_weight(torch.tensor([0.2 / 7, 3.4 / 7, 3.6 / 7, 6.9 / 7]), quantized=True)
    assert wq.tolist() == [0.0, 27.0, 37.0, 64.0]


@pytest.mark.parametrize("signed", [False, True])
def test_gradients_finite_at_range_ends(signed):
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    vals = [lo, lo + 0.5, hi - 0.5, hi, 0.0, 0.3, 1.0, 1.7, 62.2] if not signed else [
        lo, lo + 1, -0.4, 0.0, 0.4, 1.0, 30.6, hi]
    n = len(vals) ** 2
    a, b = np.meshgrid(vals, vals, indexing="ij")
    e = np.zeros((n, 4, 3))
    e[:, 0], e[:, 1] = a.reshape(-1, 1), b.reshape(-1, 1)
    e[:, 2], e[:, 3] = b.reshape(-1, 1), a.reshape(-1, 1)
    endpoints = torch.tensor(e, dtype=torch.float32, requires_grad=True)
    xs = torch.tensor([0.0, 1.0, 1 / 7, 0.5, 6 / 7, 0.999, 1e-4, 3 / 7] * 2, dtype=torch.float32)
    x = xs.repeat(n, 1).requires_grad_(True)
    mask = emulate.partition_mask(np.arange(n) % 32)
    for quantized in (False, True):
        out = emulate.decode_blocks(endpoints, x, mask, signed=signed, quantized=quantized)
        assert torch.isfinite(out).all()
        # a loss whose gradient reaches every texel, including near-zero (subnormal) ones
        loss = (out * torch.linspace(0.5, 1.5, 3)).sum() + (out.abs() + 1e-3).log().sum()
        ge, gx = torch.autograd.grad(loss, (endpoints, x))
        assert torch.isfinite(ge).all() and torch.isfinite(gx).all()
        assert ge.abs().sum() > 0 and gx.abs().sum() > 0


def test_gradients_flow_through_straight_through_rounding():
    torch.manual_seed(0)
    e = (torch.rand(64, 4, 3, dtype=torch.float64) * 40 + 10).requires_grad_(True)
    x = torch.rand(64, 16, dtype=torch.float64).requires_grad_(True)
    mask = emulate.partition_mask(torch.arange(64) % 32)
    out = emulate.decode_blocks(e, x, mask)
    assert out.dtype == torch.float64
    out.sum().backward()
    # increasing an endpoint never decreases the texels (monotone decode), gradients positive
    assert (e.grad >= 0).all() and (e.grad > 0).any()
    # d out / d x has the sign of (e_b - e_a)
    assert torch.isfinite(x.grad).all() and (x.grad.abs() > 0).any()
    # finite-difference check of the (straight-through) gradient on a smooth surrogate:
    # the forward of a continuous endpoint lies within one half-bit step of the
    # linearisation
    e0 = torch.full((1, 4, 3), 40.25, dtype=torch.float64)
    e0[0, 1] = 47.75
    x0 = torch.full((1, 16), 0.4, dtype=torch.float64)
    m0 = torch.zeros(1, 16, dtype=torch.bool)
    f = lambda ee: emulate.decode_blocks(ee, x0, m0)[0, 0, 0]  # noqa: E731
    h = 0.25
    fd = (f(e0 + torch.tensor([h, 0, 0, 0]).view(1, 4, 1)) - f(e0)) / h
    ee = e0.clone().requires_grad_(True)
    f(ee).backward()
    assert torch.isclose(ee.grad[0, 0, 0], fd, rtol=0.1)


def test_quantized_flag_equals_decode_of_rounded_parameters():
    rng = np.random.default_rng(5)
    n = 2000
    e = torch.tensor(rng.uniform(-0.4, 63.4, (n, 4, 3)), dtype=torch.float32)
    x = torch.tensor(rng.uniform(0, 1, (n, 16)), dtype=torch.float32)
    part = rng.integers(0, 32, n)
    mask = emulate.partition_mask(part)
    with torch.no_grad():
        out = emulate.decode_blocks(e, x, mask, quantized=True).numpy()
    blocks = emulate.to_blocks(e, x, part)
    assert np.array_equal(out.astype(np.float16).view(np.uint16), decode_to_u16(blocks))
    # round trip of the parameter helpers
    ep, ix, pt = emulate.to_params(e, x, part)
    E, X, M, P = emulate.from_params(ep, ix, pt)
    assert torch.equal(M, mask) and np.array_equal(P.numpy(), part)
    assert torch.equal(E, torch.round(e).clamp(0, 63))


def test_output_follows_input_device_and_dtype():
    e = torch.full((2, 4, 3), 30.0, dtype=torch.float64)
    x = torch.full((2, 16), 0.5, dtype=torch.float32)
    m = torch.zeros(2, 16)
    out = emulate.decode_blocks(e, x, m)
    assert out.dtype == torch.float64 and out.device == e.device
    out16 = emulate.decode_blocks(e.half(), x, m)
    assert out16.dtype == torch.float32
    with pytest.raises(ValueError):
        emulate.decode_blocks(e[:, :3], x, m)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_bit_exact_on_cuda():
    rng = np.random.default_rng(7)
    for signed in (False, True):
        e, idx, part = _random_params(rng, 20_000, signed)
        blocks = mode10.pack(e, idx, part, signed=signed)
        E, X, M, _ = emulate.from_blocks(blocks, signed=signed, device="cuda")
        out = emulate.decode_blocks(E, X, M, signed=signed).cpu().numpy()
        assert out.dtype == np.float32
        assert np.array_equal(out.astype(np.float16).view(np.uint16), decode_to_u16(blocks, signed=signed))
