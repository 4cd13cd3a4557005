"""bcfpipe: neural materials with block-compressed features (BC7 by default, or BC6H) for USD scenes."""
import os as _os

__version__ = "0.1.0"

# torch's OpenMP workers spin while waiting; on a machine whose cores are busy (parallel builds,
# CI) that made training steps 10-50x slower in our measurements (docs/benchmarks.md). Passive
# waiting costs nothing measurable when the machine is idle. Set before torch is imported; an
# explicit user setting wins.
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

