"""The decoder in every engine's shading language (issue 60): glsl/bcf_decode.comp, the one source,
compiled to Vulkan SPIR-V, and that SPIR-V translated to HLSL and MSL (`bcfpipe.targets.spirv`)."""
