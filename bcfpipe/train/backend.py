"""How one training run's steps run: torch's autograd, or the fused kernel (bcfpipe.train.fused).

`make_backend` picks one where the run starts, from ``TrainConfig.kernel`` on the run's device, and
the trainer hands it to the phases. They call its methods (a phase's step, a batch's targets, the
compiled library the first encode and the centre targets use) and never ask which kernel runs.
"""
from __future__ import annotations

from typing import Callable, Protocol

import torch

from bcfpipe.config import TrainConfig
from bcfpipe.formats.vocabulary import Kernel
from bcfpipe.model import neural as M
from bcfpipe.model.features import BlockParams, Layers
from bcfpipe.texset.reference import CentreTargets, ReferencePyramid, sample_reference
from bcfpipe.train.fused import native
from bcfpipe.train.fused import targets
from bcfpipe.train.fused.step import default_backend
from bcfpipe.train.fused.step import FusedStep

__all__ = ["Step", "StepBackend", "TorchStep", "TorchBackend", "FusedBackend", "make_backend"]


class Step(Protocol):
    """One training step: ``step(uv, target, weight, s)`` returns the loss (the MSE, weighted by
    ``weight`` where it is not None) and sets ``.grad`` on the parameters the step touched. Where
    ``owns_adam``, the step keeps the features' gradients itself and ``adam(lr)`` updates them
    after the optimizer's step (which then holds the MLP alone)."""

    owns_adam: bool

    def __call__(self, uv: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None, s: float) -> float: ...

    def adam(self, lr: float) -> None: ...


class TorchStep:
    """A step through torch's autograd: ``predict(uv, s)``, the loss against the targets, backward."""

    owns_adam = False

    def __init__(self, predict: Callable[[torch.Tensor, float], torch.Tensor]):
        self.predict = predict

    def __call__(self, uv: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None, s: float) -> float:
        pred = self.predict(uv, s)
        if weight is None:
            loss = torch.mean((pred - target) ** 2)
        else:
            loss = torch.mean(weight[:, None] * (pred - target) ** 2) / weight.mean().clamp_min(1e-6)
        loss.backward()
        return float(loss.detach())


class StepBackend(Protocol):
    """What the phases ask of the kernel that runs their steps."""

    kernel: Kernel

    def library(self):
        """The fused kernel's compiled library where it runs natively (its encoders and lookups), else None."""

    def bicubic(self):
        """The lookup that precomputes the centre targets (`CentreTargets`' ``bicubic``), or None: torch's."""

    def free_step(self, free: Layers[torch.Tensor]) -> Step:
        """Phase 1's step over free features (the fused one moves them into its storage: take the
        optimizer's parameters after this)."""

    def block_step(self, blocks: Layers[BlockParams], quantized: Callable[[], bool]) -> Step:
        """Phase 2's step over block parameters, quantization-aware where ``quantized()`` says."""

    def cached_step(self, levels: list[list[torch.Tensor]]) -> Step:
        """The fine-tune's step: the MLP alone, on decoded levels."""

    def centre_batch(self, centres: CentreTargets, batch: int, s: float,
                     gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """uv and targets of a batch at texel centres."""

    def sample_reference(self, ref: ReferencePyramid, uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
        """The reference's bicubic lookup at ``uv``, lod ``s``."""


class TorchBackend:
    """Every step through torch's autograd, on the run's device."""

    kernel = Kernel.TORCH

    def __init__(self, cfg: TrainConfig, device: torch.device, mlp: dict[str, torch.Tensor], biases: tuple[float, ...]):
        self.cfg, self.device, self.mlp, self.biases = cfg, device, mlp, biases

    def library(self):
        return None

    def bicubic(self):
        return None

    def _step(self, level_fn: M.LevelFn, tap_fn: M.TapFn | None) -> TorchStep:
        mc, mlp, biases = self.cfg.model, self.mlp, self.biases
        taps = tap_fn if self.cfg.tap_decode else None
        return TorchStep(lambda uv, s: M.forward(level_fn, mlp, mc, biases, uv, s, taps))

    def free_step(self, free: Layers[torch.Tensor]) -> Step:
        mc = self.cfg.model
        return self._step(M.free_level_fn(free, mc), M.free_tap_fn(free, mc))

    def block_step(self, blocks: Layers[BlockParams], quantized: Callable[[], bool]) -> Step:
        mc = self.cfg.model
        return self._step(M.block_level_fn(blocks, mc, quantized), M.block_tap_fn(blocks, mc, quantized))

    def cached_step(self, levels: list[list[torch.Tensor]]) -> Step:
        return self._step(M.cached_level_fn(levels), None)

    def centre_batch(self, centres: CentreTargets, batch: int, s: float,
                     gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        uv, target = centres.batch(batch, s, gen)
        return uv.to(self.device), target

    def sample_reference(self, ref: ReferencePyramid, uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
        return sample_reference(ref, uv, s, wrap)


class FusedBackend(TorchBackend):
    """The features' phases through the fused kernel (native where a C++ compiler builds it, else
    numba), with its Adam; the fine-tune, the MLP alone on decoded levels, stays torch's."""

    kernel = Kernel.FUSED

    def library(self):
        if default_backend() != "native":
            return None

        return native.load()

    def bicubic(self):
        """The native lookup (targets.cpp; 3.4 s of torch at a 2048² source become 0.3), where the
        kernel is native."""
        if self.library() is None:
            return None

        return targets.bicubic

    def _fused(self, levels: Layers, quantized: Callable[[], bool]) -> Step:
        return FusedStep(self.cfg.model, self.biases, self.mlp, levels, quantized, chunks=self.cfg.threads or 1,
                         own_adam=True)

    def free_step(self, free: Layers[torch.Tensor]) -> Step:
        return self._fused(free, lambda: False)

    def block_step(self, blocks: Layers[BlockParams], quantized: Callable[[], bool]) -> Step:
        return self._fused(blocks, quantized)

    def centre_batch(self, centres: CentreTargets, batch: int, s: float,
                     gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        return targets.centre_batch(centres, batch, s, gen)

    def sample_reference(self, ref: ReferencePyramid, uv: torch.Tensor, s: float, wrap: str) -> torch.Tensor:
        return targets.sample_reference(ref, uv, s, wrap)


def make_backend(cfg: TrainConfig, device: torch.device, mlp: dict[str, torch.Tensor],
                 biases: tuple[float, ...]) -> StepBackend:
    """The backend ``cfg.kernel`` picks on ``device``: the one place a run asks which kernel it uses.
    ``mlp`` and ``biases`` are the run's decoder and lod biases, which every step reads."""
    if cfg.kernel.on(device) == Kernel.FUSED:
        return FusedBackend(cfg, device, mlp, biases)
    return TorchBackend(cfg, device, mlp, biases)
