#version 450 core
// The source of bcf_decode.hlsli, the HLSL include (bcfpipe shaders; docs/format.md#other-apis).
// glslang compiles this entry with the library; SPIRV-Cross translates it to HLSL, and everything
// but the library's functions (this entry, its resources, bcfWeightWord) is dropped: the include
// is bcf_decode.glsl's functions, called from here so that the compiler keeps each one.

layout(local_size_x = 1) in;
layout(std430, set = 0, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
layout(std430, set = 0, binding = 2) writeonly buffer BcfOutput { float bcfOut[]; };
layout(set = 0, binding = 4) uniform sampler2D bcfT[BCF_N_LAYERS];

uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

void main() {
    BcfMaterial m;
    m.weightOffset = 0u;
    for (int i = 0; i < BCF_N_LAYERS; ++i) m.lodBias[i] = 0.0;
    m.refSize = vec2(1.0);
    m.normalIndex = -1;
    m.wrap = ivec2(0);
    float ch[BCF_MAX_OUT];
    int n = bcfDecodeGrad(bcfT, m, vec2(0.5), vec2(0.1), vec2(0.1), ch);
    bcfOut[0] = ch[0] + float(n);
}
