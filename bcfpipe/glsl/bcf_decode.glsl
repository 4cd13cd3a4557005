// bcf_decode.glsl - runtime decoder for bcfpipe neural materials (BC6H or BC7 features + fp16 MLP).
//
// GLSL 4.50 core, no extensions, no #version and no bindings: the host inserts this file right
// after the #version line of the shader that uses it (see glsl/README.md; ES 3.2 notes there).
// Optional #defines placed before it: BCF_N_LAYERS (feature layers, 4 to 6; default 4: material.json's
// len(layers)), BCF_MAX_HIDDEN (default 64), BCF_MAX_OUT (default 16), and BCF_N_HIDDEN / BCF_N_OUT to
// compile for one network shape (constant loop bounds the compiler can unroll, hidden activations in
// registers; records of another shape are rejected).
//
// The including shader must define the weight-buffer accessor (declared here, so the library
// does not fix a binding or a buffer type):
//     uint bcfWeightWord(uint wordIndex);   // 32-bit little-endian word wordIndex of the buffer
//
// G(u, v, s) = f(T0(u, v, s_0), ..., T{N-1}(u, v, s_{N-1})),  s_i = s + b_i,  N = BCF_N_LAYERS
//   (paper eq. 2, sec. 5.2; a T_0 of one to three fixed layers of principal components gives N = 4..6)
//   uv: u along the width, v along the height, v = 0 is the first stored row (GL's t = 0 row);
//       texel i of a w-texel level has its centre at (i + 0.5) / w; wrapping is sampler state.
//   s : lod in the reference material's mip units (0 = full-resolution reference texels).
//   Each layer is sampled with the hardware trilinear filter (LINEAR_MIPMAP_LINEAR, mag LINEAR,
//   GL_TEXTURE_MAX_LEVEL = mip_count - 1, so s_i is clamped to [0, mip_count - 1] by the sampler).
//   Addressing is per axis (S along u, T along v), as the sources' UsdUVTexture wrapS / wrapT:
//   BCF_WRAP_REPEAT, BCF_WRAP_CLAMP or BCF_WRAP_MIRROR, which the samplers' GL_TEXTURE_WRAP_S / _T
//   must match (GL_REPEAT, GL_CLAMP_TO_EDGE, GL_MIRRORED_REPEAT).
//   Range reduction happens here, in exact fp32, not in the texture unit, per axis: x - floor(x) for
//   repeat, x - 2 floor(x / 2) for mirror, clamp(x, -1, 2) for clamp-to-edge, and s_i clamped to
//   [0, BCF_MAX_LOD]; hardware guarantees
//   full sub-texel precision only for |uv| <= 10 (D3D11_COMMONSHADER_TEXCOORD_RANGE_REDUCTION_MAX).
//   Precision limits (glsl/README.md): the fp32 uv itself resolves ulp(|uv|) * width texels.
//   Features: BC6H layers give 3 channels (T_i.rgb, n_in 12, 4 layers only), BC7 layers 4 (T_i.rgba,
//   n_in 4 N; upload as GL_COMPRESSED_RGBA_BPTC_UNORM); the record's n_in says which.
//   f : relu MLP n_in -> n_hidden -> n_out in fp32 with fp16 weights, then per channel
//       y = clamp(raw * out_scale + out_bias, lo, hi), lo = -1 for the normal x/y pair, else 0,
//       then for an HDR channel (record v2, log_gain g > 0) y = (exp2(g y) - 1) * (1 / (exp2(g) - 1)),
//       and normal z = sqrt(max(0, 1 - x^2 - y^2)) inserted right after normal y.

#ifndef BCF_MAX_HIDDEN
#define BCF_MAX_HIDDEN 64
#endif
#ifndef BCF_MAX_OUT
#define BCF_MAX_OUT 16
#endif
#ifndef BCF_MAX_LOD
#define BCF_MAX_LOD 32.0
#endif
#ifndef BCF_N_LAYERS
#define BCF_N_LAYERS 4
#endif
#if BCF_N_LAYERS < 4 || BCF_N_LAYERS > 6
#error "BCF_N_LAYERS must be 4, 5 or 6"
#endif
#ifdef BCF_N_HIDDEN
#undef BCF_MAX_HIDDEN
#define BCF_MAX_HIDDEN BCF_N_HIDDEN
#endif

// Weight record "BCFW" v1 or v2 (bcfpipe/model/decoder.py), at a 4-byte aligned byte offset:
//   word 0 magic 'BCFW' (0x57464342), 1 version (1 or 2), 2 n_in (12, or 4 N), 3 n_hidden, 4 n_out,
//   5 n_halves, then fp16 values from word 6: W1[n_hidden][n_in], b1[n_hidden], W2[n_out][n_hidden],
//   b2[n_out], out_scale[n_out], out_bias[n_out], and in v2 log_gain[n_out] (HDR channels).
//   Value e sits in word 6 + e/2, low half if e even.
const uint BCF_MAGIC = 0x57464342u;
const uint BCF_HEADER_WORDS = 6u;
const uint BCF_N_IN = uint(4 * BCF_N_LAYERS);  // BC7 layers; BC6H records have 12 (4 layers)

