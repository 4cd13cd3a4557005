"""The layout rule of issue 31: which channel groups stay classic BC textures, and at which
profile the neural features carry the rest, chosen by rate and per-mip distortion against BC@R.

BC@R is the classic set a user would ship at the material's resolution R (`bcfpipe.layout.classic`).
Every candidate is a set of classic groups plus, for the other channels, a neural model at a
profile; or BC@R with some groups repacked as BC7 in the same bytes (measured exactly); or a mip
split: each of a kind (`bcfpipe.layout.kinds`), which labels, trains and exports it. Its per-mip
MSE is the mean over channels of each channel's own MSE (the metric is a plain mean over channels,
`bcfpipe.texset.metrics`), so a candidate's figures follow from per-channel errors without
decoding it:

* classic channels, ``estimated``: from a sample of their blocks (`bcfpipe.layout.estimate`),
  ``measured`` once encoded in full (what ships always is);
* neural channels, ``predicted``: from the probe, a short training on *all* channels at one
  profile, moved per mip by what a full training at the preset asked gains over it
  (`bcfpipe.train.gains.PROBE_GAINS_DB`), and for the other profiles and T_0 widths by the
  measured gains between them (`GAINS_DB`, `T0_LAYER_GAINS_DB`), held to the oracle at the mips
  finer than their T_0 (`bcfpipe.layout.oracle`). A model trained on fewer channels fits those at
  least as well in expectation;
* ``measured`` once trained: the first choice alone is, when it has a neural part.

Default objective: the highest all-mip PSNR with the size at most BC@R's and no reference mip
more than `SLACK_DB` below BC@R at that mip (mips whose smaller side is at least 4 texels, the ones
the all-mip PSNR averages). ``match_bc``: the smallest layout whose every such mip reaches BC@R.
The all-classic layout (BC@R itself) always qualifies, so the result is never worse than it.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal, Protocol, Sequence, SupportsInt

import numpy as np

from bcfpipe.texset.metrics import psnr_from_mse


SLACK_DB = 0.5
Basis = Literal["measured", "estimated", "predicted"]
ALL_CLASSIC = "all classic (BC@R)"


class CandidateKind(Protocol):
    """What a candidate's kind is to the rule: a name, a label and its own keys in layout.json
    (`bcfpipe.layout.kinds.Kind`, which also trains and exports it, is one)."""

    name: str

    def label(self, c: "Candidate") -> str: ...

    def json(self, c: "Candidate") -> dict: ...


@dataclass(frozen=True)
class Candidate:
    """One layout: the classic groups (by name), the neural profile (None: no neural part), and
    its ``kind``, which labels, trains and exports it, with what only that kind has (``part``)."""

    classic: tuple[str, ...]
    profile: str | None
    size_bytes: int
    mse_per_mip: tuple[float, ...]
    basis: Basis
    use: tuple[int, ...] = field(repr=False, default=())  # the mips the all-mip PSNR averages
    part: Any = None  # its kind's own record (`bcfpipe.layout.kinds`: a repack's, a neural part's, a split's)
    # its files zstd-compressed (measured ones only); an int, or a sum read when to_json writes it (`classic.DiskBytes`)
    disk_bytes: SupportsInt | None = field(compare=False, default=None)
    kind: "CandidateKind | None" = field(repr=False, compare=False, default=None)  # what it is (`bcfpipe.layout.kinds`); not in to_json

    @property
    def label(self) -> str:
        return self.kind.label(self)

    @property
    def psnr_per_mip(self) -> tuple[float, ...]:
        return tuple(psnr_from_mse(m) for m in self.mse_per_mip)

    @property
    def psnr(self) -> float:
        use = self.use or tuple(range(len(self.mse_per_mip)))
        return psnr_from_mse(float(np.mean([self.mse_per_mip[k] for k in use])))

    def margins(self, bc: "Candidate") -> tuple[float, ...]:
        """Per-mip PSNR minus BC@R's, in dB."""
        return tuple(a - b for a, b in zip(self.psnr_per_mip, bc.psnr_per_mip))

    def to_json(self, bc: "Candidate | None" = None, quality: "Candidate | None" = None) -> dict:
        """Its figures; with ``bc`` (BC@R) and ``quality`` (the BC7 quality set) its per-mip margins
        against each."""
        d = {"layout": self.label, "classic": list(self.classic), "profile": self.profile,
             "size_bytes": self.size_bytes,
             "disk_bytes": None if self.disk_bytes is None else int(self.disk_bytes), "psnr": round(self.psnr, 3),
             "psnr_per_mip": [round(v, 3) for v in self.psnr_per_mip], "basis": self.basis,
             **(self.kind.json(self) if self.kind is not None else {"t0_layers": None})}
        if bc is not None:
            d["margin_per_mip_db"] = [round(v, 3) for v in self.margins(bc)]
            d["worst_margin_db"] = round(min(self.margins(bc)[k] for k in bc.use), 3) if bc.use else None
        if quality is not None:
            d["margin_vs_bc7_per_mip_db"] = [round(v, 3) for v in self.margins(quality)]
        return d


