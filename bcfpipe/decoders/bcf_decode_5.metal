#pragma clang diagnostic ignored "-Wmissing-prototypes"
#pragma clang diagnostic ignored "-Wmissing-braces"

#include <metal_stdlib>
#include <simd/simd.h>

using namespace metal;

template<typename T, size_t Num>
struct spvUnsafeArray
{
    T elements[Num ? Num : 1];
    
    thread T& operator [] (size_t pos) thread
    {
        return elements[pos];
    }
    constexpr const thread T& operator [] (size_t pos) const thread
    {
        return elements[pos];
    }
    
    device T& operator [] (size_t pos) device
    {
        return elements[pos];
    }
    constexpr const device T& operator [] (size_t pos) const device
    {
        return elements[pos];
    }
    
    constexpr const constant T& operator [] (size_t pos) const constant
    {
        return elements[pos];
    }
    
    threadgroup T& operator [] (size_t pos) threadgroup
    {
        return elements[pos];
    }
    constexpr const threadgroup T& operator [] (size_t pos) const threadgroup
    {
        return elements[pos];
    }
};

struct BcfMaterial
{
    uint weightOffset;
    spvUnsafeArray<float, 5> lodBias;
    float2 refSize;
    int normalIndex;
    int2 wrap;
};

struct BcfParams
{
    uint uWeightOffset;
    int uNormalIndex;
    uint uCount;
    uint uOutStride;
    int2 uWrap;
    float2 uRefSize;
    uint2 uGrid;
    float uGridLod;
    uint uGradQueryWord;
    float uLodBias[5];
};

struct BcfWeights
{
    uint bcfWeights[1];
};

struct BcfQueries
{
    float4 bcfQueries[1];
};

struct BcfOutput
{
    float bcfOut[1];
};

constant uint3 gl_WorkGroupSize [[maybe_unused]] = uint3(64u, 1u, 1u);

static inline __attribute__((always_inline))
BcfMaterial bcfParams(const device BcfParams& v_811)
{
    BcfMaterial m;
    m.weightOffset = v_811.uWeightOffset;
    for (int i = 0; i < 5; i++)
    {
        m.lodBias[i] = v_811.uLodBias[i];
    }
    m.refSize = v_811.uRefSize;
    m.normalIndex = v_811.uNormalIndex;
    m.wrap = v_811.uWrap;
    return m;
}

static inline __attribute__((always_inline))
float bcfReduceCoord(thread const float& x, thread const int& wrap)
{
    if (wrap == 0)
    {
        return x - floor(x);
    }
    if (wrap == 2)
    {
        return x - (2.0 * floor(x * 0.5));
    }
    return fast::clamp(x, -1.0, 2.0);
}

static inline __attribute__((always_inline))
float2 bcfReduceUv(thread const float2& uv, thread const int2& wrap)
{
    float param = uv.x;
    int param_1 = wrap.x;
    float param_2 = uv.y;
    int param_3 = wrap.y;
    return float2(bcfReduceCoord(param, param_1), bcfReduceCoord(param_2, param_3));
}

static inline __attribute__((always_inline))
void bcfSampleFeatures(thread const array<texture2d<float>, 5>& T, thread const array<sampler, 5>& TSmplr, thread const BcfMaterial& m, thread float2& uv, thread const float& s, thread spvUnsafeArray<float4, 5>& t)
{
    float2 param = uv;
    int2 param_1 = m.wrap;
    uv = bcfReduceUv(param, param_1);
    t[0] = T[0].sample(TSmplr[0], uv, level(fast::clamp(s + m.lodBias[0], 0.0, 32.0)));
    t[1] = T[1].sample(TSmplr[1], uv, level(fast::clamp(s + m.lodBias[1], 0.0, 32.0)));
    t[2] = T[2].sample(TSmplr[2], uv, level(fast::clamp(s + m.lodBias[2], 0.0, 32.0)));
    t[3] = T[3].sample(TSmplr[3], uv, level(fast::clamp(s + m.lodBias[3], 0.0, 32.0)));
    t[4] = T[4].sample(TSmplr[4], uv, level(fast::clamp(s + m.lodBias[4], 0.0, 32.0)));
}

static inline __attribute__((always_inline))
uint bcfWeightWord(thread const uint& wordIndex, const device BcfWeights& v_852)
{
    return v_852.bcfWeights[wordIndex];
}

