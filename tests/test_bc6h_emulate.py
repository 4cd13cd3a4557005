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


# ---------------------------------------------------------------------------
# fused decode (one autograd node) against the composed reference
# ---------------------------------------------------------------------------

N_FUSED = 50_000


@pytest.fixture
def one_thread():
    """The fused tests run many small kernels: on a loaded machine torch's OpenMP threads mostly
    wait for each other, so these tests use one thread (restored afterwards)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


_INT = {torch.float32: torch.int32, torch.float64: torch.int64}


def _bits(t: torch.Tensor) -> torch.Tensor:
    """Exact bit patterns (tells -0 from +0)."""
    return t.detach().contiguous().view(_INT[t.dtype])


def _pick(gen, choices: list[torch.Tensor], shape) -> torch.Tensor:
    """Elementwise random choice among same-shaped candidate tensors."""
    which = torch.randint(0, len(choices), shape, generator=gen)
    out = choices[0].clone()
    for i, c in enumerate(choices[1:], 1):
        out = torch.where(which == i, c, out)
    return out


def _edge_inputs(n, signed, dtype, seed):
    """Endpoints and indices mixing continuous values, integers, the clamps and values beyond,
    round ties, exact knots k/7, values at and around the snap epsilon, and a few ulps either
    side of the snap threshold."""
    gen = torch.Generator().manual_seed(seed)
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    es = (n, 4, 3)
    rnd = lambda shape: torch.rand(shape, generator=gen, dtype=dtype)  # noqa: E731
    special = torch.tensor([lo, hi, lo + 1, hi - 1, lo - 1e-3, hi + 1e-3, lo + 1e-6, hi - 1e-6, 0.0, -0.0,
                            0.5, -0.5, 1.5, 2.5, 0.49999997, 30.5, 31.0, -31.0, -32.0, 62.5, 63.0,
                            -7e-4, -8e-4, -9e-4, 7e-4], dtype=dtype)  # -1 < p < 0 for the floor
    e = _pick(gen, [
        rnd(es) * (hi - lo + 3) + lo - 1.5,  # continuous, partly beyond the clamps
        torch.randint(int(lo), int(hi) + 1, es, generator=gen).to(dtype),  # integers
        torch.randint(int(lo), int(hi) + 1, es, generator=gen).to(dtype) + 0.5,  # round ties
        special[torch.randint(0, len(special), es, generator=gen)],
    ], es)
    xs = (n, 16)
    k = torch.randint(0, 8, xs, generator=gen).to(dtype)
    knot = k / 7.0
    eps = torch.tensor(1e-4, dtype=dtype)
    # the snap test is |7x - k| < 7e-4 (in the compute dtype): a few ulps around x = (k +- 7e-4) / 7
    t_edge = (k + torch.where(rnd(xs) < 0.5, 1.0, -1.0).to(dtype) * torch.tensor(7e-4, dtype=dtype)) / 7.0
    ulps = torch.randint(-8, 9, xs, generator=gen).to(_INT[dtype])
    near_threshold = (t_edge.view(_INT[dtype]) + ulps).view(dtype)
    x = _pick(gen, [
        rnd(xs) * 1.1 - 0.05,  # continuous, partly beyond [0, 1]
        knot,  # exact k/7 in this dtype
        knot + (rnd(xs) * 2.4 - 1.2) * eps,  # within (and just beyond) the snap epsilon
        near_threshold,
        (k + 0.5) / 7.0,  # round ties of 7x
        torch.tensor([0.0, 1.0, -0.0, 1e-30, 1.0 - 1e-7, -1e-7, 1.0 + 1e-7], dtype=dtype)[
            torch.randint(0, 7, xs, generator=gen)],
    ], xs)
    mask = torch.rand(xs, generator=gen) < 0.5
    return e, x, mask


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("signed", [False, True])
def test_fused_forward_bit_identical_to_composed(signed, dtype, one_thread):
    e, x, mask = _edge_inputs(N_FUSED, signed, dtype, seed=11 + signed)
    for quantized in (False, True):
        with torch.no_grad():
            ref = emulate.decode_blocks_composed(e, x, mask, signed=signed, quantized=quantized)
            got = emulate.decode_blocks(e, x, mask, signed=signed, quantized=quantized)
        assert got.shape == ref.shape and got.dtype == ref.dtype == dtype
        diff = int((_bits(got) != _bits(ref)).sum())
        assert diff == 0, f"{diff} texel values differ (quantized={quantized})"
    # with gradients enabled the fused forward takes another path: same values
    eg, xg = e[:2000].clone().requires_grad_(True), x[:2000].clone().requires_grad_(True)
    got = emulate.decode_blocks(eg, xg, mask[:2000], signed=signed, quantized=quantized)
    assert torch.equal(_bits(got), _bits(ref[:2000]))


def _grads(fn, e, x, mask, g, signed, quantized):
    e, x = e.clone().requires_grad_(True), x.clone().requires_grad_(True)
    out = fn(e, x, mask, signed=signed, quantized=quantized)
    ge, gx = torch.autograd.grad(out, (e, x), g)
    return out.detach(), ge, gx


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("signed", [False, True])
@pytest.mark.parametrize("quantized", [False, True])
def test_fused_gradients_equal_composed(signed, quantized, dtype, one_thread):
    n = 4000
    e, x, mask = _edge_inputs(n, signed, dtype, seed=21 + 2 * signed + quantized)
    g = torch.randn((n, 16, 3), generator=torch.Generator().manual_seed(3), dtype=dtype)
    g[: n // 4] = 1.0  # also the plain sum
    ref = _grads(emulate.decode_blocks_composed, e, x, mask, g, signed, quantized)
    got = _grads(emulate.decode_blocks, e, x, mask, g, signed, quantized)
    assert torch.equal(_bits(got[0]), _bits(ref[0]))
    # float32: the composed backward itself has rounding (e.g. dL/dw = sum g ub - sum g ua
    # cancels), hence a small absolute term relative to the gradient's scale
    rtol, atol_rel = (1e-5, 1e-6) if dtype == torch.float32 else (1e-10, 1e-13)
    for name, a, b in (("endpoints", got[1], ref[1]), ("x", got[2], ref[2])):
        assert a.dtype == dtype
        atol = atol_rel * float(b.abs().max())
        assert torch.allclose(a, b, rtol=rtol, atol=atol), (
            f"{name}: max |diff| {float((a - b).abs().max()):.3g}, max |grad| {float(b.abs().max()):.3g}")
    # outside the clamps the gradient is exactly zero, at the clamps it is passed
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    assert torch.all(got[1][(e < lo) | (e > hi)] == 0) and torch.all(got[2][(x < 0) | (x > 1)] == 0)
    at = (e == lo) | (e == hi)
    assert torch.equal(got[1][at] == 0, ref[1][at] == 0)


@pytest.mark.parametrize("signed", [False, True])
def test_fused_backward_gradcheck(signed, one_thread):
    """The fused backward is the derivative of the straight-through surrogate (every floor /
    trunc / round taken away, the half exponent h held at its decoded value).  torch's gradcheck
    compares it, as the analytic Jacobian, with central differences of that surrogate, in
    float64 at points away from every kink (the decoder itself is piecewise constant)."""
    gen = torch.Generator().manual_seed(5 + signed)
    lo, hi = (-32.0, 31.0) if signed else (0.0, 63.0)
    n = 6
    e = torch.randint(int(lo) + 1, int(hi) - 1, (n, 4, 3), generator=gen).double()
    e += 0.2 + 0.6 * torch.rand((n, 4, 3), generator=gen, dtype=torch.float64)
    x = (torch.randint(0, 7, (n, 16), generator=gen).double() + 0.2
         + 0.6 * torch.rand((n, 16), generator=gen, dtype=torch.float64)) / 7.0
    mask = emulate.partition_mask(torch.arange(n) * 5 % 32)
    with torch.no_grad():
        decoded = emulate.decode_blocks(e, x, mask, signed=signed)
    abs_f = decoded.numpy().astype(np.float16).view(np.uint16).astype(np.int64) & 0x7FFF  # |F|
    h = torch.tensor(np.maximum(abs_f // 1024 - 1, 0), dtype=torch.float64)
    sign = torch.sign(decoded)
    c = 31.0 / 32.0 if signed else 31.0 / 64.0

    class SurrogateWithFusedBackward(torch.autograd.Function):
        @staticmethod
        def forward(ctx, ee, xx):
            ctx.save_for_backward(ee, xx)
            u = emulate.unquantize(ee, signed=signed)
            m = mask.unsqueeze(-1)
            ua = torch.where(m, u[:, None, 2], u[:, None, 0])
            ub = torch.where(m, u[:, None, 3], u[:, None, 1])
            w = emulate.index_weight(xx).unsqueeze(-1)
            f = (ua * (64 - w) + ub * w + 32) / 64 * c
            return torch.exp2(h - 14) * (f / 1024 - sign * h)

        @staticmethod
        def backward(ctx, g):
            ee, xx = (t.detach().requires_grad_(True) for t in ctx.saved_tensors)
            with torch.enable_grad():
                out = emulate.decode_blocks(ee, xx, mask, signed=signed)  # the fused node
            return torch.autograd.grad(out, (ee, xx), g)

    assert torch.autograd.gradcheck(SurrogateWithFusedBackward.apply,
                                    (e.requires_grad_(True), x.requires_grad_(True)), eps=1e-6, atol=1e-9)


def test_fused_input_handling(one_thread):
    rng = np.random.default_rng(9)
    n = 300
    e0 = torch.tensor(rng.uniform(-1, 64, (n, 3, 4)), dtype=torch.float32)
    x0 = torch.tensor(rng.uniform(0, 1, (16, n)), dtype=torch.float32)
    mask = emulate.partition_mask(rng.integers(0, 32, n))
    e, x = e0.transpose(1, 2), x0.t()  # non-contiguous views
    ref = emulate.decode_blocks_composed(e, x, mask)
    assert torch.equal(emulate.decode_blocks(e, x, mask), ref)
    assert torch.equal(emulate.decode_blocks(e, x, mask.float()), ref)  # float mask
    assert torch.equal(emulate.decode_blocks(e.half(), x, mask), emulate.decode_blocks_composed(e.half(), x, mask))
    # gradient for one input only, a broadcast grad_output (out.sum())
    xg = x.clone().requires_grad_(True)
    emulate.decode_blocks(e, xg, mask).sum().backward()
    xr = x.clone().requires_grad_(True)
    emulate.decode_blocks_composed(e, xr, mask).sum().backward()
    assert torch.allclose(xg.grad, xr.grad, rtol=1e-5, atol=1e-6 * float(xr.grad.abs().max()))
    eg = e.clone().requires_grad_(True)
    emulate.decode_blocks(eg, x, mask, signed=False).sum().backward()
    assert eg.grad.shape == (n, 4, 3) and torch.isfinite(eg.grad).all()
    # no blocks
    empty = emulate.decode_blocks(torch.zeros(0, 4, 3, requires_grad=True), torch.zeros(0, 16), torch.zeros(0, 16))
    assert empty.shape == (0, 16, 3)
    # double precision half_from_bits is the bit-cast too (the fused forward relies on it)
    y = np.arange(0, 31744)
    want = y.astype(np.uint16).view(np.float16).astype(np.float64)
    got = emulate.half_from_bits(torch.tensor(np.concatenate([y, -y]), dtype=torch.float64)).numpy()
    assert np.array_equal(got, np.concatenate([want, -want]))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_fused_equals_composed_on_cuda():
    for signed in (False, True):
        e, x, mask = _edge_inputs(20_000, signed, torch.float32, seed=31 + signed)
        e, x, mask = e.cuda(), x.cuda(), mask.cuda()
        g = torch.randn((20_000, 16, 3), device="cuda")
        for quantized in (False, True):
            ref = _grads(emulate.decode_blocks_composed, e, x, mask, g, signed, quantized)
            got = _grads(emulate.decode_blocks, e, x, mask, g, signed, quantized)
            assert torch.equal(_bits(got[0]), _bits(ref[0]))
            assert torch.equal(_bits(got[0].cpu()), _bits(emulate.decode_blocks(
                e.cpu(), x.cpu(), mask.cpu(), signed=signed, quantized=quantized)))
            for a, b in zip(got[1:], ref[1:]):
                assert torch.allclose(a, b, rtol=1e-5, atol=1e-6 * float(b.abs().max()))
