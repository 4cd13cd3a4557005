"""One entry that fits a material: `fit` chooses the neural, layout or rate-controlled fit once."""
from bcfpipe.fit.entry import FitMode, Fitted, fit, fit_mode, prepare

__all__ = ["FitMode", "Fitted", "fit", "fit_mode", "prepare"]
