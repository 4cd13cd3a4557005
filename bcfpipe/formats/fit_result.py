"""What one material's fit measured and chose, as one record: `bcfpipe train --json`'s object, a
build job's result (worker → executor → cache → assemble, events, report) and a cache entry's.

Its JSON is the stable contract (`bcfpipe train --json` keys); in Python it is read by attribute
only. ``layout`` is the material's layout.json decision, whole; `FitResult.choice` is the
manifest's summary of it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bcfpipe.formats.manifest import LayoutChoice, Quality, RateControl
from bcfpipe.formats.record import Record, optional

CLASSIC_ENCODE = "classic_encode"  # the phase of a layout fit's BC encodes (BC@R and its repacks)


@dataclass(frozen=True)
class FitResult(Record):
    """One material's fit: headline figures of the exported files, sizes, where and how it trained,
    the seconds of each phase, and under --layout auto or --target-psnr what was chosen."""

    psnr: float
    ssim: float | None
    flip: float | None
    size_bytes: int
    size_mib: float
    train_seconds: float
    profile: str
    resolutions: tuple[int, ...]
    preset: str
    device: str
    phase_seconds: dict[str, float]
    metrics: Quality
    phase_samples: dict[str, int] | None = None
    t0_layers: int = 1
    out: str | None = optional()  # the folder `bcfpipe train` wrote; absent in a build's job
    float_psnr: float | None = optional()
    quantization_loss_db: float | None = optional()
    layout: dict[str, Any] | None = optional()  # --layout auto: layout.json's decision
    target: RateControl | None = optional()  # --target-psnr: how rate control went

    _ORDER = ("psnr", "ssim", "flip", "size_bytes", "size_mib", "train_seconds", "out", "profile", "resolutions",
              "preset", "device", "phase_seconds", "phase_samples", "t0_layers", "metrics")

    @property
    def headline_psnr(self) -> float:
        """What a user reads: over the texels the scene reads where a coverage mask applied."""
        return self.metrics.psnr_covered if self.metrics.psnr_covered is not None else self.psnr

    @property
    def encode_seconds(self) -> float | None:
        """The BC encode time of a layout fit (BC@R and its repacks); None for a fit that encoded
        none (a training's own T_0 encode is part of its training)."""
        return self.phase_seconds.get(CLASSIC_ENCODE)

    @property
    def choice(self) -> LayoutChoice | None:
        """The manifest's summary of the layout decision; None without one."""
        d = self.layout
        if not d:
            return None
        ch, bc = d["chosen"], d["bc"]
        angle = d.get("normal_angular_error")
        return LayoutChoice(ch["layout"], tuple(ch["classic"]), ch["profile"], d["reason"], ch["size_bytes"],
                            bc["size_bytes"], ch["psnr"], bc["psnr"], tuple(ch["margin_per_mip_db"]),
                            ch.get("worst_margin_db"), (angle["mean_deg"], angle["p99_deg"]) if angle else None)
