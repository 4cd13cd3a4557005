"""A texture set's reference for one fit: its box mip chain and, with a coverage mask, the mask's
chain, built once and shared by everyone who measures or trains against it (issue 58).

An 8192² set of 8 channels has a 2.7 GiB chain (level 0 is the set's own data, not a copy: the
levels below it hold 0.67 GiB). Training, measuring BC@R, measuring the probe's and the chosen
model's exported files each used to build it again; a fit now builds one `Reference` and passes
it on. `bcfpipe.texset.reference.ReferencePyramid` is another thing: the trainer's torch copy, in
its learnt (encoded) domain, on its device.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bcfpipe.formats.vocabulary import Wrap, wrap_axes
from bcfpipe.scan.coverage import mask_mips
from bcfpipe.texset.texture_set import TextureSet, build_mip_chain

__all__ = ["Reference"]


@dataclass(frozen=True)
class Reference:
    """``mips``: `build_mip_chain` of a set's data ((H_k, W_k, c) float32, level 0 the data itself).
    ``masks``: `bcfpipe.scan.coverage.mask_mips` of its coverage (one (H_k, W_k) bool per mip, with
    the addressing ``wrap``), or None when every texel counts. Read-only: share, never modify."""

    mips: tuple[np.ndarray, ...]
    masks: tuple[np.ndarray, ...] | None = None
    wrap: object = Wrap.REPEAT  # the addressing the masks were dilated with (a mode or an (S, T) pair)
    coverage: np.ndarray | None = None  # the level-0 mask the masks were made from (training draws there)

    def __post_init__(self) -> None:
        object.__setattr__(self, "mips", tuple(self.mips))
        if self.masks is not None:
            object.__setattr__(self, "masks", tuple(self.masks))
            if len(self.masks) != len(self.mips):
                raise ValueError(f"{len(self.masks)} coverage masks for {len(self.mips)} mips")

    @classmethod
    def of(cls, ts: TextureSet, coverage: np.ndarray | None = None, wrap=Wrap.REPEAT) -> "Reference":
        """``ts``'s chain, and ``coverage``'s (a (H, W) bool mask of the texels the scene reads)."""
        mips = build_mip_chain(ts.data)
        masks = None
        if coverage is not None:
            masks = mask_mips(coverage, len(mips), wrap)
        return cls(tuple(mips), None if masks is None else tuple(masks), wrap, coverage)

    @property
    def shapes(self) -> list[tuple[int, int]]:
        """(H_k, W_k) per mip."""
        return [m.shape[:2] for m in self.mips]

    def check(self, ts: TextureSet, coverage: np.ndarray | None, wrap) -> None:
        """Raise ValueError unless this is a reference of ``ts``'s shape with masks exactly when
        there is a ``coverage`` (dilated with ``wrap``): a reference passed in for another set (a
        subset of its channels, another size) or another coverage would measure the wrong thing."""
        if self.mips[0].shape != ts.data.shape:
            raise ValueError(f"the reference is of a {self.mips[0].shape} set, not of this {ts.data.shape} one")
        if (coverage is None) != (self.masks is None):
            raise ValueError("the reference's coverage masks do not match the coverage given"
                             f" ({'none' if coverage is None else 'a mask'} given, "
                             f"{'none' if self.masks is None else 'masks'} held)")
        if coverage is not None and (self.masks[0].shape != coverage.shape or wrap_axes(self.wrap) != wrap_axes(wrap)):
            raise ValueError(f"the reference's masks are of a {self.masks[0].shape} mask with addressing "
                             f"{self.wrap!r}, not of this {coverage.shape} one with {wrap!r}")
