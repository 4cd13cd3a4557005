// The fused path's training targets (targets.py), vectorised across samples like step.cpp: the
// reference's bicubic lookup at continuous uv, and the precomputed texel-centre targets.
#include <cmath>
#include <cstdint>

#include "lanes.h"

using namespace bcf;

namespace {

// Cubic-convolution (Keys) weights of the taps at -1, 0, 1, 2 for fraction f (reference.keys_weights).
inline void keys(vf f, float a, vf* w) {
    vf f2 = f * f, f3 = f2 * f;
    w[0] = a * (f3 - 2.0f * f2 + f);
    w[1] = (a + 2.0f) * f3 - (a + 3.0f) * f2 + 1.0f;
    w[2] = -(a + 2.0f) * f3 + (2.0f * a + 3.0f) * f2 - a * f;
    w[3] = a * (f2 - f3);
}

}  // namespace

extern "C" {

// out (n, c) = bicubic(tex (c, h, w), uv (n, 2)) when t < 0, else lerp(out, bicubic, t): the
// numba kernel's sums in its order (rows of taps, then the column).
void bcf_bicubic(const float* tex, int c, int h, int w, const float* uv, int64_t n, int wrap, float a,
                 float t, float* out) {
    const int64_t plane = int64_t(h) * w;
    for (int64_t n0 = 0; n0 < n; n0 += W) {
        const int live = int(n - n0 < W ? n - n0 : W);
        const vi idx = lanes(n0, live);
        vf x = gather(uv, idx * 2) * float(w) - 0.5f;
        vf y = gather(uv, idx * 2 + 1) * float(h) - 0.5f;
        vf x0 = vfloor(x), y0 = vfloor(y);
        vf wx[4], wy[4];
        keys(x - x0, a, wx);
        keys(y - y0, a, wy);
        vi xs[4], rows[4];
        for (int k = 0; k < 4; ++k) {
            xs[k] = address(toi(x0) - 1 + k, w, wrap & 3);
            rows[k] = address(toi(y0) - 1 + k, h, (wrap >> 2) & 3) * w;
        }
        for (int ch = 0; ch < c; ++ch) {
            const float* p = tex + ch * plane;
            vf acc = S(0.0f);
            for (int ky = 0; ky < 4; ++ky) {
                vf row = S(0.0f);
                for (int kx = 0; kx < 4; ++kx) row += gather(p, rows[ky] + xs[kx]) * wx[kx];
                acc += row * wy[ky];
            }
            for (int l = 0; l < live; ++l) {
                float* o = out + (n0 + l) * c + ch;
                *o = t >= 0.0f ? *o + t * (acc[l] - *o) : acc[l];
            }
        }
    }
}

// Texel-centre targets (reference.CentreTargets.batch): uv (n, 2) of flat texel ids of an h x w
// mip, and target (n, c) = lerp(mip (c, h w), up (c, h w), t) as torch.lerp computes it on the CPU.
void bcf_centres(const float* mip, const float* up, int c, int h, int w, const int64_t* ids, int64_t n, float t,
                 float* uv, float* target) {
    const int64_t plane = int64_t(h) * w;
    constexpr int64_t AHEAD = 16;  // as bcf_centre_rows, one line per plane
    for (int64_t k = 0; k < n; ++k) {
        if (k + AHEAD < n) {
            const int64_t next = ids[k + AHEAD];
            for (int ch = 0; ch < c; ++ch) {
                __builtin_prefetch(mip + ch * plane + next);
                if (t > 0.0f) __builtin_prefetch(up + ch * plane + next);
            }
        }
        const int64_t id = ids[k];
        uv[2 * k] = (float(id % w) + 0.5f) / float(w);
        uv[2 * k + 1] = (float(id / w) + 0.5f) / float(h);
        for (int ch = 0; ch < c; ++ch) {
            float a = mip[ch * plane + id];
            if (t > 0.0f) {
                float b = up[ch * plane + id];
                a = t < 0.5f ? std::fma(t, b - a, a) : std::fma(-(b - a), 1.0f - t, b);  // ATen's vectorised lerp
            }
            target[k * c + ch] = a;
        }
    }
}

// The same from a level kept texel by texel (CentreTargets.texels): rows (h w, 2 c) = [mip | up].
void bcf_centre_rows(const float* rows, int c, int h, int w, const int64_t* ids, int64_t n, float t, float* uv,
                     float* target) {
    // the ids are sorted but sparse: each row misses the caches, so it is requested AHEAD rows early
    constexpr int64_t AHEAD = 16;
    for (int64_t k = 0; k < n; ++k) {
        if (k + AHEAD < n) {
            const float* next = rows + ids[k + AHEAD] * 2 * c;
            __builtin_prefetch(next);
            __builtin_prefetch(next + 2 * c - 1);
        }
        const int64_t id = ids[k];
        const float* r = rows + id * 2 * c;
        uv[2 * k] = (float(id % w) + 0.5f) / float(w);
        uv[2 * k + 1] = (float(id / w) + 0.5f) / float(h);
        for (int ch = 0; ch < c; ++ch) {
            float a = r[ch];
            if (t > 0.0f) {
                float b = r[c + ch];
                a = t < 0.5f ? std::fma(t, b - a, a) : std::fma(-(b - a), 1.0f - t, b);  // ATen's vectorised lerp
            }
            target[k * c + ch] = a;
        }
    }
}

}  // extern "C"
