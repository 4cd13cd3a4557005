"""BC6H (DXGI_FORMAT_BC6H_UF16 / BC6H_SF16) block compression: tables, decoder, encoder."""

from .decode import decode
from .encode import encode