uint bcfWeightWord(uint wordIndex);

struct BcfMaterial {
    uint weightOffset;  // byte offset of the material's BCFW record in the weight buffer
    float lodBias[BCF_N_LAYERS];  // b_0..b_{N-1} (material.json layers[i].lod_bias)
    vec2 refSize;       // reference width, height (material.json reference; derivative path only)
    int normalIndex;    // index of normal x among the n_out model channels (y follows); -1: none
    ivec2 wrap;         // (S, T) addressing, BCF_WRAP_*: material.json sampling (the samplers' wrap modes)
};

const int BCF_WRAP_REPEAT = 0;  // GL_REPEAT
const int BCF_WRAP_CLAMP = 1;   // GL_CLAMP_TO_EDGE
const int BCF_WRAP_MIRROR = 2;  // GL_MIRRORED_REPEAT

// fp16 value e of the record whose first fp16 word is 'base'.
float bcfHalf(uint base, uint e) {
    vec2 p = unpackHalf2x16(bcfWeightWord(base + (e >> 1u)));
    return (e & 1u) == 0u ? p.x : p.y;
}

vec4 bcfHalf4(uint base, uint word) {  // four consecutive values starting at an even index
    return vec4(unpackHalf2x16(bcfWeightWord(base + word)), unpackHalf2x16(bcfWeightWord(base + word + 1u)));
}

// Number of channels bcfDecode* writes for this record: n_out (+1 with a normal), 0 if invalid.
int bcfChannelCount(BcfMaterial m) {
    uint w0 = m.weightOffset >> 2u;
    uint version = bcfWeightWord(w0 + 1u);
    uint ni = bcfWeightWord(w0 + 2u);
    if (bcfWeightWord(w0) != BCF_MAGIC || (version != 1u && version != 2u) || (ni != BCF_N_IN && (ni != 12u || BCF_N_LAYERS != 4)))
        return 0;
    uint nh = bcfWeightWord(w0 + 3u), no = bcfWeightWord(w0 + 4u);
    int extra = m.normalIndex >= 0 ? 1 : 0;
#ifdef BCF_N_HIDDEN
    if (nh != uint(BCF_N_HIDDEN)) return 0;
#endif
#ifdef BCF_N_OUT
    if (no != uint(BCF_N_OUT)) return 0;
#endif
    if (nh == 0u || nh > uint(BCF_MAX_HIDDEN) || no == 0u || int(no) + extra > BCF_MAX_OUT ||
        m.normalIndex + 1 >= int(no))
        return 0;
    return int(no) + extra;
}

// The decoder MLP and post-processing on already sampled features (t[i] = T_i.rgba; for BC6H layers
// only .rgb is read); returns the channel count (see bcfChannelCount; 0 = invalid record, ch untouched).
int bcfDecodeFeatures(BcfMaterial m, vec4 t[BCF_N_LAYERS], out float ch[BCF_MAX_OUT]) {
    int count = bcfChannelCount(m);
    if (count == 0) return 0;
    uint w0 = m.weightOffset >> 2u;
#ifdef BCF_N_HIDDEN
    const uint nh = uint(BCF_N_HIDDEN);
#else
    uint nh = bcfWeightWord(w0 + 3u);
#endif
#ifdef BCF_N_OUT
    const uint no = uint(BCF_N_OUT);
#else
    uint no = bcfWeightWord(w0 + 4u);
#endif
    uint base = w0 + BCF_HEADER_WORDS;
    float hid[BCF_MAX_HIDDEN];
    uint b1;
    if (bcfWeightWord(w0 + 2u) == BCF_N_IN) {
        // BC7: input order T0.rgba .. T{N-1}.rgba; a W1 row is 4 N halves = 2 N whole words
        b1 = nh * BCF_N_IN;
        for (uint j = 0u; j < nh; ++j) {
            uint row = j * (BCF_N_IN / 2u);
            float a = bcfHalf(base, b1 + j);
            a += dot(bcfHalf4(base, row), t[0]) + dot(bcfHalf4(base, row + 2u), t[1]) +
                 dot(bcfHalf4(base, row + 4u), t[2]) + dot(bcfHalf4(base, row + 6u), t[3])
#if BCF_N_LAYERS > 4
                 + dot(bcfHalf4(base, row + 8u), t[4])
#endif
#if BCF_N_LAYERS > 5
                 + dot(bcfHalf4(base, row + 10u), t[5])
#endif
                 ;
            hid[j] = max(a, 0.0);
        }
    } else {
        // BC6H (4 layers): input order T0.rgb, T1.rgb, T2.rgb, T3.rgb; a W1 row is 12 halves = 6 whole words
        vec4 fa = vec4(t[0].rgb, t[1].x), fb = vec4(t[1].yz, t[2].xy), fc = vec4(t[2].z, t[3].rgb);
        b1 = nh * 12u;
        for (uint j = 0u; j < nh; ++j) {
            uint row = j * 6u;
            float a = bcfHalf(base, b1 + j);
            a += dot(bcfHalf4(base, row), fa) + dot(bcfHalf4(base, row + 2u), fb) + dot(bcfHalf4(base, row + 4u), fc);
            hid[j] = max(a, 0.0);
        }
    }
    uint w2 = b1 + nh, b2 = w2 + no * nh, sc = b2 + no, bi = sc + no, lg = bi + no;
    bool hdr = bcfWeightWord(w0 + 1u) == 2u;
    int o = 0;
    for (uint c = 0u; c < no; ++c) {
        float a = bcfHalf(base, b2 + c);
        for (uint j = 0u; j < nh; ++j) a += bcfHalf(base, w2 + c * nh + j) * hid[j];
        float y = a * bcfHalf(base, sc + c) + bcfHalf(base, bi + c);
        bool isNormal = m.normalIndex >= 0 && (int(c) == m.normalIndex || int(c) == m.normalIndex + 1);
        y = clamp(y, isNormal ? -1.0 : 0.0, 1.0);
        float g = hdr ? bcfHalf(base, lg + c) : 0.0;
        if (g > 0.0) y = (exp2(g * y) - 1.0) * (1.0 / (exp2(g) - 1.0));
        ch[o++] = y;
        if (isNormal && int(c) == m.normalIndex + 1) {
            float x = ch[o - 2], yy = ch[o - 1];
            ch[o++] = sqrt(max(0.0, 1.0 - x * x - yy * yy));
        }
    }
    return count;
}

