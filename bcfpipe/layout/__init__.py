"""Layouts (``--layout auto``, issue 31): which of a material's outputs the neural features carry
and which stay classic BC textures, chosen by measured rate and per-mip distortion against the BC
set a user would ship (docs/layout.md)."""