def combine(neural: np.ndarray | None, classic: np.ndarray, classic_channels: Sequence[int]) -> tuple[float, ...]:
    """Per-mip MSE of a layout from per-channel errors ((mips, channels) each): classic channels
    from ``classic``, the others from ``neural``."""
    err = classic.copy() if neural is None else neural.copy()
    cols = list(classic_channels)
    err[:, cols] = classic[:, cols]
    return tuple(float(v) for v in err.mean(axis=1))


def admissible(c: Candidate, bc: Candidate, match_bc: bool = False) -> str | None:
    """Why ``c`` may not be shipped (None when it may): the size, or the first mip below the floor."""
    if c.size_bytes > bc.size_bytes and not match_bc:
        return f"{c.size_bytes / 2**20:.2f} MiB > BC@R's {bc.size_bytes / 2**20:.2f} MiB"
    slack = 0.0 if match_bc else SLACK_DB
    for k in bc.use:
        if c.psnr_per_mip[k] < bc.psnr_per_mip[k] - slack - 1e-9:
            return (f"mip {k} at {c.psnr_per_mip[k]:.1f} dB, below BC@R's {bc.psnr_per_mip[k]:.1f}"
                    + (f" - {slack:g}" if slack else ""))
    return None


@dataclass(frozen=True)
class Decision:
    """The candidates weighed, the one chosen and why, against BC@R."""

    bc: Candidate
    candidates: tuple[Candidate, ...]
    chosen: Candidate
    reason: str
    objective: Literal["quality", "match-bc"]
    quality: Candidate | None = None  # the BC7 quality set, measured: reported against, never shipped

    def to_json(self) -> dict:
        q = self.quality
        return {"objective": self.objective, "chosen": self.chosen.to_json(self.bc, q), "reason": self.reason,
                "bc": self.bc.to_json(None, q), "bc7_quality": None if q is None else q.to_json(self.bc),
                "candidates": [dict(c.to_json(self.bc, q), rejected=admissible(c, self.bc, self.objective == "match-bc"))
                               for c in self.candidates]}


def deficit(c: Candidate, bc: Candidate, match_bc: bool = False) -> float:
    """How far ``c``'s worst mip falls short of its floor (BC@R - slack), in dB; <= 0 when none does."""
    slack = 0.0 if match_bc else SLACK_DB
    return max(bc.psnr_per_mip[k] - slack - c.psnr_per_mip[k] for k in bc.use)


def choose(candidates: Sequence[Candidate], bc: Candidate, match_bc: bool = False,
           quality: Candidate | None = None) -> Decision:
    """The best admissible candidate (BC@R itself among them, so there always is one); ``quality``,
    the BC7 quality set, goes with the decision to report against."""
    pool = [bc, *[c for c in candidates if c.label != bc.label]]
    ok = [c for c in pool if admissible(c, bc, match_bc) is None]
    if match_bc:
        best = min(ok, key=lambda c: (c.size_bytes, -c.psnr))
        why = (f"the smallest layout whose every mip reaches BC@R: {best.size_bytes / 2**20:.2f} MiB "
               f"against BC@R's {bc.size_bytes / 2**20:.2f} MiB")
    else:
        best = max(ok, key=lambda c: (c.psnr, -c.size_bytes))
        worst = min(best.margins(bc)[k] for k in bc.use)
        why = (f"highest all-mip PSNR ({best.psnr:.2f} dB, BC@R {bc.psnr:.2f}) within BC@R's size and "
               f"{SLACK_DB:g} dB of it at every mip (worst mip {worst:+.1f} dB)")
        if best is bc:
            why = "no other layout stays within BC@R's size and 0.5 dB of it at every mip; shipping BC@R"
    return Decision(bc, tuple(pool), best, why, "match-bc" if match_bc else "quality", quality)
