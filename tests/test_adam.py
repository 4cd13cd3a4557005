"""`train.adam.DecayedAdam` is ``torch.optim.Adam(fused=True)`` with ``LambdaLR``'s exponential decay,
bit for bit, without importing torch._dynamo (what torch.optim's step does on its first call)."""
from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from bcfpipe.train.adam import DecayedAdam


def _params(seed: int) -> list[list[torch.Tensor]]:
    g = torch.Generator().manual_seed(seed)
    feats = [torch.randn(4, 16, 16, generator=g, requires_grad=True), torch.randn(3, 8, 8, generator=g, requires_grad=True)]
    mlp = [torch.randn(16, 12, generator=g, requires_grad=True), torch.randn(16, generator=g, requires_grad=True)]
    return [feats, mlp]


def _loss(groups, t: int) -> torch.Tensor:
    """A loss whose gradients change from step to step, and that leaves one tensor without a gradient once."""
    total = sum((p * p * (1 + 0.1 * t)).sum() + p.sin().sum() for g in groups for p in g if not (t == 3 and p.dim() == 1))
    return total


@pytest.mark.parametrize("rates,gammas", [((0.01, 0.003), (0.999, 0.9995)), ((0.2,), (0.98,))])
def test_same_parameters_as_torch_adam_with_lambdalr(rates, gammas):
    ours, theirs = _params(1)[-len(rates):], _params(1)[-len(rates):]
    opt = DecayedAdam(ours, rates, gammas, "cpu")
    ref = torch.optim.Adam([{"params": g, "lr": r} for g, r in zip(theirs, rates)], fused=True)
    sched = torch.optim.lr_scheduler.LambdaLR(ref, [lambda t, g=g: g ** t for g in gammas])
    for t in range(40):
        opt.zero_grad()
        _loss(ours, t).backward()
        opt.step()
        ref.zero_grad(set_to_none=True)
        _loss(theirs, t).backward()
        ref.step()
        sched.step()
        for a, b in zip(sum(ours, []), sum(theirs, [])):
            assert torch.equal(a, b), f"step {t}"
    assert opt.rate(0) == ref.param_groups[0]["lr"]


def test_training_imports_no_dynamo():
    code = ("import sys, torch; from bcfpipe.train.adam import DecayedAdam; p = torch.ones(3, requires_grad=True); "
            "o = DecayedAdam([[p]], [0.1], [0.99], 'cpu'); (p * p).sum().backward(); o.step(); "
            "print('torch._dynamo' in sys.modules, float(p[0]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out[0] == "False" and float(out[1]) < 1.0
