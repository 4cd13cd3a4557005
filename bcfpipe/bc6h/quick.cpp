// BC6H mode 10's quick encode, compiled: bcfpipe.bc6h.encode's algorithm with one shape refined
// (refine_top = 1), block by block in float32. The trainer's first encode of the warm features
// (model/features.py) runs it: at 2k the torch version took 15 s of a 38 s `draft`.
//
// The same steps and float32 operations as encode.py (_to_q, _pca, _shape_scores, _bracket,
// _assign, _grid_step, _refine), with its tables passed in (bcfpipe/bc6h/quick.py), so the result
// is the torch encoder's up to the order of a few float sums: tests/test_bc6h_quick.py measures
// the agreement, and the decoded error, on real features.
#include <cmath>
#include <cstdint>

namespace {

struct Tables {
    const float* u;        // (64,): every endpoint position's unquantized value
    const float* pal;      // (4096, 8): every decodable channel value, row ia * 64 + ib
    const float* w3;       // (8,): BC6H's 3-bit weights
    const int32_t* part;   // (32, 16): the two-subset shapes
    int sgn;
    float rows[16 * 64];   // rows[64 p + 2 shape + s]: 1 where texel p is in the shape's subset s
    float cnt[64];         // each subset row's texels
};

// encode.py _Ctx.nearest: the table position whose unquantized value is nearest x.
inline int nearest(float x, bool sgn) {
    if (!sgn) {
        float mid = std::nearbyint((x - 512.0f) * (1.0f / 1024.0f));
        mid = mid < 1.0f ? 1.0f : (mid > 62.0f ? 62.0f : mid);
        return x < 768.0f ? 0 : (x > 64767.5f ? 63 : int(mid));
    }
    const float a = std::fabs(x);
    float mid = std::nearbyint((a - 512.0f) * (1.0f / 1024.0f));
    mid = mid < 1.0f ? 1.0f : (mid > 30.0f ? 30.0f : mid);
    const int c = a < 768.0f ? 0 : (a > 31999.5f ? 31 : int(mid));
    return (x < 0.0f ? -c : c) + 32;
}

// encode.py _to_q of one value: (q, (d value / d q)^2).
inline void to_q(float t, bool sgn, float& q, float& om) {
    const float a = sgn ? std::fabs(t) : t;
    int ex;
    const float m = std::frexp(a, &ex);
    const float exf = float(ex);
    const bool sub = a < 6.103515625e-05f;  // 2^-14
    const float y = sub ? a * 16777216.0f : 1024.0f * (exf + 13.0f) + 2048.0f * m;
    const float slope = sub ? 5.9604644775390625e-08f : std::exp2(exf - 11.0f);
    float dq;
    if (sgn) {
        const float s = t > 0.0f ? 1.0f : (t < 0.0f ? -1.0f : 0.0f);
        q = s * (y + 0.5f) * float(32.0 / 31.0);
        dq = slope * float(31.0 / 32.0);
    } else {
        q = (y + 0.5f) * float(64.0 / 31.0);
        dq = slope * float(31.0 / 64.0);
    }
    om = dq * dq;
}

// encode.py _assign: each texel's best index for endpoints ia, ib (2, 3) and each subset's error.
inline void assign(const Tables& T, const float (*t)[3], const int (*ia)[3], const int (*ib)[3], const int32_t* member,
                   int* k, float* sub_err) {
    sub_err[0] = sub_err[1] = 0.0f;
    for (int p = 0; p < 16; ++p) {
        const int s = member[p];
        float e[8];
        for (int ch = 0; ch < 3; ++ch) {
            const float* val = T.pal + 8 * (ia[s][ch] * 64 + ib[s][ch]);
            for (int j = 0; j < 8; ++j) {
                const float d = val[j] - t[p][ch];
                e[j] = ch == 0 ? d * d : e[j] + d * d;
            }
        }
        int best = 0;
        for (int j = 1; j < 8; ++j)
            if (e[j] < e[best]) best = j;
        k[p] = best;
        sub_err[s] += e[best];
    }
}

// encode.py _grid_step for one subset and channel set: the endpoint pair per channel.
inline void grid_step(const Tables& T, const float (*qc)[3], const float* c, const float* w, const int32_t* member,
                      const int* k, int window, int (*ia_out)[3], int (*ib_out)[3]) {
    const bool sgn = T.sgn;
    for (int s = 0; s < 2; ++s) {
        float saa = 0.0f, sab = 0.0f, sbb = 0.0f, saq[3] = {0.0f, 0.0f, 0.0f}, sbq[3] = {0.0f, 0.0f, 0.0f};
        for (int p = 0; p < 16; ++p) {
            if (member[p] != s) continue;
            const float alpha = T.w3[k[p]] * (1.0f / 64.0f), a1 = 1.0f - alpha;
            const float owa = w[p] * a1, owb = w[p] * alpha;
            saa += owa * a1;
            sab += owa * alpha;
            sbb += owb * alpha;
            for (int ch = 0; ch < 3; ++ch) {
                saq[ch] += owa * qc[p][ch];
                sbq[ch] += owb * qc[p][ch];
            }
        }
        const float det = saa * sbb - sab * sab;
        const bool ok = det > 1e-6f * saa * sbb;
        const float stot = saa + 2.0f * sab + sbb;
        const bool has_b = sbb > 0.0f;
        const float inv_b = has_b ? 1.0f / sbb : 0.0f;
        for (int ch = 0; ch < 3; ++ch) {
            const float ua_c = (sbb * saq[ch] - sab * sbq[ch]) / (ok ? det : 1.0f);
            const float qbar = (saq[ch] + sbq[ch]) / (stot > 0.0f ? stot : 1.0f);
            const int centre = nearest((ok ? ua_c : qbar) + c[ch], sgn);
            int lo = centre - window;
            lo = lo < 0 ? 0 : (lo > 63 - 2 * window ? 63 - 2 * window : lo);
            float best = INFINITY;
            int best_a = lo, best_b = lo;
            for (int j = 0; j <= 2 * window; ++j) {
                const int ia = lo + j;
                const float da = T.u[ia] - c[ch];
                const float ub_opt = has_b ? (sbq[ch] - da * sab) * inv_b : da;
                const int ib = nearest(ub_opt + c[ch], sgn);
                const float db = T.u[ib] - c[ch];
                const float err = da * (saa * da + 2.0f * (sab * db - saq[ch])) + db * (sbb * db - 2.0f * sbq[ch]);
                if (err < best) {
                    best = err;
                    best_a = ia;
                    best_b = ib;
                }
            }
            ia_out[s][ch] = best_a;
            ib_out[s][ch] = best_b;
        }
    }
}

// One block: texels tin (16, 3) -> endpoints (4, 3) as table positions + lo, indices (16), shape.
void encode_block(const Tables& T, const float* tin, int rounds, int window, int64_t* e_out, int64_t* k_out,
                  int64_t* shape_out) {
    const bool sgn = T.sgn;
    const float lim = 65504.0f;
    float t[16][3], q[16][3], om[16][3];
    float om_max = 0.0f;
    for (int p = 0; p < 16; ++p)
        for (int ch = 0; ch < 3; ++ch) {
            float v = tin[3 * p + ch];
            v = v < (sgn ? -lim : 0.0f) ? (sgn ? -lim : 0.0f) : (v > lim ? lim : v);
            t[p][ch] = v;
            to_q(v, sgn, q[p][ch], om[p][ch]);
            om_max = om[p][ch] > om_max ? om[p][ch] : om_max;
        }
    for (int p = 0; p < 16; ++p)
        for (int ch = 0; ch < 3; ++ch) om[p][ch] /= om_max;
    // _pca over the 64 subset rows (2 shape + subset), centred on the block's mean
    float qm[3];
    for (int ch = 0; ch < 3; ++ch) {
        float sum = 0.0f;
        for (int p = 0; p < 16; ++p) sum += q[p][ch];
        qm[ch] = sum / 16.0f;
    }
    float qc[16][3];
    for (int p = 0; p < 16; ++p)
        for (int ch = 0; ch < 3; ++ch) qc[p][ch] = q[p][ch] - qm[ch];
    float wt[16];  // om.mean(-1)
    for (int p = 0; p < 16; ++p) wt[p] = (om[p][0] + om[p][1] + om[p][2]) / 3.0f;
    // every subset row's sums over its texels, then its statistics, 64 rows side by side (SIMD)
    float S[10][64] = {};
    for (int p = 0; p < 16; ++p) {
        const float x = qc[p][0], y = qc[p][1], z = qc[p][2];
        const float v[10] = {x, y, z, x * x, y * y, z * z, x * y, x * z, y * z, wt[p]};
        const float* in = T.rows + 64 * p;
        for (int st = 0; st < 10; ++st)
            for (int r = 0; r < 64; ++r) S[st][r] += in[r] * v[st];
    }
    float mean[3][64], ax[3][64], pmin[64], pmax[64], score_row[64];
    float proj[16][64];
    for (int r = 0; r < 64; ++r) {
        const float cnt = T.cnt[r];
        const float mx = S[0][r] / cnt, my = S[1][r] / cnt, mz = S[2][r] / cnt;
        const float cxx = S[3][r] / cnt - mx * mx, cyy = S[4][r] / cnt - my * my, czz = S[5][r] / cnt - mz * mz;
        const float cxy = S[6][r] / cnt - mx * my, cxz = S[7][r] / cnt - mx * mz, cyz = S[8][r] / cnt - my * mz;
        const bool pick0 = (cxx >= cyy) & (cxx >= czz), pick1 = !pick0 & (cyy >= czz);
        float vx = pick0 ? cxx : (pick1 ? cxy : cxz);
        float vy = pick0 ? cxy : (pick1 ? cyy : cyz);
        float vz = pick0 ? cxz : (pick1 ? cyz : czz);
        for (int it = 0; it < 3; ++it) {
            const float ax_ = std::fabs(vx), ay_ = std::fabs(vy), az_ = std::fabs(vz);
            const float m1 = ax_ > ay_ ? ax_ : ay_;
            const float n = (m1 > az_ ? m1 : az_) + 1e-30f;
            vx /= n, vy /= n, vz /= n;
            const float nx = cxx * vx + cxy * vy + cxz * vz, ny = cxy * vx + cyy * vy + cyz * vz;
            const float nz = cxz * vx + cyz * vy + czz * vz;
            vx = nx, vy = ny, vz = nz;
        }
        const float norm = std::sqrt(vx * vx + vy * vy + vz * vz);
        const bool ok = norm > 1e-20f * (std::fabs(cxx) + std::fabs(cyy) + std::fabs(czz)) + 1e-30f;
        const float r3 = 0.57735026918962573f;  // 3^-0.5
        const float den = ok ? norm : 1.0f;
        const float a0 = ok ? vx / den : r3, a1 = ok ? vy / den : r3, a2 = ok ? vz / den : r3;
        ax[0][r] = a0, ax[1][r] = a1, ax[2][r] = a2;
        mean[0][r] = mx, mean[1][r] = my, mean[2][r] = mz;
        const float along = cxx * a0 * a0 + cyy * a1 * a1 + czz * a2 * a2 +
                            2.0f * (cxy * a0 * a1 + cxz * a0 * a2 + cyz * a1 * a2);
        const float off_axis = cxx + cyy + czz - along;
        score_row[r] = off_axis < 0.0f ? 0.0f : off_axis;
        pmin[r] = INFINITY, pmax[r] = -INFINITY;
    }
    for (int p = 0; p < 16; ++p) {
        const float* in = T.rows + 64 * p;
        for (int r = 0; r < 64; ++r) {
            const float off = mean[0][r] * ax[0][r] + mean[1][r] * ax[1][r] + mean[2][r] * ax[2][r];
            const float pr = (ax[0][r] * qc[p][0] + ax[1][r] * qc[p][1] + ax[2][r] * qc[p][2]) - off;
            proj[p][r] = pr;
            const bool inside = in[r] != 0.0f;
            pmin[r] = inside & (pr < pmin[r]) ? pr : pmin[r];
            pmax[r] = inside & (pr > pmax[r]) ? pr : pmax[r];
        }
    }
    for (int r = 0; r < 64; ++r) {
        const float ext = pmax[r] - pmin[r], e2 = 0.2f * ext, wsum = S[9][r];
        score_row[r] = wsum * score_row[r] + wsum * (e2 * e2) / 12.0f;
    }
    int best_shape = 0;
    float best_score = score_row[0] + score_row[1];
    for (int shape = 1; shape < 32; ++shape) {
        const float score = score_row[2 * shape] + score_row[2 * shape + 1];
        if (score < best_score) best_score = score, best_shape = shape;
    }
    float mean_b[2][3], axis_b[2][3], pmin_b[2], pmax_b[2], proj_b[2][16];
    for (int s = 0; s < 2; ++s) {
        const int r = 2 * best_shape + s;
        for (int ch = 0; ch < 3; ++ch) mean_b[s][ch] = mean[ch][r] + qm[ch], axis_b[s][ch] = ax[ch][r];
        pmin_b[s] = pmin[r], pmax_b[s] = pmax[r];
        for (int p = 0; p < 16; ++p) proj_b[s][p] = proj[p][r];
    }
    // _refine of the chosen shape from three starts: index patterns from tau at scales 1 and 1/7,
    // and the segment's ends rounded outwards
    const int32_t* member = T.part + 16 * best_shape;
    float tau[16];
    for (int p = 0; p < 16; ++p) {
        const int s = member[p];
        const float span = pmax_b[s] - pmin_b[s];
        tau[p] = span > 0.0f ? (proj_b[s][p] - pmin_b[s]) / span : 0.5f;
    }
    constexpr int NS = 3;
    int k[NS][16], best_k[NS][16];
    float best_err[NS][2];
    int best_ia[NS][2][3], best_ib[NS][2][3];
    const float scales[2] = {7.0f, 1.0f};  // 7 s for s = 1, 1/7
    for (int j = 0; j < 2; ++j) {
        for (int p = 0; p < 16; ++p) {
            float v = std::nearbyint(3.5f + (tau[p] - 0.5f) * scales[j]);
            v = v < 0.0f ? 0.0f : (v > 7.0f ? 7.0f : v);
            k[j][p] = int(v);
        }
        best_err[j][0] = best_err[j][1] = INFINITY;
        for (int s = 0; s < 2; ++s)
            for (int ch = 0; ch < 3; ++ch) best_ia[j][s][ch] = best_ib[j][s][ch] = 0;
    }
    {  // _bracket, then _assign: the third start and its first result
        int ia0[2][3], ib0[2][3];
        for (int s = 0; s < 2; ++s)
            for (int ch = 0; ch < 3; ++ch) {
                const float ea = mean_b[s][ch] + pmin_b[s] * axis_b[s][ch];
                const float eb = mean_b[s][ch] + pmax_b[s] * axis_b[s][ch];
                int ia = nearest(ea, sgn), ib = nearest(eb, sgn);
                const float ua = T.u[ia], ub = T.u[ib];
                if (ea <= eb) {
                    ia -= ua > ea;
                    ib += ub < eb;
                } else {
                    ia += ua < ea;
                    ib -= ub > eb;
                }
                ia0[s][ch] = ia < 0 ? 0 : (ia > 63 ? 63 : ia);
                ib0[s][ch] = ib < 0 ? 0 : (ib > 63 ? 63 : ib);
            }
        assign(T, t, ia0, ib0, member, k[2], best_err[2]);
        for (int s = 0; s < 2; ++s)
            for (int ch = 0; ch < 3; ++ch) best_ia[2][s][ch] = ia0[s][ch], best_ib[2][s][ch] = ib0[s][ch];
    }
    for (int j = 0; j < NS; ++j)
        for (int p = 0; p < 16; ++p) best_k[j][p] = k[j][p];
    for (int r = 0; r < (rounds > 1 ? rounds : 1); ++r)
        for (int j = 0; j < NS; ++j) {  // _refine's offset c and q - c are _pca's qm and qc
            int ia[2][3], ib[2][3];
            float sub_err[2];
            grid_step(T, qc, qm, wt, member, k[j], window, ia, ib);
            assign(T, t, ia, ib, member, k[j], sub_err);
            bool better[2];
            for (int s = 0; s < 2; ++s) {
                better[s] = sub_err[s] < best_err[j][s];
                if (better[s]) {
                    best_err[j][s] = sub_err[s];
                    for (int ch = 0; ch < 3; ++ch) best_ia[j][s][ch] = ia[s][ch], best_ib[j][s][ch] = ib[s][ch];
                }
            }
            for (int p = 0; p < 16; ++p)
                if (better[member[p]]) best_k[j][p] = k[j][p];
        }
    // per subset the start with the lowest error (ties: the first)
    int pick[2];
    for (int s = 0; s < 2; ++s) {
        pick[s] = 0;
        for (int j = 1; j < NS; ++j)
            if (best_err[j][s] < best_err[pick[s]][s]) pick[s] = j;
    }
    const int lo = sgn ? -32 : 0;
    for (int s = 0; s < 2; ++s)
        for (int ch = 0; ch < 3; ++ch) {
            e_out[(2 * s) * 3 + ch] = best_ia[pick[s]][s][ch] + lo;
            e_out[(2 * s + 1) * 3 + ch] = best_ib[pick[s]][s][ch] + lo;
        }
    for (int p = 0; p < 16; ++p) k_out[p] = best_k[pick[member[p]]][p];
    *shape_out = best_shape;
}

}  // namespace

extern "C" {

// Blocks [0, n) of texels (n, 16, 3) -> endpoints (n, 4, 3), indices (n, 16), shapes (n,).
void bcf_bc6h_quick(const float* texels, int64_t n, int sgn, int rounds, int window, const float* u, const float* pal,
                    const float* w3, const int32_t* part, int64_t* endpoints, int64_t* indices, int64_t* shapes) {
    Tables T{u, pal, w3, part, sgn, {}, {}};
    for (int r = 0; r < 64; ++r) {
        T.cnt[r] = 0.0f;
        for (int p = 0; p < 16; ++p) {
            T.rows[64 * p + r] = part[16 * (r / 2) + p] == r % 2 ? 1.0f : 0.0f;
            T.cnt[r] += T.rows[64 * p + r];
        }
    }
    for (int64_t b = 0; b < n; ++b)
        encode_block(T, texels + 48 * b, rounds, window, endpoints + 12 * b, indices + 16 * b, shapes + b);
}

}  // extern "C"
