"""A small reference renderer for built stages (``bcfpipe render``, docs/render.md).

It reads only the USD stage and the files it names: meshes and the camera (:mod:`.scene`), each
material's surface, neural from the ``bcf`` render context or the original UsdPreviewSurface
(:mod:`.surfaces`); it draws them with OpenGL through glsl/bcf_render.* and the shipped decoder
glsl/bcf_decode.glsl (:mod:`.raster`), and turns frames into pictures and numbers
(:mod:`.compare`). :mod:`.frames` ties them together. A reference and a test tool, not a
production renderer.
"""
