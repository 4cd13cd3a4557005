"""BC7 (BPTC UNORM) feature textures: trained layers in mode 6 (block layout, encoder, trainable emulation), a
fixed T_0 in any mode (ISPC encodes it); the spec decoder reads every mode. Mode 7 and the per-block choice of 6
and 7 were measured for issue 29 and live in benchmarks/bc7_mode7/."""
from .decode import decode, decode_to_u8  # noqa: F401
from .encode import encode  # noqa: F401
