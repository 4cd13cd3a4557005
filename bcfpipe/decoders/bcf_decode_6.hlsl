struct BcfMaterial
{
    uint weightOffset;
    float lodBias[6];
    float2 refSize;
    int normalIndex;
    int2 wrap;
};

static const uint3 gl_WorkGroupSize = uint3(64u, 1u, 1u);

ByteAddressBuffer _831 : register(t3, space0);
ByteAddressBuffer _872 : register(t0, space0);
ByteAddressBuffer _943 : register(t1, space0);
RWByteAddressBuffer _1007 : register(u2, space0);
Texture2D<float4> bcfT[6] : register(t4, space0);
SamplerState _bcfT_sampler[6] : register(s4, space0);

static uint3 gl_GlobalInvocationID;
struct SPIRV_Cross_Input
{
    uint3 gl_GlobalInvocationID : SV_DispatchThreadID;
};

uint spvPackHalf2x16(float2 value)
{
    uint2 Packed = f32tof16(value);
    return Packed.x | (Packed.y << 16);
}

float2 spvUnpackHalf2x16(uint value)
{
    return f16tof32(uint2(value & 0xffff, value >> 16));
}

BcfMaterial bcfParams()
{
    BcfMaterial m;
    m.weightOffset = _831.Load(0);
    for (int i = 0; i < 6; i++)
    {
        m.lodBias[i] = asfloat(_831.Load(i * 4 + 48));
    }
    m.refSize = asfloat(_831.Load2(24));
    m.normalIndex = int(_831.Load(4));
    m.wrap = int2(_831.Load2(16));
    return m;
}

float bcfReduceCoord(float x, int wrap)
{
    if (wrap == 0)
    {
        return x - floor(x);
    }
    if (wrap == 2)
    {
        return x - (2.0f * floor(x * 0.5f));
    }
    return clamp(x, -1.0f, 2.0f);
}

float2 bcfReduceUv(float2 uv, int2 wrap)
{
    float param = uv.x;
    int param_1 = wrap.x;
    float param_2 = uv.y;
    int param_3 = wrap.y;
    return float2(bcfReduceCoord(param, param_1), bcfReduceCoord(param_2, param_3));
}

void bcfSampleFeatures(Texture2D<float4> T[6], SamplerState _T_sampler[6], BcfMaterial m, inout float2 uv, float s, inout float4 t[6])
{
    float2 param = uv;
    int2 param_1 = m.wrap;
    uv = bcfReduceUv(param, param_1);
    t[0] = T[0].SampleLevel(_T_sampler[0], uv, clamp(s + m.lodBias[0], 0.0f, 32.0f));
    t[1] = T[1].SampleLevel(_T_sampler[1], uv, clamp(s + m.lodBias[1], 0.0f, 32.0f));
    t[2] = T[2].SampleLevel(_T_sampler[2], uv, clamp(s + m.lodBias[2], 0.0f, 32.0f));
    t[3] = T[3].SampleLevel(_T_sampler[3], uv, clamp(s + m.lodBias[3], 0.0f, 32.0f));
    t[4] = T[4].SampleLevel(_T_sampler[4], uv, clamp(s + m.lodBias[4], 0.0f, 32.0f));
    t[5] = T[5].SampleLevel(_T_sampler[5], uv, clamp(s + m.lodBias[5], 0.0f, 32.0f));
}

uint bcfWeightWord(uint wordIndex)
{
    return _872.Load(wordIndex * 4 + 0);
}

int bcfChannelCount(BcfMaterial m)
{
    uint w0 = m.weightOffset >> 2u;
    uint param = w0 + 1u;
    uint version = bcfWeightWord(param);
    uint param_1 = w0 + 2u;
    uint ni = bcfWeightWord(param_1);
    uint param_2 = w0;
    bool _163 = bcfWeightWord(param_2) != 1464222530u;
    bool _172;
    if (!_163)
    {
        _172 = (version != 1u) && (version != 2u);
    }
    else
    {
        _172 = _163;
    }
    bool _187;
    if (!_172)
    {
        bool _178 = ni != 24u;
        bool _186;
        if (_178)
        {
            _186 = (ni != 12u) || true;
        }
        else
        {
            _186 = _178;
        }
        _187 = _186;
    }
    else
    {
        _187 = _172;
    }
    if (_187)
    {
        return 0;
    }
    uint param_3 = w0 + 3u;
    uint nh = bcfWeightWord(param_3);
    uint param_4 = w0 + 4u;
    uint no = bcfWeightWord(param_4);
    int extra = int(m.normalIndex >= 0);
    bool _218 = ((nh == 0u) || (nh > 64u)) || (no == 0u);
    bool _228;
    if (!_218)
    {
        _228 = (int(no) + extra) > 16;
    }
    else
    {
        _228 = _218;
    }
    bool _238;
    if (!_228)
    {
        _238 = (m.normalIndex + 1) >= int(no);
    }
    else
    {
        _238 = _228;
    }
    if (_238)
    {
        return 0;
    }
    return int(no) + extra;
}

