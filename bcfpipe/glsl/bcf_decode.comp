#version 450 core
// Batch decode: one invocation per sample, output = the decoded channels as float32.
// The host inserts bcf_decode.glsl right after the #version line (glsl/README.md).
//
// Bindings: texture units 0..N-1 = T0..T{N-1}, N = BCF_N_LAYERS (as in bcf_fullscreen.frag);
//   shader storage block 0 = weight buffer (uint words), 1 = queries (below),
//   2 = output float[count * uOutStride], sample i's channel c at i * uOutStride + c.
// Uniforms:
//   uint  uWeightOffset, float uLodBias[N], vec2 uRefSize, int uNormalIndex, ivec2 uWrap
//                      as in bcf_fullscreen.frag
//   uint  uCount       number of samples
//   bool  uGradQueries false: query i is vec4(u, v, s, unused) (bcfDecodeLod);
//                      true: queries 2i, 2i+1 are vec4(u, v, du/dx, dv/dx), vec4(du/dy, dv/dy, -, -)
//                      and s comes from the derivatives (bcfDecodeGrad)
//   uint  uOutStride   floats per sample in the output (>= channel count; extra slots untouched)
//   uvec2 uGrid        (0, 0): read the queries; (W, H): sample i is the texel centre
//                      ((i % W + 0.5) / W, (i / W + 0.5) / H) of a W x H grid at s = uGridLod
//   float uGridLod
// An invalid weight record writes NaN to every slot. Dispatch ceil(uCount / 64) groups.

layout(local_size_x = 64) in;

layout(binding = 0) uniform sampler2D bcfT[BCF_N_LAYERS];  // units 0..BCF_N_LAYERS - 1

layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
layout(std430, binding = 1) readonly buffer BcfQueries { vec4 bcfQueries[]; };
layout(std430, binding = 2) writeonly buffer BcfOutput { float bcfOut[]; };
uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

uniform uint uWeightOffset;
uniform float uLodBias[BCF_N_LAYERS];
uniform vec2 uRefSize;
uniform int uNormalIndex;
uniform ivec2 uWrap;
uniform uint uCount;
uniform bool uGradQueries;
uniform uint uOutStride;
uniform uvec2 uGrid;
uniform float uGridLod;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uCount) return;
    BcfMaterial m = BcfMaterial(uWeightOffset, uLodBias, uRefSize, uNormalIndex, uWrap);
    float ch[BCF_MAX_OUT];
    int n;
    if (uGrid.x > 0u) {
        vec2 uv = (vec2(float(i % uGrid.x), float(i / uGrid.x)) + 0.5) / vec2(uGrid);
        n = bcfDecodeLod(bcfT, m, uv, uGridLod, ch);
    } else if (uGradQueries) {
        vec4 a = bcfQueries[2u * i], b = bcfQueries[2u * i + 1u];
        n = bcfDecodeGrad(bcfT, m, a.xy, a.zw, b.xy, ch);
    } else {
        vec4 q = bcfQueries[i];
        n = bcfDecodeLod(bcfT, m, q.xy, q.z, ch);
    }
    uint o = i * uOutStride;
    if (n == 0) {
        for (uint c = 0u; c < uOutStride; ++c) bcfOut[o + c] = uintBitsToFloat(0x7FC00000u);
        return;
    }
    for (int c = 0; c < n && uint(c) < uOutStride; ++c) bcfOut[o + uint(c)] = ch[c];
}
