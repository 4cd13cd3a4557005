#version 450 core
// Batch decode: one invocation per sample, output = the decoded channels as float32.
// The host inserts bcf_decode.glsl right after the #version line (glsl/README.md).
//
// OpenGL (no VULKAN defined): texture units 0..N-1 = T0..T{N-1}, N = BCF_N_LAYERS (as in
//   bcf_fullscreen.frag); shader storage block 0 = weight buffer (uint words), 1 = queries (below),
//   2 = output float[count * uOutStride], sample i's channel c at i * uOutStride + c; the
//   parameters below as uniforms.
// Vulkan (glslang -V defines VULKAN), and D3D / Metal through its SPIR-V (bcfpipe shaders): set 0,
//   binding 0 = weights, 1 = queries, 2 = output, 3 = the parameters as one std430 storage block
//   in the order declared below (48 bytes, then uLodBias), 4 = the N combined image samplers
//   (last, so that D3D registers t4..t(3+N) overlap no buffer's).
// Parameters:
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

#ifdef VULKAN
layout(std430, set = 0, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
layout(std430, set = 0, binding = 1) readonly buffer BcfQueries { vec4 bcfQueries[]; };
layout(std430, set = 0, binding = 2) writeonly buffer BcfOutput { float bcfOut[]; };
layout(set = 0, binding = 4) uniform sampler2D bcfT[BCF_N_LAYERS];
layout(std430, set = 0, binding = 3) readonly buffer BcfParams {
    uint uWeightOffset;     // byte 0
    int uNormalIndex;       // 4
    uint uCount;            // 8
    uint uOutStride;        // 12
    ivec2 uWrap;            // 16
    vec2 uRefSize;          // 24
    uvec2 uGrid;            // 32
    float uGridLod;         // 40
    uint uGradQueryWord;    // 44: uGradQueries, 0 or 1
    float uLodBias[BCF_N_LAYERS];  // 48
};
#define uGradQueries (uGradQueryWord != 0u)

BcfMaterial bcfParams() {  // member by member: SPIRV-Cross's HLSL cannot copy a buffer's array whole
    BcfMaterial m;
    m.weightOffset = uWeightOffset;
    for (int i = 0; i < BCF_N_LAYERS; ++i) m.lodBias[i] = uLodBias[i];
    m.refSize = uRefSize;
    m.normalIndex = uNormalIndex;
    m.wrap = uWrap;
    return m;
}
#else
layout(binding = 0) uniform sampler2D bcfT[BCF_N_LAYERS];  // units 0..BCF_N_LAYERS - 1

layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
layout(std430, binding = 1) readonly buffer BcfQueries { vec4 bcfQueries[]; };
layout(std430, binding = 2) writeonly buffer BcfOutput { float bcfOut[]; };

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

BcfMaterial bcfParams() { return BcfMaterial(uWeightOffset, uLodBias, uRefSize, uNormalIndex, uWrap); }
#endif
uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= uCount) return;
    BcfMaterial m = bcfParams();
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
