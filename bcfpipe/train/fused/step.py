"""The trainer's side of the fused kernel: one call per step computes the loss and sets ``.grad``
on the parameters the step touched (the two levels of each layer it samples, and the MLP), exactly
where torch's autograd would set them. With ``own_adam`` (native) the feature levels' gradients
stay in the step's buffers and :meth:`FusedStep.adam` updates them; the MLP keeps torch's Adam."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from bcfpipe.bc6h import mode10
from bcfpipe.bc6h.tables import WEIGHTS3
from bcfpipe.config import ModelConfig
from bcfpipe.formats.vocabulary import FeatureFormat
from bcfpipe.model.features import BlockParams, Layers, codec_of
from bcfpipe.model.sampling import level_weights
from bcfpipe.pooltrace import trace_pool
from bcfpipe.texset import hostmem
from bcfpipe.train.fused import common
from bcfpipe.train.fused import native
from bcfpipe.train.fused.common import FIXED, TRAINED, wrap_code
from bcfpipe.train.fused.common import say_once


def default_backend() -> str:
    """``native`` (step.cpp, vectorised) where a C++ compiler builds it, else ``numba`` (kernel.py),
    with one line on stderr saying why (once per build: `common.say_once`). Without it the first
    encode runs in torch too (bcfpipe.model.features)."""
    global _BACKEND
    if _BACKEND is None:
        try:
            native.load()
            _BACKEND = "native"
        except native.NativeUnavailable as e:
            say_once(f"bcfpipe: {e}; the fused kernel runs in numba and the first encode in torch (slower)")
            _BACKEND = "numba"
    return _BACKEND


_BACKEND: str | None = None
MAX_LAYERS = 8  # step.cpp's: the layers (two slots each) one step samples


def _tables(signed: bool):
    """The BC6H decode's tables as bcfpipe.bc6h.emulate builds them: every 6-bit endpoint's
    unquantized value and the slope to the next, and the 3-bit weights and theirs."""
    u = mode10.unquantize_table(signed)[1].astype(np.float32)
    w3 = WEIGHTS3.astype(np.float32)
    return u, np.append(np.diff(u), 0).astype(np.float32), w3, np.append(np.diff(w3), 0).astype(np.float32)


class FusedStep:
    """Loss and gradients of one step at scale ``s`` through the native kernel (native.py) or the
    numba one (kernel.py), ``backend`` (default: :func:`default_backend`).

    ``levels.trained[i][k]`` are layer i's mip-k parameters: free (C, H, W) tensors (phase 1) or
    `BlockParams` (phase 2); ``levels.fixed`` (a T_0 of principal components) are sampled from their
    values, without a gradient. The trained ones are moved, in place in their layers' lists, into
    one flat storage (the kernel then addresses every level by offset), so build the optimizer after
    this. ``quantized()`` is asked per step, as the torch path does. ``chunks``: sample ranges run
    in parallel, each with its own gradient buffers (the result depends on the count, not on the
    scheduling). ``own_adam`` (native only; see ``owns_adam``): :meth:`adam` updates the feature
    parameters, their gradients stay in the step's buffers, and the trainer's optimizer holds the
    MLP alone."""

    def __init__(self, mc: ModelConfig, biases: Sequence[float], mlp: dict[str, torch.Tensor], levels: Layers,
                 quantized: Callable[[], bool] = lambda: False, chunks: int = 1, backend: str | None = None,
                 own_adam: bool = False):
        if levels.fixed and FeatureFormat(mc.features) != FeatureFormat.BC7:
            raise ValueError("fixed levels are BC7 UNORM8 values; the format is " + str(mc.features))
        if mc.n_layers > MAX_LAYERS:
            raise ValueError(f"the fused kernel takes at most {MAX_LAYERS} layers; the model has {mc.n_layers}")
        self.backend = backend or default_backend()
        self.mc, self.biases, self.mlp, self.levels = mc, biases, mlp, levels
        self.quantized, self.chunks = quantized, max(1, int(chunks))
        codec = codec_of(mc)
        blocks = any(isinstance(lv, BlockParams) for lv in levels.trained_levels())  # phase 2's, else phase 1's
        bc7 = FeatureFormat(mc.features) == FeatureFormat.BC7
        self.fmt = ((common.BLOCK_BC7 if bc7 else common.BLOCK_BC6H) if blocks
                    else (common.FREE_BC7 if bc7 else common.FREE_BC6H))
        self.C = codec.channels
        self.plo, self.phi = (np.float32(v) for v in codec.param_range(mc))
        self.tables = _tables(bool(mc.signed))
        self._rehome(blocks)
        self.blocks = blocks
        self._touched: list[tuple[int, int]] = []
        self.owns_adam = own_adam and self.backend == "native"
        if self.owns_adam:  # Adam's moments for every level's parameters, and each level's update count
            self.mP, self.vP = np.zeros_like(self.P), np.zeros_like(self.P)
            self.mX, self.vX = np.zeros_like(self.X), np.zeros_like(self.X)
            self.updates = {(i, k): 0 for i, row in enumerate(self.slot) for k in range(len(row))}
        if self.backend == "native":
            self.K, self.M = native, native.block_masks(self.M)
        else:
            import numba  # lazy: start-up

            from bcfpipe.train.fused import kernel as K  # lazy: start-up

            self.K = K
            numba.set_num_threads(min(self.chunks, numba.config.NUMBA_NUM_THREADS))

            trace_pool("numba", numba.get_num_threads())

    def adam(self, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        """Adam (torch's update, per-level step counts as torch keeps per tensor) on the levels the
        last step touched, then the clamp that the trainer's projection applies (parameters to the
        codec's range, block indices to [0, 1]), and their gradients zeroed for the next step."""
        for i, k in self._touched:
            po, np_, xo, nx, _, _ = self.slot[i][k]
            self.updates[(i, k)] += 1
            t = self.updates[(i, k)]
            self.K.adam(self.P[po:po + np_], self.gP[:, po:po + np_], self.mP[po:po + np_], self.vP[po:po + np_],
                        lr, betas, eps, t, float(self.plo), float(self.phi))
            if self.blocks:
                self.K.adam(self.X[xo:xo + nx], self.gX[:, xo:xo + nx], self.mX[xo:xo + nx], self.vX[xo:xo + nx],
                            lr, betas, eps, t, 0.0, 1.0)

    def _rehome(self, blocks: bool) -> None:
        """One flat float32 storage for the levels' parameters (P) and indices (X), one uint8 for the
        BC6H subset masks (M); ``self.slot[i][k]`` = (po, np, xo, nx, mo, plane)."""
        levels = self.levels
        self.fixed = {(i, k) for i, mips in levels.fixed.items() for k in range(len(mips))}
        params = levels.each(lambda lv: lv.values, (lambda b, i, k: b.endpoints) if blocks else (lambda p, i, k: p))
        n_p = sum(p.numel() for layer in params for p in layer)
        n_x = sum(b.x.numel() for b in levels.trained_levels()) if blocks else 0
        P, X = hostmem.empty((n_p,), torch.float32), hostmem.empty((max(n_x, 1),), torch.float32)
        M = np.zeros(max(n_x, 1), np.uint8)
        po = xo = 0
        self.slot = []
        for i, layer in enumerate(params):
            row = []
            for k, p in enumerate(layer):
                view = P[po:po + p.numel()].view(p.shape)
                view.copy_(p.detach())
                fixed = (i, k) in self.fixed
                plane = p.shape[1] * p.shape[2] if fixed or not blocks else 0
                if fixed:
                    row.append((po, p.numel(), 0, 0, 0, plane))
                elif blocks:
                    b = levels.trained[i][k]
                    xv = X[xo:xo + b.x.numel()].view(b.x.shape)
                    xv.copy_(b.x.detach())
                    if b.mask is not None:
                        M[xo:xo + b.x.numel()] = b.mask.cpu().numpy().reshape(-1)
                    b.endpoints, b.x = view.requires_grad_(True), xv.requires_grad_(True)
                    row.append((po, p.numel(), xo, b.x.numel(), xo, plane))
                    xo += b.x.numel()
                else:
                    levels.trained[i][k] = view.requires_grad_(True)
                    row.append((po, p.numel(), 0, 0, 0, plane))
                po += p.numel()
            self.slot.append(row)
        self.P, self.X, self.M = P.numpy(), X.numpy(), M
        self.gP = np.zeros((self.chunks, n_p), np.float32)
        self.gX = np.zeros((self.chunks, max(n_x, 1)), np.float32)

    def _slots(self, s: float):
        """(slots (2 L, 6), blend (L,), touched (layer, mip) pairs) at scale s, for the model's L
        layers: slot 2 i is layer i's lower level, 2 i + 1 its upper one (inactive when the blend
        does not reach it); a slot is (active, size, po, xo, mo, plane)."""
        mc = self.mc
        slots = np.zeros((2 * mc.n_layers, 6), np.int64)
        blend = np.zeros(mc.n_layers, np.float32)
        touched = []
        for i, (count, b) in enumerate(zip(mc.mip_counts, self.biases)):
            lo, hi, t = level_weights(s + b, count)
            use_hi = hi != lo and t > 0
            blend[i] = t if use_hi else 0.0
            for j, (k, on) in enumerate(((lo, True), (hi, use_hi))):
                if on:
                    po, _, xo, _, mo, plane = self.slot[i][k]
                    fixed = (i, k) in self.fixed
                    slots[2 * i + j] = (FIXED if fixed else TRAINED, max(4, mc.layer_resolutions[i] >> k), po, xo, mo, plane)
                    if not fixed:
                        touched.append((i, k))
        return slots, blend, touched

    def features(self, uv: torch.Tensor, s: float) -> torch.Tensor:
        """The (N, L C) features the step feeds the MLP (tests compare them with the torch path's)."""
        slots, blend, _ = self._slots(s)
        mc = self.mc
        return torch.from_numpy(self.K.features(self.fmt, bool(self.quantized()), bool(mc.signed),
                                                wrap_code(mc.wrap), uv.detach().numpy(), self.P, self.X, self.M,
                                                slots, blend, self.C, self.plo, self.phi, *self.tables))

    def __call__(self, uv: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None, s: float) -> float:
        """The step's loss (the torch path's ``loss``); sets ``.grad`` as its ``backward`` would."""
        mc, n = self.mc, self.chunks
        slots, blend, touched = self._slots(s)
        self._touched = touched
        if not self.owns_adam:
            for i, k in touched:
                po, np_, xo, nx, _, _ = self.slot[i][k]
                self.gP[:, po:po + np_] = 0.0
                self.gX[:, xo:xo + nx] = 0.0
        w1, b1, w2, b2 = (self.mlp[k].detach().numpy() for k in ("w1", "b1", "w2", "b2"))
        gw1, gb1 = np.zeros((n,) + w1.shape, np.float32), np.zeros((n,) + b1.shape, np.float32)
        gw2, gb2 = np.zeros((n,) + w2.shape, np.float32), np.zeros((n,) + b2.shape, np.float32)
        N, C_out = target.shape
        wnp = weight.detach().numpy().astype(np.float32) if weight is not None else np.zeros(0, np.float32)
        wmean = max(float(weight.mean()), 1e-6) if weight is not None else 1.0
        loss_scale = 1.0 / (N * C_out * wmean)
        sse = self.K.step(self.fmt, bool(self.quantized()), bool(mc.signed), wrap_code(mc.wrap), n,
                          uv.detach().numpy(), target.detach().numpy(), wnp, self.P, self.X, self.M, slots, blend,
                          self.C, self.plo, self.phi, *self.tables, w1, b1, w2, b2,
                          self.mlp["out_scale"].numpy(), self.mlp["out_bias"].numpy(), loss_scale,
                          self.gP, self.gX, gw1, gb1, gw2, gb2)
        for i, k in touched if not self.owns_adam else ():
            po, np_, xo, nx, _, _ = self.slot[i][k]
            for q in range(1, n):  # chunk order: deterministic for a given count
                self.gP[0, po:po + np_] += self.gP[q, po:po + np_]
                self.gX[0, xo:xo + nx] += self.gX[q, xo:xo + nx]
            lvl = self.levels.trained[i][k]
            if self.blocks:
                lvl.endpoints.grad = torch.from_numpy(self.gP[0, po:po + np_]).view(lvl.endpoints.shape)
                lvl.x.grad = torch.from_numpy(self.gX[0, xo:xo + nx]).view(lvl.x.shape)
            else:
                lvl.grad = torch.from_numpy(self.gP[0, po:po + np_]).view(lvl.shape)
        for name, g in (("w1", gw1), ("b1", gb1), ("w2", gw2), ("b2", gb2)):
            self.mlp[name].grad = torch.from_numpy(g.sum(0))
        return float(sse.sum()) * loss_scale
