#version 450 core
// Batch decode: one invocation per sample, output = the decoded channels as float32.
// The host inserts bcf_decode.glsl right after the #version line (glsl/README.md).
//
// Bindings: texture units 0..3 = T0..T3 (as in bcf_fullscreen.frag);
//   shader storage block 0 = weight buffer (uint words), 1 = queries vec4(u, v, s, unused),
//   2 = output float[count * uOutStride], sample i's channel c at i * uOutStride + c.
// Uniforms:
//   uint  uWeightOffset, vec4 uLodBias, int uNormalIndex   as in bcf_fullscreen.frag
//   uint  uCount       number of samples
//   uint  uOutStride   floats per sample in the output (>= channel count; extra slots untouched)
//   uvec2 uGrid        (0, 0): read the queries; (W, H): sample i is the texel centre
//                      ((i % W + 0.5) / W, (i / W + 0.5) / H) of a W x H grid at s = uGridLod
//   float uGridLod
// An invalid weight record writes NaN to every slot. Dispatch ceil(uCount / 64) groups.

layout(local_size_x = 64) in;

layout(binding = 0) uniform sampler2D bcfT0;
layout(binding = 1) uniform sampler2D bcfT1;
layout(binding = 2) uniform sampler2D bcfT2;
layout(binding = 3) uniform sampler2D bcfT3;

layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
layout(std430, binding = 1) readonly buffer BcfQueries { vec4 bcfQueries[]; };
layout(std430, binding = 2) writeonly buffer BcfOutput { float bcfOut[]; };
uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

uniform uint uWeightOffset;
uniform vec4 uLodBias;
uniform int uNormalIndex;
uniform uint uCount;
uniform uint uOutStride;
uniform uvec2 uGrid;
uniform float uGridLod;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uCount) return;
    vec2 uv;
    float s;
    if (uGrid.x > 0u) {
        uv = (vec2(float(i % uGrid.x), float(i / uGrid.x)) + 0.5) / vec2(uGrid);
        s = uGridLod;
    } else {
        vec4 q = bcfQueries[i];
        uv = q.xy;
        s = q.z;
    }
    BcfMaterial m = BcfMaterial(uWeightOffset, uLodBias, vec2(0.0), uNormalIndex);
    float ch[BCF_MAX_OUT];
    int n = bcfDecodeLod(bcfT0, bcfT1, bcfT2, bcfT3, m, uv, s, ch);
    uint o = i * uOutStride;
    if (n == 0) {
        for (uint c = 0u; c < uOutStride; ++c) bcfOut[o + c] = uintBitsToFloat(0x7FC00000u);
        return;
    }
    for (int c = 0; c < n && uint(c) < uOutStride; ++c) bcfOut[o + uint(c)] = ch[c];
}
