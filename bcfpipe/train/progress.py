"""What a long run reports as it goes (`Progress`) and who hears it (`ProgressFn`): apart from the
trainer, so that the classic path (estimates, encodes, the final measure) reports without
importing torch."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class Progress:
    """A progress report; ``eta`` is the estimated seconds left for the whole run."""

    phase: str
    step: int
    steps: int
    loss: float
    psnr: float
    elapsed: float
    eta: float


ProgressFn = Callable[[Progress], None]
