"""What a layout fit decided and trained (`bcfpipe.layout.decide.decide_layout`'s result), read by the
kinds that export it and by the material's measure; below them all, so that none imports the fit."""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Callable

from bcfpipe.export.material import MaterialResult
from bcfpipe.layout import choose as C
from bcfpipe.layout.classic import EncodedGroup, Repack


@dataclass
class LayoutFit:
    """What `decide_layout` decided and trained."""

    decision: C.Decision  # among measured layouts
    first: C.Decision  # among all candidates, some predicted: what was trained next
    classic: list[EncodedGroup]  # every group of BC@R
    neural: MaterialResult | None  # the chosen layout's model (None: all classic)
    neural_channels: tuple[int, ...]  # the texture set's channels it decodes
    probe: MaterialResult | None  # None when --classic fixed the layout
    train_seconds: float  # training of the probe and of the model trained, if any
    seconds: float  # everything: BC@R, trainings, exports and measuring
    repacked: dict[str, tuple[Repack, list[EncodedGroup]]] = field(default_factory=dict)  # by Repack.label
    encode_seconds: float = 0.0  # BC@R's and its repacks' estimates, encodes and measuring
    parts: Any = None  # what the chosen candidate's kind exports beside the model (`kinds.Weighed.parts`)
    costs: dict[str, float] = field(default_factory=dict)  # seconds by part: estimate, probe, train, classic_encode
    # the BC7 quality set the decisions report against, and its seconds, when estimated aside
    # (`decide._quality_aside`): `resolved` waits for it
    quality_later: Callable[[], tuple[C.Candidate, float]] | None = None
    # waits for a training the fit started and dropped (`bcfpipe.layout.speculate`) and removes its
    # files: the fit's folder is removed after it
    aside: Callable[[], None] | None = None

    def join_aside(self) -> None:
        """Wait for what the fit left running aside, if anything."""
        if self.aside is not None:
            self.aside()

    def resolved(self) -> "LayoutFit":
        """This fit with the BC7 quality set in its decisions (waited for when estimated aside)."""
        if self.quality_later is None:
            return self
        q, seconds = self.quality_later()
        decision = replace(self.decision, quality=q)
        first = decision if self.first is self.decision else replace(self.first, quality=q)
        costs = {**self.costs, "estimate_aside": round(seconds, 1)} if seconds else self.costs
        return replace(self, decision=decision, first=first, costs=costs, quality_later=None)