// One coordinate moved into the range where every texture unit filters at full precision, with the
// same texels and weights: the fractional part for repeat, x mod 2 for mirror (both exact in fp32),
// [-1, 2] for clamp-to-edge.
float bcfReduceCoord(float x, int wrap) {
    if (wrap == BCF_WRAP_REPEAT) return x - floor(x);
    if (wrap == BCF_WRAP_MIRROR) return x - 2.0 * floor(x * 0.5);
    return clamp(x, -1.0, 2.0);
}

// uv range-reduced per axis (bcfReduceCoord): u with wrap.x (S), v with wrap.y (T).
vec2 bcfReduceUv(vec2 uv, ivec2 wrap) {
    return vec2(bcfReduceCoord(uv.x, wrap.x), bcfReduceCoord(uv.y, wrap.y));
}

// Hardware trilinear samples of the N layers at s_i = s + b_i (s = +-inf is fine; NaN is not).
void bcfSampleFeatures(sampler2D T[BCF_N_LAYERS], BcfMaterial m, vec2 uv, float s, out vec4 t[BCF_N_LAYERS]) {
    uv = bcfReduceUv(uv, m.wrap);
    // constant indices into T: Vulkan without shaderSampledImageArrayDynamicIndexing (lavapipe) and
    // GLSL ES index sampler arrays with constant expressions only
#define BCF_SAMPLE(i) t[i] = textureLod(T[i], uv, clamp(s + m.lodBias[i], 0.0, BCF_MAX_LOD))
    BCF_SAMPLE(0); BCF_SAMPLE(1); BCF_SAMPLE(2); BCF_SAMPLE(3);
#if BCF_N_LAYERS > 4
    BCF_SAMPLE(4);
#endif
#if BCF_N_LAYERS > 5
    BCF_SAMPLE(5);
#endif
#undef BCF_SAMPLE
}

// s from uv derivatives (paper sec. 5.2): log2 of the larger pixel footprint in reference texels.
// This is GL's isotropic scale factor rho (OpenGL 4.5 eq. 8.5), so with square layers whose
// b_i = log2(w_i / W) it equals the lod textureGrad(T_i, uv, dx, dy) would pick for each layer.
// Zero derivatives give -66 (magnification); huge or infinite ones overflow to +inf (last mip).
float bcfLodFromGrad(vec2 duvdx, vec2 duvdy, vec2 refSize) {
    float rho = max(length(duvdx * refSize), length(duvdy * refSize));
    return log2(max(rho, 1e-20));
}

// Decode at an explicit lod s (reference mip units). Returns the channel count, 0 if invalid.
int bcfDecodeLod(sampler2D T[BCF_N_LAYERS], BcfMaterial m, vec2 uv, float s, out float ch[BCF_MAX_OUT]) {
    vec4 t[BCF_N_LAYERS];
    bcfSampleFeatures(T, m, uv, s, t);
    return bcfDecodeFeatures(m, t, ch);
}

// Decode with the lod from uv derivatives (e.g. dFdx(uv), dFdy(uv) in a fragment shader).
int bcfDecodeGrad(sampler2D T[BCF_N_LAYERS], BcfMaterial m, vec2 uv, vec2 duvdx, vec2 duvdy,
                  out float ch[BCF_MAX_OUT]) {
    return bcfDecodeLod(T, m, uv, bcfLodFromGrad(duvdx, duvdy, m.refSize), ch);
}