float bcfHalf(uint base, uint e)
{
    uint param = base + (e >> 1u);
    float2 p = spvUnpackHalf2x16(bcfWeightWord(param));
    float _112;
    if ((e & 1u) == 0u)
    {
        _112 = p.x;
    }
    else
    {
        _112 = p.y;
    }
    return _112;
}

float4 bcfHalf4(uint base, uint word)
{
    uint param = base + word;
    uint param_1 = (base + word) + 1u;
    return float4(spvUnpackHalf2x16(bcfWeightWord(param)), spvUnpackHalf2x16(bcfWeightWord(param_1)));
}

int bcfDecodeFeatures(BcfMaterial m, float4 t[6], inout float ch[16])
{
    BcfMaterial param = m;
    int count = bcfChannelCount(param);
    if (count == 0)
    {
        return 0;
    }
    uint w0 = m.weightOffset >> 2u;
    uint param_1 = w0 + 3u;
    uint nh = bcfWeightWord(param_1);
    uint param_2 = w0 + 4u;
    uint no = bcfWeightWord(param_2);
    uint base = w0 + 6u;
    uint param_3 = w0 + 2u;
    uint b1;
    float hid[64];
    if (bcfWeightWord(param_3) == 24u)
    {
        b1 = nh * 24u;
        for (uint j = 0u; j < nh; j++)
        {
            uint row = j * 12u;
            uint param_4 = base;
            uint param_5 = b1 + j;
            float a = bcfHalf(param_4, param_5);
            uint param_6 = base;
            uint param_7 = row;
            uint param_8 = base;
            uint param_9 = row + 2u;
            uint param_10 = base;
            uint param_11 = row + 4u;
            uint param_12 = base;
            uint param_13 = row + 6u;
            uint param_14 = base;
            uint param_15 = row + 8u;
            uint param_16 = base;
            uint param_17 = row + 10u;
            a += (((((dot(bcfHalf4(param_6, param_7), t[0]) + dot(bcfHalf4(param_8, param_9), t[1])) + dot(bcfHalf4(param_10, param_11), t[2])) + dot(bcfHalf4(param_12, param_13), t[3])) + dot(bcfHalf4(param_14, param_15), t[4])) + dot(bcfHalf4(param_16, param_17), t[5]));
            hid[j] = max(a, 0.0f);
        }
    }
    else
    {
        float4 fa = float4(t[0].xyz, t[1].x);
        float4 fb = float4(t[1].yz, t[2].xy);
        float4 fc = float4(t[2].z, t[3].xyz);
        b1 = nh * 12u;
        for (uint j_1 = 0u; j_1 < nh; j_1++)
        {
            uint row_1 = j_1 * 6u;
            uint param_18 = base;
            uint param_19 = b1 + j_1;
            float a_1 = bcfHalf(param_18, param_19);
            uint param_20 = base;
            uint param_21 = row_1;
            uint param_22 = base;
            uint param_23 = row_1 + 2u;
            uint param_24 = base;
            uint param_25 = row_1 + 4u;
            a_1 += ((dot(bcfHalf4(param_20, param_21), fa) + dot(bcfHalf4(param_22, param_23), fb)) + dot(bcfHalf4(param_24, param_25), fc));
            hid[j_1] = max(a_1, 0.0f);
        }
    }
    uint w2 = b1 + nh;
    uint b2 = w2 + (no * nh);
    uint sc = b2 + no;
    uint bi = sc + no;
    uint lg = bi + no;
    uint param_26 = w0 + 1u;
    bool hdr = bcfWeightWord(param_26) == 2u;
    int o = 0;
    float _592;
    for (uint c = 0u; c < no; c++)
    {
        uint param_27 = base;
        uint param_28 = b2 + c;
        float a_2 = bcfHalf(param_27, param_28);
        for (uint j_2 = 0u; j_2 < nh; j_2++)
        {
            uint param_29 = base;
            uint param_30 = (w2 + (c * nh)) + j_2;
            a_2 += (bcfHalf(param_29, param_30) * hid[j_2]);
        }
        uint param_31 = base;
        uint param_32 = sc + c;
        uint param_33 = base;
        uint param_34 = bi + c;
        float y = (a_2 * bcfHalf(param_31, param_32)) + bcfHalf(param_33, param_34);
        bool _565 = m.normalIndex >= 0;
        bool _583;
        if (_565)
        {
            bool _572 = int(c) == m.normalIndex;
            bool _582;
            if (!_572)
            {
                _582 = int(c) == (m.normalIndex + 1);
            }
            else
            {
                _582 = _572;
            }
            _583 = _582;
        }
        else
        {
            _583 = _565;
        }
        bool isNormal = _583;
        y = clamp(y, isNormal ? (-1.0f) : 0.0f, 1.0f);
        if (hdr)
        {
            uint param_35 = base;
            uint param_36 = lg + c;
            _592 = bcfHalf(param_35, param_36);
        }
        else
        {
            _592 = 0.0f;
        }
        float g = _592;
        if (g > 0.0f)
        {
            y = (exp2(g * y) - 1.0f) * (1.0f / (exp2(g) - 1.0f));
        }
        int _618 = o;
        o = _618 + 1;
        ch[_618] = y;
        bool _631;
        if (isNormal)
        {
            _631 = int(c) == (m.normalIndex + 1);
        }
        else
        {
            _631 = isNormal;
        }
        if (_631)
        {
            float x = ch[o - 2];
            float yy = ch[o - 1];
            int _644 = o;
            o = _644 + 1;
            ch[_644] = sqrt(max(0.0f, (1.0f - (x * x)) - (yy * yy)));
        }
    }
    return count;
}

