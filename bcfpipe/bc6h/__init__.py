"""BC6H (DXGI_FORMAT_BC6H_UF16 / BC6H_SF16) block compression: tables, decoder, and the encoder
(`bcfpipe.bc6h.encode`, in torch: imported where it encodes, so reading a DDS needs no torch)."""

from .decode import decode
