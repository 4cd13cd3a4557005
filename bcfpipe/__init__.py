"""bcfpipe: neural materials with block-compressed (BC6H) features for USD scenes."""

__version__ = "0.1.0"