int bcfDecodeLod(Texture2D<float4> T[6], SamplerState _T_sampler[6], BcfMaterial m, float2 uv, float s, out float ch[16])
{
    BcfMaterial param = m;
    float2 param_1 = uv;
    float param_2 = s;
    float4 param_3[6];
    bcfSampleFeatures(T, _T_sampler, param, param_1, param_2, param_3);
    float4 t[6] = param_3;
    BcfMaterial param_4 = m;
    float4 param_5[6] = t;
    float param_6[16];
    int _804 = bcfDecodeFeatures(param_4, param_5, param_6);
    ch = param_6;
    return _804;
}

float bcfLodFromGrad(float2 duvdx, float2 duvdy, float2 refSize)
{
    float rho = max(length(duvdx * refSize), length(duvdy * refSize));
    return log2(max(rho, 9.9999996826552253889678874634872e-21f));
}

int bcfDecodeGrad(Texture2D<float4> T[6], SamplerState _T_sampler[6], BcfMaterial m, float2 uv, float2 duvdx, float2 duvdy, out float ch[16])
{
    float2 param = duvdx;
    float2 param_1 = duvdy;
    float2 param_2 = m.refSize;
    BcfMaterial param_3 = m;
    float2 param_4 = uv;
    float param_5 = bcfLodFromGrad(param, param_1, param_2);
    float param_6[16];
    int _822 = bcfDecodeLod(T, _T_sampler, param_3, param_4, param_5, param_6);
    ch = param_6;
    return _822;
}

void comp_main()
{
    uint i = gl_GlobalInvocationID.x;
    if (i >= _831.Load(8))
    {
        return;
    }
    BcfMaterial m = bcfParams();
    int n;
    float ch[16];
    if (_831.Load(32) > 0u)
    {
        float2 uv = (float2(float(i % _831.Load(32)), float(i / _831.Load(32))) + 0.5f.xx) / float2(_831.Load2(32));
        BcfMaterial param = m;
        float2 param_1 = uv;
        float param_2 = asfloat(_831.Load(40));
        float param_3[16];
        int _930 = bcfDecodeLod(bcfT, _bcfT_sampler, param, param_1, param_2, param_3);
        ch = param_3;
        n = _930;
    }
    else
    {
        if (_831.Load(44) != 0u)
        {
            float4 a = asfloat(_943.Load4((2u * i) * 16 + 0));
            float4 b = asfloat(_943.Load4(((2u * i) + 1u) * 16 + 0));
            BcfMaterial param_4 = m;
            float2 param_5 = a.xy;
            float2 param_6 = a.zw;
            float2 param_7 = b.xy;
            float param_8[16];
            int _967 = bcfDecodeGrad(bcfT, _bcfT_sampler, param_4, param_5, param_6, param_7, param_8);
            ch = param_8;
            n = _967;
        }
        else
        {
            float4 q = asfloat(_943.Load4(i * 16 + 0));
            BcfMaterial param_9 = m;
            float2 param_10 = q.xy;
            float param_11 = q.z;
            float param_12[16];
            int _983 = bcfDecodeLod(bcfT, _bcfT_sampler, param_9, param_10, param_11, param_12);
            ch = param_12;
            n = _983;
        }
    }
    uint o = i * _831.Load(12);
    if (n == 0)
    {
        for (uint c = 0u; c < _831.Load(12); c++)
        {
            _1007.Store((o + c) * 4 + 0, asuint(asfloat(2143289344u)));
        }
        return;
    }
    int c_1 = 0;
    for (;;)
    {
        bool _1025 = c_1 < n;
        bool _1033;
        if (_1025)
        {
            _1033 = uint(c_1) < _831.Load(12);
        }
        else
        {
            _1033 = _1025;
        }
        if (_1033)
        {
            _1007.Store((o + uint(c_1)) * 4 + 0, asuint(ch[c_1]));
            c_1++;
            continue;
        }
        else
        {
            break;
        }
    }
}

[numthreads(64, 1, 1)]
void main(SPIRV_Cross_Input stage_input)
{
    gl_GlobalInvocationID = stage_input.gl_GlobalInvocationID;
    comp_main();
}