static inline __attribute__((always_inline))
int bcfChannelCount(thread const BcfMaterial& m, const device BcfWeights& v_852)
{
    uint w0 = m.weightOffset >> 2u;
    uint param = w0 + 1u;
    uint version = bcfWeightWord(param, v_852);
    uint param_1 = w0 + 2u;
    uint ni = bcfWeightWord(param_1, v_852);
    uint param_2 = w0;
    bool _163 = bcfWeightWord(param_2, v_852) != 1464222530u;
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
        bool _178 = ni != 20u;
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
    uint nh = bcfWeightWord(param_3, v_852);
    uint param_4 = w0 + 4u;
    uint no = bcfWeightWord(param_4, v_852);
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

static inline __attribute__((always_inline))
float bcfHalf(thread const uint& base, thread const uint& e, const device BcfWeights& v_852)
{
    uint param = base + (e >> 1u);
    float2 p = float2(as_type<half2>(bcfWeightWord(param, v_852)));
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

static inline __attribute__((always_inline))
float4 bcfHalf4(thread const uint& base, thread const uint& word, const device BcfWeights& v_852)
{
    uint param = base + word;
    uint param_1 = (base + word) + 1u;
    return float4(float2(as_type<half2>(bcfWeightWord(param, v_852))), float2(as_type<half2>(bcfWeightWord(param_1, v_852))));
}

static inline __attribute__((always_inline))
int bcfDecodeFeatures(thread const BcfMaterial& m, thread const spvUnsafeArray<float4, 5>& t, thread spvUnsafeArray<float, 16>& ch, const device BcfWeights& v_852)
{
    BcfMaterial param = m;
    int count = bcfChannelCount(param, v_852);
    if (count == 0)
    {
        return 0;
    }
    uint w0 = m.weightOffset >> 2u;
    uint param_1 = w0 + 3u;
    uint nh = bcfWeightWord(param_1, v_852);
    uint param_2 = w0 + 4u;
    uint no = bcfWeightWord(param_2, v_852);
    uint base = w0 + 6u;
    uint param_3 = w0 + 2u;
    uint b1;
    spvUnsafeArray<float, 64> hid;
    if (bcfWeightWord(param_3, v_852) == 20u)
    {
        b1 = nh * 20u;
        for (uint j = 0u; j < nh; j++)
        {
            uint row = j * 10u;
            uint param_4 = base;
            uint param_5 = b1 + j;
            float a = bcfHalf(param_4, param_5, v_852);
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
            a += ((((dot(bcfHalf4(param_6, param_7, v_852), t[0]) + dot(bcfHalf4(param_8, param_9, v_852), t[1])) + dot(bcfHalf4(param_10, param_11, v_852), t[2])) + dot(bcfHalf4(param_12, param_13, v_852), t[3])) + dot(bcfHalf4(param_14, param_15, v_852), t[4]));
            hid[j] = fast::max(a, 0.0);
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
            uint param_16 = base;
            uint param_17 = b1 + j_1;
            float a_1 = bcfHalf(param_16, param_17, v_852);
            uint param_18 = base;
            uint param_19 = row_1;
            uint param_20 = base;
            uint param_21 = row_1 + 2u;
            uint param_22 = base;
            uint param_23 = row_1 + 4u;
            a_1 += ((dot(bcfHalf4(param_18, param_19, v_852), fa) + dot(bcfHalf4(param_20, param_21, v_852), fb)) + dot(bcfHalf4(param_22, param_23, v_852), fc));
            hid[j_1] = fast::max(a_1, 0.0);
        }
    }
    uint w2 = b1 + nh;
    uint b2 = w2 + (no * nh);
    uint sc = b2 + no;
    uint bi = sc + no;
    uint lg = bi + no;
    uint param_24 = w0 + 1u;
    bool hdr = bcfWeightWord(param_24, v_852) == 2u;
    int o = 0;
    float _582;
    for (uint c = 0u; c < no; c++)
    {
        uint param_25 = base;
        uint param_26 = b2 + c;
        float a_2 = bcfHalf(param_25, param_26, v_852);
        for (uint j_2 = 0u; j_2 < nh; j_2++)
        {
            uint param_27 = base;
            uint param_28 = (w2 + (c * nh)) + j_2;
            a_2 += (bcfHalf(param_27, param_28, v_852) * hid[j_2]);
        }
        uint param_29 = base;
        uint param_30 = sc + c;
        uint param_31 = base;
        uint param_32 = bi + c;
        float y = (a_2 * bcfHalf(param_29, param_30, v_852)) + bcfHalf(param_31, param_32, v_852);
        bool _555 = m.normalIndex >= 0;
        bool _573;
        if (_555)
        {
            bool _562 = int(c) == m.normalIndex;
            bool _572;
            if (!_562)
            {
                _572 = int(c) == (m.normalIndex + 1);
            }
            else
            {
                _572 = _562;
            }
            _573 = _572;
        }
        else
        {
            _573 = _555;
        }
        bool isNormal = _573;
        y = fast::clamp(y, isNormal ? (-1.0) : 0.0, 1.0);
        if (hdr)
        {
            uint param_33 = base;
            uint param_34 = lg + c;
            _582 = bcfHalf(param_33, param_34, v_852);
        }
        else
        {
            _582 = 0.0;
        }
        float g = _582;
        if (g > 0.0)
        {
            y = (exp2(g * y) - 1.0) * (1.0 / (exp2(g) - 1.0));
        }
        int _608 = o;
        o = _608 + 1;
        ch[_608] = y;
        bool _621;
        if (isNormal)
        {
            _621 = int(c) == (m.normalIndex + 1);
        }
        else
        {
            _621 = isNormal;
        }
        if (_621)
        {
            float x = ch[o - 2];
            float yy = ch[o - 1];
            int _634 = o;
            o = _634 + 1;
            ch[_634] = sqrt(fast::max(0.0, (1.0 - (x * x)) - (yy * yy)));
        }
    }
    return count;
}

static inline __attribute__((always_inline))
int bcfDecodeLod(thread const array<texture2d<float>, 5>& T, thread const array<sampler, 5>& TSmplr, thread const BcfMaterial& m, thread const float2& uv, thread const float& s, thread spvUnsafeArray<float, 16>& ch, const device BcfWeights& v_852)
{
    BcfMaterial param = m;
    float2 param_1 = uv;
    float param_2 = s;
    spvUnsafeArray<float4, 5> param_3;
    bcfSampleFeatures(T, TSmplr, param, param_1, param_2, param_3);
    spvUnsafeArray<float4, 5> t;
    t = param_3;
    BcfMaterial param_4 = m;
    spvUnsafeArray<float4, 5> param_5;
    param_5 = t;
    spvUnsafeArray<float, 16> param_6;
    int _784 = bcfDecodeFeatures(param_4, param_5, param_6, v_852);
    ch = param_6;
    return _784;
}

static inline __attribute__((always_inline))
float bcfLodFromGrad(thread const float2& duvdx, thread const float2& duvdy, thread const float2& refSize)
{
    float rho = fast::max(length(duvdx * refSize), length(duvdy * refSize));
    return log2(fast::max(rho, 9.9999996826552253889678874634872e-21));
}

static inline __attribute__((always_inline))
int bcfDecodeGrad(thread const array<texture2d<float>, 5>& T, thread const array<sampler, 5>& TSmplr, thread const BcfMaterial& m, thread const float2& uv, thread const float2& duvdx, thread const float2& duvdy, thread spvUnsafeArray<float, 16>& ch, const device BcfWeights& v_852)
{
    float2 param = duvdx;
    float2 param_1 = duvdy;
    float2 param_2 = m.refSize;
    BcfMaterial param_3 = m;
    float2 param_4 = uv;
    float param_5 = bcfLodFromGrad(param, param_1, param_2);
    spvUnsafeArray<float, 16> param_6;
    int _802 = bcfDecodeLod(T, TSmplr, param_3, param_4, param_5, param_6, v_852);
    ch = param_6;
    return _802;
}

kernel void main0(const device BcfWeights& v_852 [[buffer(0)]], const device BcfQueries& _924 [[buffer(1)]], device BcfOutput& _988 [[buffer(2)]], const device BcfParams& v_811 [[buffer(3)]], array<texture2d<float>, 5> bcfT [[texture(4)]], array<sampler, 5> bcfTSmplr [[sampler(4)]], uint3 gl_GlobalInvocationID [[thread_position_in_grid]])
{
    uint i = gl_GlobalInvocationID.x;
    if (i >= v_811.uCount)
    {
        return;
    }
    BcfMaterial m = bcfParams(v_811);
    int n;
    spvUnsafeArray<float, 16> ch;
    if (((device uint*)&v_811.uGrid)[0u] > 0u)
    {
        float2 uv = (float2(float(i % ((device uint*)&v_811.uGrid)[0u]), float(i / ((device uint*)&v_811.uGrid)[0u])) + float2(0.5)) / float2(v_811.uGrid);
        BcfMaterial param = m;
        float2 param_1 = uv;
        float param_2 = v_811.uGridLod;
        spvUnsafeArray<float, 16> param_3;
        int _911 = bcfDecodeLod(bcfT, bcfTSmplr, param, param_1, param_2, param_3, v_852);
        ch = param_3;
        n = _911;
    }
    else
    {
        if (v_811.uGradQueryWord != 0u)
        {
            float4 a = _924.bcfQueries[2u * i];
            float4 b = _924.bcfQueries[(2u * i) + 1u];
            BcfMaterial param_4 = m;
            float2 param_5 = a.xy;
            float2 param_6 = a.zw;
            float2 param_7 = b.xy;
            spvUnsafeArray<float, 16> param_8;
            int _948 = bcfDecodeGrad(bcfT, bcfTSmplr, param_4, param_5, param_6, param_7, param_8, v_852);
            ch = param_8;
            n = _948;
        }
        else
        {
            float4 q = _924.bcfQueries[i];
            BcfMaterial param_9 = m;
            float2 param_10 = q.xy;
            float param_11 = q.z;
            spvUnsafeArray<float, 16> param_12;
            int _964 = bcfDecodeLod(bcfT, bcfTSmplr, param_9, param_10, param_11, param_12, v_852);
            ch = param_12;
            n = _964;
        }
    }
    uint o = i * v_811.uOutStride;
    if (n == 0)
    {
        for (uint c = 0u; c < v_811.uOutStride; c++)
        {
            _988.bcfOut[o + c] = as_type<float>(2143289344u);
        }
        return;
    }
    int c_1 = 0;
    for (;;)
    {
        bool _1006 = c_1 < n;
        bool _1014;
        if (_1006)
        {
            _1014 = uint(c_1) < v_811.uOutStride;
        }
        else
        {
            _1014 = _1006;
        }
        if (_1014)
        {
            _988.bcfOut[o + uint(c_1)] = ch[c_1];
            c_1++;
            continue;
        }
        else
        {
            break;
        }
    }
}

