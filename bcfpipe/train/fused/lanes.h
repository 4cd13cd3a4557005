// Lanes: W samples at once in GCC's vector types, for step.cpp and targets.cpp. The few operations
// that have no operator (rounding, gathers) use the target's intrinsics, or per-lane loops elsewhere.
#pragma once
#include <cmath>
#include <cstdint>

#if defined(__AVX2__) || defined(__AVX512F__)
#include <immintrin.h>
#endif

namespace bcf {
#if defined(__AVX512F__)
constexpr int W = 16;
#elif defined(__AVX2__)
constexpr int W = 8;
#else
constexpr int W = 4;
#endif
typedef float vf __attribute__((vector_size(4 * W)));
typedef int32_t vi __attribute__((vector_size(4 * W)));

inline vf S(float x) { return vf{} + x; }
inline vi Si(int32_t x) { return vi{} + x; }
inline vf sel(vi m, vf a, vf b) { return m ? a : b; }
inline vi seli(vi m, vi a, vi b) { return m ? a : b; }
inline vf tof(vi x) { return __builtin_convertvector(x, vf); }
inline vi toi(vf x) { return __builtin_convertvector(x, vi); }  // truncates, as int(x)
inline vf bits_f(vi x) { return (vf)x; }  // a vector cast reinterprets the bits
inline vi bits_i(vf x) { return (vi)x; }
inline vf vabs(vf x) { return bits_f(bits_i(x) & Si(0x7fffffff)); }
// Python's max(v, lo) and min(v, hi), whose ties keep the first argument
inline vf vmax(vf v, vf lo) { return sel(lo > v, lo, v); }
inline vf vmin(vf v, vf hi) { return sel(hi < v, hi, v); }
inline vf vclamp(vf v, float lo, float hi) { return vmin(vmax(v, S(lo)), S(hi)); }
inline vi vmaxi(vi a, vi b) { return seli(b > a, b, a); }
inline vi vmini(vi a, vi b) { return seli(b < a, b, a); }
inline vf one_if(vi m) { return sel(m, S(1.0f), S(0.0f)); }

#if defined(__AVX512F__)
inline vf vfloor(vf x) { return (vf)_mm512_roundscale_ps((__m512)x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
inline vf vrint(vf x) { return (vf)_mm512_roundscale_ps((__m512)x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); }
inline vf vtrunc(vf x) { return (vf)_mm512_roundscale_ps((__m512)x, _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC); }
inline vf gather(const float* base, vi idx) { return (vf)_mm512_i32gather_ps((__m512i)idx, base, 4); }
inline vi gatheri(const int32_t* base, vi idx) { return (vi)_mm512_i32gather_epi32((__m512i)idx, base, 4); }
#elif defined(__AVX2__)
inline vf vfloor(vf x) { return (vf)_mm256_round_ps((__m256)x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
inline vf vrint(vf x) { return (vf)_mm256_round_ps((__m256)x, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); }
inline vf vtrunc(vf x) { return (vf)_mm256_round_ps((__m256)x, _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC); }
inline vf gather(const float* base, vi idx) { return (vf)_mm256_i32gather_ps(base, (__m256i)idx, 4); }
inline vi gatheri(const int32_t* base, vi idx) { return (vi)_mm256_i32gather_epi32((const int*)base, (__m256i)idx, 4); }
#endif

// base[idx] and base[idx + 1] for even idx: one 64-bit gather per 8 lanes, where AVX-512 has it,
// then the pairs split (half the gathered elements of two float gathers)
#if defined(__AVX512F__)
inline void gather_pair(const float* base, vi idx, vf& first, vf& second) {
    const __m512i i2 = (__m512i)(idx >> 1);
    const __m512d lo = _mm512_i32gather_pd(_mm512_castsi512_si256(i2), (const double*)base, 8);
    const __m512d hi = _mm512_i32gather_pd(_mm512_extracti64x4_epi64(i2, 1), (const double*)base, 8);
    const vi even = {0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30};
    first = (vf)_mm512_permutex2var_ps(_mm512_castpd_ps(lo), (__m512i)even, _mm512_castpd_ps(hi));
    second = (vf)_mm512_permutex2var_ps(_mm512_castpd_ps(lo), (__m512i)(even + 1), _mm512_castpd_ps(hi));
}
#else
inline void gather_pair(const float* base, vi idx, vf& first, vf& second) {
    first = gather(base, idx);
    second = gather(base, idx + 1);
}
#endif

// a * b + c: one rounding where the target fuses it (the MLP only: the decode stays unfused, as torch's)
#if defined(__AVX512F__)
inline vf madd(vf a, vf b, vf c) { return (vf)_mm512_fmadd_ps((__m512)a, (__m512)b, (__m512)c); }
#elif defined(__AVX2__) && defined(__FMA__)
inline vf madd(vf a, vf b, vf c) { return (vf)_mm256_fmadd_ps((__m256)a, (__m256)b, (__m256)c); }
#else
inline vf madd(vf a, vf b, vf c) { return a * b + c; }
#endif

#if !defined(__AVX512F__) && !defined(__AVX2__)
inline vf vfloor(vf x) { vf r; for (int l = 0; l < W; ++l) r[l] = std::floor(x[l]); return r; }
inline vf vrint(vf x) { vf r; for (int l = 0; l < W; ++l) r[l] = std::rint(x[l]); return r; }
inline vf vtrunc(vf x) { vf r; for (int l = 0; l < W; ++l) r[l] = std::trunc(x[l]); return r; }
inline vf gather(const float* base, vi idx) { vf r; for (int l = 0; l < W; ++l) r[l] = base[idx[l]]; return r; }
inline vi gatheri(const int32_t* base, vi idx) { vi r; for (int l = 0; l < W; ++l) r[l] = base[idx[l]]; return r; }
#endif

// Whether any lane of the mask m is set.
#if defined(__AVX512F__)
inline bool any(vi m) { return _mm512_test_epi32_mask((__m512i)m, (__m512i)m) != 0; }
#elif defined(__AVX2__)
inline bool any(vi m) { return _mm256_movemask_ps((__m256)m) != 0; }
#else
inline bool any(vi m) { for (int l = 0; l < W; ++l) if (m[l]) return true; return false; }
#endif

// Texel i of n along an axis: wrapped (Python's modulo) or clamped to the edge. A training's i lies
// in [-n, 2n) (the decode wraps uv into [0, 1] first; the bicubic's taps of uv in [0, 1) reach one
// texel further), where the modulo is one conditional add or subtract. A vector modulo has no
// instruction: it became 16 integer divisions per call, about a sixth of the decode's time. When
// any lane lies outside, all take the modulo.
// Mirror (mode 2, GL_MIRRORED_REPEAT): i modulo 2n, then 2n - 1 - j for j >= n. mode is one axis's
// code (common.py: 0 repeat, 1 clamp, 2 mirror).
inline vi address(vi i, int n, int mode) {
    if (mode == 0) {
        if (__builtin_expect(any((i < -n) | (i >= 2 * n)), 0)) {
            vi m = i % n;
            return seli(m < 0, m + n, m);  // Python's modulo
        }
        return seli(i < 0, i + n, seli(i >= n, i - n, i));
    }
    if (mode == 2) {
        const int p = 2 * n;
        vi j;
        if (__builtin_expect(any((i < -p) | (i >= 2 * p)), 0)) {
            vi m = i % p;
            j = seli(m < 0, m + p, m);
        } else {
            j = seli(i < 0, i + p, seli(i >= p, i - p, i));
        }
        return seli(j >= n, (p - 1) - j, j);
    }
    return vmini(vmaxi(i, Si(0)), Si(n - 1));
}

// One coordinate range-reduced for its axis's mode (sampling.reduce_coord): x - floor(x) for repeat,
// x - 2 floor(x / 2) for mirror (both exact), x clamped to [-1, 2] for clamp.
inline vf reduce(vf x, int mode) {
    if (mode == 0) return x - vfloor(x);
    if (mode == 2) return x - 2.0f * vfloor(x * 0.5f);
    return vclamp(x, -1.0f, 2.0f);
}

inline float hsum(vf x) {
    float acc = 0.0f;
    for (int l = 0; l < W; ++l) acc += x[l];
    return acc;
}

// The lanes of samples n0 .. n0 + live - 1; padding lanes repeat n0.
inline vi lanes(int64_t n0, int live) {
    vi idx;
    for (int l = 0; l < W; ++l) idx[l] = int32_t(l < live ? n0 + l : n0);
    return idx;
}

}  // namespace bcf
