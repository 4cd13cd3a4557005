"""BC7 (BPTC UNORM) feature textures in mode 6: block layout, spec decoder, encoder, trainable emulation; mode 7
and the per-block choice of the two, measured for issue 29 and read by the decoder."""
from .decode import decode, decode_to_u8  # noqa: F401
from .encode import encode  # noqa: F401
