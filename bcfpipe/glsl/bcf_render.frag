#version 450 core
// bcf_render.frag: the reference renderer's surface shader (bcfpipe render, docs/render.md).
// The host inserts bcf_decode.glsl after the #version line, preceded by #define BCF_NEURAL 0 or 1.
//
// BCF_NEURAL 1: the UsdPreviewSurface components come from the neural decoder, one sample per
//   pixel, at the lod s from the uv derivatives (bcfDecodeGrad, paper sec. 5.2).
//   A component the decoder does not drive (a --layout auto material's classic group) reads
//   its UsdUVTexture as below, from texture units BCF_N_LAYERS (4 to 6: the feature layers come
//   first) and up: its source is 1024 + unit * 4 + slot, unit counted from there.
//   A mip-split material (BCF_SPLIT = k > 0, the material's bcf:split) reads each component the
//   decoder drives from its original network (BCF_BELOW*: a UsdUVTexture or a constant) up to
//   s = k - 1 and from the decoder from s = k, mixed linearly in s between (material.json "split").
// BCF_NEURAL 0: they come from up to 8 UsdUVTexture files (trilinear, each with its own
//   UsdTransform2d), or are constants.
// Both then shade with the same model (shade() below): Lambert diffuse plus GGX specular
// (Smith-Schlick visibility, Schlick Fresnel) under one directional light, plus an ambient term
// (albedo + F0) * occlusion; the metallic or the specular workflow of UsdPreviewSurface; emissive
// added; opacity < opacityThreshold discards; normal maps in a tangent frame from the st and
// position derivatives. Output: linear radiance in rgb, 1 in alpha.

#ifndef BCF_NEURAL
#define BCF_NEURAL 0
#endif
#define N_COMPONENTS 17  // bcfpipe/render/surfaces.py COMPONENTS
#define MAX_TEXTURES 8
#define NEURAL_ST 8      // uStMatrix/uStOffset entry of the neural material's st transform

// The component routing is compiled in (one program per material, as an engine would specialise
// it): component k is BCF_BIAS[k] when BCF_SOURCE[k] < 0, else decode(source) * BCF_SCALE[k] +
// BCF_BIAS[k], where the source is a decoder channel (neural) or texture unit * 4 + rgba slot
// (original), sRGB-decoded when BCF_SRGB[k] != 0. BCF_TEXTURES: the original's texture count.
// The defaults (every component 0) only let the file compile on its own. For neural materials
// the host also defines BCF_N_HIDDEN and BCF_N_OUT from the weight record's header.
#ifndef BCF_SOURCE
#define BCF_SOURCE int[](-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1)
#define BCF_SCALE float[](0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0.)
#define BCF_BIAS float[](0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0., 0.)
#define BCF_SRGB int[](0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
#define BCF_TEXTURES 0
#endif
#ifndef BCF_SPLIT
#define BCF_SPLIT 0
#endif
#if BCF_SPLIT > 0
const int kBelow[N_COMPONENTS] = BCF_BELOW;
const float kBelowScale[N_COMPONENTS] = BCF_BELOW_SCALE;
const float kBelowBias[N_COMPONENTS] = BCF_BELOW_BIAS;
const int kBelowSrgb[N_COMPONENTS] = BCF_BELOW_SRGB;
#endif
const int kSource[N_COMPONENTS] = BCF_SOURCE;
const float kScale[N_COMPONENTS] = BCF_SCALE;
const float kBias[N_COMPONENTS] = BCF_BIAS;
const int kSrgb[N_COMPONENTS] = BCF_SRGB;
// st transforms (UsdTransform2d): st' = (dot(m.xy, st), dot(m.zw, st)) + offset
uniform vec4 uStMatrix[MAX_TEXTURES + 1];
uniform vec2 uStOffset[MAX_TEXTURES + 1];
uniform int uNormalSt;  // the st transform whose axes the normal map's x and y follow

uniform vec3 uEye;
uniform vec3 uLightDirection;  // towards the light, unit length
uniform vec3 uLightRadiance;
uniform vec3 uAmbient;
uniform int uUseSpecularWorkflow;
uniform float uOpacityThreshold;

#if BCF_NEURAL
layout(binding = 0) uniform sampler2D bcfT[BCF_N_LAYERS];  // units 0..BCF_N_LAYERS - 1
uniform uint uWeightOffset;
uniform float uLodBias[BCF_N_LAYERS];
uniform vec2 uRefSize;
uniform int uNormalIndex;
uniform ivec2 uWrap;
#define TEXTURE_SOURCE 1024  // bcfpipe/render/surfaces.py
layout(binding = BCF_N_LAYERS) uniform sampler2D uTexture[MAX_TEXTURES];
#else
layout(binding = 0) uniform sampler2D uTexture[MAX_TEXTURES];
#endif
layout(std430, binding = 0) readonly buffer BcfWeights { uint bcfWeights[]; };
uint bcfWeightWord(uint wordIndex) { return bcfWeights[wordIndex]; }

layout(location = 0) in vec3 vPosition;
layout(location = 1) in vec3 vNormal;
layout(location = 2) in vec2 vSt;
layout(location = 0) out vec4 fragColor;

const float PI = 3.14159265358979;

