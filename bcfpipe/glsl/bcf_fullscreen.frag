#version 450 core
// Example fragment shader: decode one neural material per pixel and show three of its channels.
// The host inserts bcf_decode.glsl right after the #version line (glsl/README.md).
//
// Bindings: texture units 0..N-1 = T0..T{N-1}, N = BCF_N_LAYERS (trilinear, GL_TEXTURE_MAX_LEVEL = mip_count - 1,
// wrap per material.json); shader storage block 0 = the weight buffer (one or many BCFW records).
// Uniforms:
//   uint  uWeightOffset  byte offset of this material's record in the weight buffer
//   float uLodBias[N]    b_0..b_{N-1}
//   vec2  uRefSize       reference width, height (for the lod from derivatives)
//   int   uNormalIndex   normal x among the model outputs, -1 if none
//   ivec2 uWrap          (S, T) addressing, BCF_WRAP_* (0 repeat, 1 clamp, 2 mirror; material.json sampling)
//   int   uLodMode       0: s from dFdx/dFdy of uv (paper sec. 5.2); 1: s = uLod
//   float uLod           explicit lod (reference mip units) for uLodMode 1
//   int   uView          first of the three channels written to rgb (normals stay in [-1, 1])
// Output: location 0 = vec4(ch[uView], ch[uView+1], ch[uView+2], 1); magenta if the record is invalid.

layout(binding = 0) uniform sampler2D bcfT[BCF_N_LAYERS];  // units 0..BCF_N_LAYERS - 1

layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

uniform uint uWeightOffset;
uniform float uLodBias[BCF_N_LAYERS];
uniform vec2 uRefSize;
uniform int uNormalIndex;
uniform ivec2 uWrap;
uniform int uLodMode;
uniform float uLod;
uniform int uView;

layout(location = 0) in vec2 vUv;
layout(location = 0) out vec4 fragColor;

void main() {
    BcfMaterial m = BcfMaterial(uWeightOffset, uLodBias, uRefSize, uNormalIndex, uWrap);
    float ch[BCF_MAX_OUT];
    int n;
    if (uLodMode == 1)
        n = bcfDecodeLod(bcfT, m, vUv, uLod, ch);
    else
        n = bcfDecodeGrad(bcfT, m, vUv, dFdx(vUv), dFdy(vUv), ch);
    if (n == 0) {
        fragColor = vec4(1.0, 0.0, 1.0, 1.0);
        return;
    }
    vec3 rgb;
    for (int k = 0; k < 3; ++k) {
        int c = clamp(uView + k, 0, n - 1);
        rgb[k] = ch[c];
    }
    fragColor = vec4(rgb, 1.0);
}
