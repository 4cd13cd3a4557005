"""Adam with a per-group exponential learning-rate decay (paper §5.1: lr_g · γ_g^t at step t), the
optimizer of every training phase.

On the CPU and CUDA it is torch's fused Adam kernel (``torch._fused_adam_``) called as
``torch.optim.Adam(fused=True)`` calls it, with the rate ``LambdaLR`` would set: the same
parameters, bit for bit (tests/test_adam.py). ``torch.optim``'s ``step`` imports torch._dynamo on
its first call, 1.5 s on this project's CPU, paid by every process that trains: the layout's
probe, whose cost is held to a quarter of a neural run, included. Elsewhere (mps, xpu) it is
``torch.optim.Adam`` itself.
"""
from __future__ import annotations

import os
import sys
import tempfile
from collections import defaultdict
from typing import Sequence

import torch

__all__ = ["DecayedAdam", "FUSED_DEVICES"]

FUSED_DEVICES = ("cpu", "cuda")  # where torch.optim.Adam(fused=True) runs, and this class with it
BETAS, EPS = (0.9, 0.999), 1e-8  # torch.optim.Adam's defaults


def _import_dynamo_quietly() -> None:
    """torch.optim imports torch._dynamo, whose import creates an inductor cache folder in the
    temporary folder and leaves it there. Nothing here compiles, so the import gets a throwaway
    folder: bcfpipe writes only to OUT and its cache."""
    if "torch._dynamo" in sys.modules or "TORCHINDUCTOR_CACHE_DIR" in os.environ:
        return
    with tempfile.TemporaryDirectory(prefix="bcfpipe-torch-") as tmp:
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = tmp
        try:
            import torch._dynamo  # noqa: F401 - lazy: start-up
        finally:
            os.environ.pop("TORCHINDUCTOR_CACHE_DIR", None)


class DecayedAdam:
    """Adam over parameter groups, group g at rate ``rates[g] · gammas[g] ** t`` after t steps
    (``step`` applies the update, then moves t on, as ``opt.step(); LambdaLR.step()`` do)."""

    def __init__(self, groups: Sequence[Sequence[torch.Tensor]], rates: Sequence[float], gammas: Sequence[float],
                 device: torch.device | str):
        self.groups = [list(g) for g in groups]
        self.rates, self.gammas, self.t = list(rates), list(gammas), 0
        self.fused = torch.device(device).type in FUSED_DEVICES
        self.state: dict[torch.Tensor, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        self.torch_opt = self.torch_sched = None
        if not self.fused:
            _import_dynamo_quietly()
            self.torch_opt = torch.optim.Adam([{"params": g, "lr": r} for g, r in zip(self.groups, self.rates)])
            self.torch_sched = torch.optim.lr_scheduler.LambdaLR(
                self.torch_opt, [lambda t, g=g: g ** t for g in self.gammas])

    def zero_grad(self) -> None:
        for g in self.groups:
            for p in g:
                p.grad = None

    def rate(self, g: int) -> float:
        """Group ``g``'s rate at this step: LambdaLR's base · λ(t)."""
        return self.rates[g] * (self.gammas[g] ** self.t)

    @torch.no_grad()
    def step(self) -> None:
        if not self.fused:
            self.torch_opt.step()
            self.torch_sched.step()
            return
        for g, params in enumerate(self.groups):
            by_kind: dict[tuple, list[torch.Tensor]] = defaultdict(list)  # the kernel takes one device and dtype
            for p in params:
                if p.grad is not None:
                    by_kind[p.device, p.dtype].append(p)
            for ps in by_kind.values():
                for p in ps:
                    if p not in self.state:  # Adam's lazy state: a float32 step count, zeroed moments
                        self.state[p] = (torch.zeros((), dtype=torch.float32, device=p.device),
                                         torch.zeros_like(p, memory_format=torch.preserve_format),
                                         torch.zeros_like(p, memory_format=torch.preserve_format))
                steps, avgs, sqs = ([self.state[p][i] for p in ps] for i in range(3))
                torch._foreach_add_(steps, 1)
                torch._fused_adam_(ps, [p.grad for p in ps], avgs, sqs, [], steps, amsgrad=False, lr=self.rate(g),
                                   beta1=BETAS[0], beta2=BETAS[1], weight_decay=0.0, eps=EPS, maximize=False,
                                   grad_scale=None, found_inf=None)
        self.t += 1