float srgbToLinear(float c) {
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

vec2 stTransform(int i, vec2 st) {
    vec4 m = uStMatrix[i];
    return vec2(dot(m.xy, st), dot(m.zw, st)) + uStOffset[i];
}

float component(int k, float texel) {
    if (kSource[k] < 0) return kBias[k];
    return (kSrgb[k] != 0 ? srgbToLinear(texel) : texel) * kScale[k] + kBias[k];
}

#if BCF_SPLIT > 0
float below(int k, float texel) {  // a mip split's value below the split (texel: its texture's, if any)
    if (kBelow[k] < 0) return kBelowBias[k];
    return (kBelowSrgb[k] != 0 ? srgbToLinear(texel) : texel) * kBelowScale[k] + kBelowBias[k];
}
#endif

// Tangent frame from screen-space derivatives (Schueler, "Normal Mapping Without Precomputed
// Tangents", 2013): T and B follow +s and +t of st on the surface.
vec3 perturb(vec3 n, vec3 tangentNormal, vec2 st) {
    vec3 dp1 = dFdx(vPosition), dp2 = dFdy(vPosition);
    vec2 d1 = dFdx(st), d2 = dFdy(st);
    vec3 p2 = cross(dp2, n), p1 = cross(n, dp1);
    vec3 t = p2 * d1.x + p1 * d2.x, b = p2 * d1.y + p1 * d2.y;
    float m = max(dot(t, t), dot(b, b));
    if (!(m > 0.0) || isinf(m)) return n;
    vec3 r = mat3(t * inversesqrt(m), b * inversesqrt(m), n) * tangentNormal;
    float len = length(r);
    return len > 0.0 ? r / len : n;
}

vec3 shade(vec3 n, vec3 v, vec3 diffuseColor, vec3 emissive, vec3 specularColor, float metallic,
           float roughness, float occlusion, float ior) {
    float r0 = (1.0 - ior) / (1.0 + ior);
    vec3 f0 = uUseSpecularWorkflow != 0 ? specularColor : mix(vec3(r0 * r0), diffuseColor, metallic);
    vec3 albedo = uUseSpecularWorkflow != 0 ? diffuseColor : diffuseColor * (1.0 - metallic);
    vec3 l = uLightDirection, h = normalize(l + v);
    float nl = max(dot(n, l), 0.0), nv = max(dot(n, v), 1e-4), nh = max(dot(n, h), 0.0);
    float a = max(roughness * roughness, 2e-3), a2 = a * a;
    float d = nh * nh * (a2 - 1.0) + 1.0;
    float ndf = a2 / (PI * d * d);
    float k = 0.5 * a;
    float vis = 0.25 / ((nl * (1.0 - k) + k) * (nv * (1.0 - k) + k));
    vec3 f = f0 + (1.0 - f0) * pow(1.0 - max(dot(v, h), 0.0), 5.0);
    vec3 direct = (albedo / PI + ndf * vis * f) * uLightRadiance * nl;
    return direct + uAmbient * occlusion * (albedo + f0) + emissive;
}

void main() {
    float c[N_COMPONENTS];
#if BCF_NEURAL
    vec2 st = stTransform(NEURAL_ST, vSt);
    vec2 uv = vec2(st.x, 1.0 - st.y);
    BcfMaterial m = BcfMaterial(uWeightOffset, uLodBias, uRefSize, uNormalIndex, uWrap);
    float ch[BCF_MAX_OUT];
    int n = bcfDecodeGrad(bcfT, m, uv, dFdx(uv), dFdy(uv), ch);
    if (n == 0) {  // an invalid weight record
        fragColor = vec4(1.0, 0.0, 1.0, 1.0);
        return;
    }
#if BCF_SPLIT > 0
    float sLod = bcfLodFromGrad(dFdx(uv), dFdy(uv), uRefSize) - float(BCF_SPLIT - 1);
    float wSplit = sLod >= 1.0 ? 1.0 : (sLod > 0.0 ? sLod : 0.0);  // NaN: the original network
#endif
    vec4 texel[MAX_TEXTURES];
    for (int t = 0; t < BCF_TEXTURES; ++t) {
        vec2 tst = stTransform(t, vSt);
        texel[t] = texture(uTexture[t], vec2(tst.x, 1.0 - tst.y));
    }
    for (int k = 0; k < N_COMPONENTS; ++k) {
        int s = kSource[k];
        if (s >= TEXTURE_SOURCE) {
            s -= TEXTURE_SOURCE;
            c[k] = component(k, texel[s >> 2][s & 3]);
            continue;
        }
#ifdef BCF_N_OUT  // the host checked every source against the compiled-in network shape
        c[k] = component(k, s < 0 ? 0.0 : ch[s]);
#else
        c[k] = component(k, s < 0 ? 0.0 : ch[min(s, n - 1)]);
#endif
#if BCF_SPLIT > 0
        if (s >= 0 && wSplit < 1.0) {
            int b = max(kBelow[k] - TEXTURE_SOURCE, 0);
            c[k] = mix(below(k, texel[b >> 2][b & 3]), c[k], wSplit);
        }
#endif
    }
#else
    vec4 texel[MAX_TEXTURES];
    for (int t = 0; t < BCF_TEXTURES; ++t) {
        vec2 st = stTransform(t, vSt);
        texel[t] = texture(uTexture[t], vec2(st.x, 1.0 - st.y));
    }
    for (int k = 0; k < N_COMPONENTS; ++k)
        c[k] = component(k, kSource[k] < 0 ? 0.0 : texel[kSource[k] >> 2][kSource[k] & 3]);
#endif
    if (uOpacityThreshold > 0.0 && c[11] < uOpacityThreshold) discard;
    vec3 v = normalize(uEye - vPosition);
    vec3 ng = normalize(vNormal);
    if (dot(ng, v) < 0.0) ng = -ng;  // two-sided
    vec3 nrm = perturb(ng, vec3(c[12], c[13], c[14]), stTransform(uNormalSt, vSt));
    vec3 rgb = shade(nrm, v, vec3(c[0], c[1], c[2]), vec3(c[3], c[4], c[5]), vec3(c[6], c[7], c[8]),
                     c[9], clamp(c[10], 0.0, 1.0), c[15], c[16]);
    fragColor = vec4(rgb, 1.0);
}
