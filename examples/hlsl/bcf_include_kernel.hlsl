// An engine's own compute kernel built on bcf_decode.hlsli (bcfpipe/decoders/): how a shader calls
// the include. Its resources are those of the shipped bcf_decode_N.hlsl (docs/format.md, Other
// APIs), so the same host code runs either; tests/test_shader_targets.py runs this one on Vulkan
// and holds it to decoder.onnx. Compile with BCF_N_LAYERS defined and the decoders folder on the
// include path, e.g. glslangValidator -D -V -S comp -e main -I bcfpipe/decoders -DBCF_N_LAYERS=5 ...

#ifndef BCF_N_LAYERS
#define BCF_N_LAYERS 4
#endif

ByteAddressBuffer bcfWeights : register(t0);   // weights.bin
ByteAddressBuffer bcfQueries : register(t1);   // float4 (u, v, s, -) per sample
RWByteAddressBuffer bcfOut : register(u2);     // float[count * stride]
ByteAddressBuffer bcfParams : register(t3);    // bcf_decode_N.hlsl's parameter block
Texture2D<float4> bcfT[BCF_N_LAYERS] : register(t4);
SamplerState bcfS[BCF_N_LAYERS] : register(s4);

uint bcfWeightWord(uint wordIndex) { return bcfWeights.Load(wordIndex * 4); }

#include "bcf_decode.hlsli"

BcfMaterial bcfMaterial() {
    BcfMaterial m;
    m.weightOffset = bcfParams.Load(0);
    m.normalIndex = asint(bcfParams.Load(4));
    m.wrap = asint(bcfParams.Load2(16));
    m.refSize = asfloat(bcfParams.Load2(24));
    for (int i = 0; i < BCF_N_LAYERS; ++i) m.lodBias[i] = asfloat(bcfParams.Load(48 + 4 * i));
    return m;
}

[numthreads(64, 1, 1)]
void main(uint3 id : SV_DispatchThreadID) {
    uint i = id.x;
    if (i >= bcfParams.Load(8)) return;
    uint stride = bcfParams.Load(12);
    uint2 grid = bcfParams.Load2(32);
    BcfMaterial m = bcfMaterial();
    float ch[16];
    int n;
    if (grid.x > 0) {
        float2 uv = (float2(i % grid.x, i / grid.x) + 0.5) / float2(grid);
        n = bcfDecodeLod(bcfT, bcfS, m, uv, asfloat(bcfParams.Load(40)), ch);
    } else if (bcfParams.Load(44) != 0) {
        float4 a = asfloat(bcfQueries.Load4(32 * i)), b = asfloat(bcfQueries.Load4(32 * i + 16));
        n = bcfDecodeGrad(bcfT, bcfS, m, a.xy, a.zw, b.xy, ch);
    } else {
        float4 q = asfloat(bcfQueries.Load4(16 * i));
        n = bcfDecodeLod(bcfT, bcfS, m, q.xy, q.z, ch);
    }
    for (uint c = 0; c < stride; ++c)
        bcfOut.Store(4 * (i * stride + c), n == 0 ? 0x7FC00000u : (c < uint(n) ? asuint(ch[c]) : 0u));
}
