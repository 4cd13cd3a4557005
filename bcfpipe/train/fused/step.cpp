// The fused training step in C++, vectorised across samples (issue 30): the same operations as
// kernel.py's numba kernel, in the same float32 order, so the decoded features are bit-identical
// to the torch emulation; lanes of W samples run each stage together, so the compiler turns the
// per-tap decode into SIMD (gathers for the block reads, masks for the branches).
//
// Built by native.py with -ffp-contract=off (no fused multiply-adds: each product and sum is
// rounded as torch rounds it) and no fast-math. Gradients are scattered lane by lane, in a fixed
// order: one chunk's result never depends on scheduling.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "lanes.h"

using namespace bcf;

namespace {

constexpr int FREE_BC6H = 0, FREE_BC7 = 1, BLOCK_BC6H = 2, BLOCK_BC7 = 3;
// A slot's first field: inactive, a trained level, or a fixed level (UNORM8 texel values, BC7 only).
constexpr int64_t INACTIVE = 0, TRAINED = 1, FIXED = 2;
constexpr int ND = 15;  // decode derivatives kept per tap (kernel.py's deriv layout)
// Layers a model may have (step.py's MAX_LAYERS): T_0's one to three, then T_1..T_3; two slots each.
constexpr int MAX_LAYERS = 8, MAX_SLOTS = 2 * MAX_LAYERS;
const float SNAP6 = float(7.0 * 1e-4);  // bc6h.emulate's snap, as kernel.py's np.float32(7.0 * 1e-4)
const float SNAP7 = float(1e-4 * 15);   // bc7.emulate's

// 2^e as a float32, exactly, for -126 <= e <= 127 (kernel.py's _POW2 table)
inline vf pow2(vi e) { return bits_f((e + 127) << 23); }

// The value of the IEEE half whose bits are the integer-valued float32 f (0 <= f <= 31743).
inline vf half_value(vf f) {
    vi b = toi(f);
    vi e = b >> 10, m = b & 1023;
    return sel(e == 0, tof(m) * pow2(Si(-24)), tof(m + 1024) * pow2(e - 25));
}

// bc6h.emulate's table of every 6-bit endpoint's unquantized value (mode10.unquantize_table: the
// spec's ((e << 16) + 0x8000) >> 6, sign-magnitude when signed, saturating at the ends) and its
// slope to the next entry, as arithmetic for k = the endpoint's offset from the lowest, 0..62.
// test_fused's random endpoints span every entry, signed and unsigned, against the torch tables.
inline void unquantize_entry(vi k, bool sgn, vf& value, vf& slope) {
    if (!sgn) {
        value = sel(k == 0, S(0.0f), tof(k * 1024 + 512));
        slope = sel(k == 0, S(1536.0f), sel(k == 62, S(1535.0f), S(1024.0f)));
    } else {
        vi e = k - 32;
        vi mag = seli(e < 0, -e, e) * 1024 + 512;
        value = sel(e <= -31, S(-32767.0f), sel(e == 0, S(0.0f), tof(seli(e < 0, -mag, mag))));
        slope = sel(k == 0, S(0.0f), sel((k == 1) | (k == 62), S(1535.0f),
                                         sel((k == 31) | (k == 32), S(1536.0f), S(1024.0f))));
    }
}

// bc6h.emulate's unquantize of a continuous endpoint and its derivative (kernel.py _unquantize).
inline void unquantize(vf e, bool sgn, bool quantized, vf& u, vf& du) {
    const float lo = sgn ? -32.0f : 0.0f, hi = lo + 63.0f;
    vf pos = vclamp(e, lo, hi);
    vf inside = one_if(pos == e);
    if (quantized) pos = pos + (vrint(pos) - pos);
    pos = pos - lo;
    vf k0 = vmin(vmax(vfloor(pos), S(0.0f)), S(62.0f));
    vf value, sl;
    unquantize_entry(toi(k0), sgn, value, sl);
    u = value + (pos - k0) * sl;
    du = sl * inside;
}

// bc6h.emulate's index_weight of a continuous index and d/dx (kernel.py _weight3); the 3-bit
// weights (0, 9, 18, 27, 37, 46, 55, 64: BC6H's table) are 9 k + (k >= 4), slope 10 at k = 3.
inline void weight3(vf x, bool quantized, vf& w, vf& dw) {
    vf t = vclamp(x, 0.0f, 1.0f);
    vf inside = one_if(t == x);
    t = t * 7.0f;
    vf d = vrint(t) - t;
    t = quantized ? t + d : sel(vabs(d) < SNAP6, t + d, t);
    vf k0 = vmin(vmax(vfloor(t), S(0.0f)), S(6.0f));
    vi k = toi(k0);
    vf sl = sel(k == 3, S(10.0f), S(9.0f));
    w = tof(k * 9 + seli(k >= 4, Si(1), Si(0))) + (t - k0) * sl;
    dw = sl * inside * 7.0f;
}

// bc7.emulate's weight of a continuous index: (w, dw without the clamp's mask, the mask).
inline void weight4(vf x, bool quantized, vf& w, vf& dw, vf& inside) {
    vf xc = vclamp(x, 0.0f, 1.0f);
    inside = one_if(xc == x);
    if (quantized) xc = vrint(xc * 15.0f) / 15.0f;
    vf t = vclamp(xc, 0.0f, 1.0f) * 15.0f;
    vf nearest = vrint(t);
    t = sel(vabs(t - nearest) < SNAP7, nearest, t);
    vf k = vmin(vfloor(t), S(14.0f));
    vf lo = vfloor((64.0f * k + 7.0f) / 15.0f);
    vf hi = vfloor((64.0f * (k + 1.0f) + 7.0f) / 15.0f);
    vf step = hi - lo;
    w = lo + (t - k) * step;
    dw = step * 15.0f;
}

// bc7.emulate.quantize_endpoints of one clamped endpoint (4 channels), in place (kernel.py _q7).
inline void q7(vf* e) {
    vf q0[4], q1[4], err0 = S(0.0f), err1 = S(0.0f);
    for (int c = 0; c < 4; ++c) {
        vf v = e[c];
        q0[c] = vclamp(2.0f * vfloor((v - 0.0f) / 2.0f + 0.5f) + 0.0f, 0.0f, 254.0f);
        q1[c] = vclamp(2.0f * vfloor((v - 1.0f) / 2.0f + 0.5f) + 1.0f, 1.0f, 255.0f);
        err0 += (q0[c] - v) * (q0[c] - v);
        err1 += (q1[c] - v) * (q1[c] - v);
    }
    vi pick = err1 < err0;
    for (int c = 0; c < 4; ++c) e[c] = sel(pick, q1[c], q0[c]);
}


struct Args {  // mirrored by native.py's ctypes Structure
    int32_t fmt, quantized, sgn, wrap, C, n_in, hidden, n_out;  // n_in / C layers; wrap: S | T << 2 (common.py)
    int64_t a, b;
    const float *uv, *target, *weight;  // weight: null when unweighted
    const float *P, *X;
    const int32_t* M;      // BC6H: each block's subset mask, bit p for texel p
    const int64_t* slots;  // (2 layers, 6): active, size, po, xo, mo, plane
    const float* blend;    // (layers,)
    float plo, phi, loss_scale, pad_;
    const float *w1, *b1, *w2, *b2, *out_scale, *out_bias;  // w1 (hidden, n_in), w2 (n_out, hidden)
    float *gP, *gX, *gw1, *gb1, *gw2, *gb2;  // this chunk's gradient rows
    float* feats_out;                        // features() only: (b - a, n_in)
};

// One lane group's taps in every active slot (2 i + level), and what their backward needs.
struct Taps {
    vi blk[MAX_SLOTS][4], pos[MAX_SLOTS][4];
    vf fx[MAX_SLOTS], fy[MAX_SLOTS];
    vf deriv[MAX_SLOTS][4][ND];
};

// Decode tap t of slot j into val[c], keeping its derivatives (kernel.py _texel). The format F,
// quantization-awareness q and signedness sgn are compile-time (one instantiation per case that
// a training runs: no per-tap branches on them).
template <int F, bool q, bool sgn>
inline void texel(const Args& A, int j, int t, Taps& T, vf* val) {
    const int64_t* s = A.slots + 6 * j;
    const int64_t po = s[2], xo = s[3], mo = s[4], plane = s[5];
    const int C = A.C;
    const vi blk = T.blk[j][t], pos = T.pos[j][t];
    vf* d = T.deriv[j][t];
    (void)mo, (void)plane, (void)C;
    if constexpr (F == FREE_BC7) {
        for (int c = 0; c < C; ++c) {
            vf v = gather(A.P + po + c * plane, blk);
            vf vc = vclamp(v, A.plo, A.phi);
            val[c] = vc / 255.0f;
            d[c] = sel(vc == v, S(1.0f / 255.0f), S(0.0f));
        }
    } else if constexpr (F == FREE_BC6H) {
        const float scale = sgn ? 31.0f / 32.0f : 31.0f / 64.0f;
        for (int c = 0; c < C; ++c) {
            vf v = gather(A.P + po + c * plane, blk);
            vf vc = vclamp(v, A.plo, A.phi);
            vf inside = one_if(vc == v);
            vf u, du;
            unquantize(vc, sgn, false, u, du);
            vf y = u * scale;
            vf h = vmax(vfloor(vabs(y) / 1024.0f) - 1.0f, S(0.0f));
            vf sg = sel(y == 0.0f, S(0.0f), sel(y > 0.0f, S(1.0f), S(-1.0f)));
            vf e2 = pow2(toi(h) - 14);
            val[c] = e2 * (y / 1024.0f - sg * h);
            d[c] = e2 / 1024.0f * scale * du * inside;
        }
    } else if constexpr (F == BLOCK_BC6H) {
        const vi sub = (gatheri(A.M + (mo >> 4), blk) >> pos) & 1;
        vf w, dw;
        weight3(gather(A.X + xo, blk * 16 + pos), q, w, dw);
        const vi ea = blk * 12 + sub * 6;  // the subset's endpoints a, b: 6 floats from an even offset
        vf e[6];
        gather_pair(A.P + po, ea, e[0], e[1]);
        gather_pair(A.P + po, ea + 2, e[2], e[3]);
        gather_pair(A.P + po, ea + 4, e[4], e[5]);
        for (int c = 0; c < 3; ++c) {
            vf ua, dua, ub, dub;
            unquantize(e[c], sgn, q, ua, dua);
            unquantize(e[3 + c], sgn, q, ub, dub);
            vf f = ua * (64.0f - w) + ub * w;
            f = vfloor((f + 32.0f) / 64.0f);
            f = sgn ? vtrunc(f * (31.0f / 32.0f)) + 0.0f : vfloor(f * (31.0f / 64.0f));
            vf af = vabs(f);
            vf v = half_value(af);
            val[c] = sel(f < 0.0f, -v, v);
            d[c] = pow2(vmaxi(toi(af) >> 10, Si(1)) - 15);
            d[3 + c] = ub - ua;
            d[6 + c] = dua;
            d[9 + c] = dub;
        }
        d[12] = w;
        d[13] = dw;
        d[14] = tof(sub);
    } else {  // BLOCK_BC7
        const float* P = A.P + po;
        const vi e0 = blk * 8;
        vf e[2][4];
        vf raw[8];
        for (int k = 0; k < 8; k += 2) gather_pair(P, e0 + k, raw[k], raw[k + 1]);
        for (int k = 0; k < 2; ++k)
            for (int c = 0; c < 4; ++c) {
                vf v = raw[4 * k + c];
                vf vc = vclamp(v, 0.0f, 255.0f);
                d[4 + 4 * k + c] = one_if(vc == v);
                e[k][c] = vc;
            }
        if constexpr (q) {
            q7(e[0]);
            q7(e[1]);
        }
        vf w, dw, inside;
        weight4(gather(A.X + xo, blk * 16 + pos), q, w, dw, inside);
        for (int c = 0; c < 4; ++c) {
            vf ea = e[0][c];
            vf dd = e[1][c] - ea;
            val[c] = vfloor((w * dd + (64.0f * ea + 32.0f)) / 64.0f) / 255.0f;
            d[c] = dd;
        }
        d[12] = w;
        d[13] = q ? dw : dw * inside;
    }
}

// The features feats[k] of the lane group whose samples are idx (kernel.py _features).
template <int F, bool q, bool sgn>
void features(const Args& A, vi idx, Taps& T, vf* feats) {
    const int C = A.C;
    const int ws = A.wrap & 3, wt = (A.wrap >> 2) & 3;
    constexpr bool free_ = F == FREE_BC6H || F == FREE_BC7;
    const vf u0 = gather(A.uv, idx * 2), v0 = gather(A.uv, idx * 2 + 1);
    vf val[4][4], lvl[2][4];
    const int layers = A.n_in / C;
    for (int i = 0; i < layers; ++i) {
        for (int lv = 0; lv < 2; ++lv) {
            const int j = 2 * i + lv;
            const int64_t* s = A.slots + 6 * j;
            if (s[0] == 0) continue;
            const int r = int(s[1]);
            vf u = u0, v = v0;
            u = reduce(u, ws);
            v = reduce(v, wt);
            vf xf = u * float(r) - 0.5f, yf = v * float(r) - 0.5f;
            vf x0 = vfloor(xf), y0 = vfloor(yf);
            T.fx[j] = xf - x0;
            T.fy[j] = yf - y0;
            vi xa = address(toi(x0), r, ws), xb = address(toi(x0) + 1, r, ws);
            vi ya = address(toi(y0), r, wt), yb = address(toi(y0) + 1, r, wt);
            const bool fixed = s[0] == FIXED;
            for (int t = 0; t < 4; ++t) {
                vi ty = t < 2 ? ya : yb, tx = (t & 1) ? xb : xa;
                if (free_ || fixed) {
                    T.blk[j][t] = ty * r + tx;
                    T.pos[j][t] = Si(0);
                } else {
                    T.blk[j][t] = (ty >> 2) * (r >> 2) + (tx >> 2);
                    T.pos[j][t] = (ty & 3) * 4 + (tx & 3);
                }
                if (fixed) {  // a level written as encoded (UNORM8 values): no parameters, no gradient
                    for (int c = 0; c < C; ++c) val[t][c] = gather(A.P + s[2] + c * s[5], T.blk[j][t]) / 255.0f;
                } else {
                    texel<F, q, sgn>(A, j, t, T, val[t]);
                }
            }
            const vf fx = T.fx[j], fy = T.fy[j];
            for (int c = 0; c < C; ++c) {
                vf top = val[0][c] + (val[1][c] - val[0][c]) * fx;
                vf bot = val[2][c] + (val[3][c] - val[2][c]) * fx;
                lvl[lv][c] = top + (bot - top) * fy;
            }
        }
        const bool hi = A.slots[6 * (2 * i + 1)] != 0;
        for (int c = 0; c < C; ++c) {
            vf f = lvl[0][c];
            if (hi) f = f + (lvl[1][c] - f) * A.blend[i];
            feats[C * i + c] = f;
        }
    }
}

// Add the gradient g[c] of tap t of slot j into the chunk's rows, lane by lane in order
// (kernel.py _texel_backward); lanes at or past `live` are padding.
template <int F, bool sgn>
inline void texel_backward(const Args& A, int j, int t, const Taps& T, const vf* g, int live) {
    const int64_t* s = A.slots + 6 * j;
    const int64_t po = s[2], xo = s[3], plane = s[5];
    const int C = A.C;
    const vi blk = T.blk[j][t], pos = T.pos[j][t];
    const vf* d = T.deriv[j][t];
    float* gP = A.gP + po;
    float* gX = A.gX + xo;
    (void)plane, (void)C;
    if constexpr (F == FREE_BC7 || F == FREE_BC6H) {
        vf add[4];
        for (int c = 0; c < C; ++c) add[c] = g[c] * d[c];
        for (int l = 0; l < live; ++l)
            for (int c = 0; c < C; ++c) gP[c * plane + blk[l]] += add[c][l];
    } else if constexpr (F == BLOCK_BC6H) {
        const float k = float((sgn ? 31.0 / 32.0 : 31.0 / 64.0) * std::ldexp(1.0, -16));
        const vf w = d[12];
        vf ga[3], gb[3], acc = S(0.0f);
        for (int c = 0; c < 3; ++c) {
            vf gq = g[c] * d[c];
            acc += d[3 + c] * gq;
            ga[c] = (64.0f - w) * gq * d[6 + c] * k;
            gb[c] = w * gq * d[9 + c] * k;
        }
        const vf gx = acc * d[13] * k;
        const vi ea = blk * 12 + toi(d[14]) * 6, xi = blk * 16 + pos;
        for (int l = 0; l < live; ++l) {
            float* e = gP + ea[l];
            for (int c = 0; c < 3; ++c) {
                e[c] += ga[c][l];
                e[3 + c] += gb[c][l];
            }
            gX[xi[l]] += gx[l];
        }
    } else {
        const float sc = float(1.0 / (64.0 * 255.0));
        const vf w = d[12];
        vf ga[4], gb[4], acc = S(0.0f);
        for (int c = 0; c < 4; ++c) {
            acc += g[c] * d[c];
            ga[c] = (64.0f - w) * g[c] * sc * d[4 + c];
            gb[c] = w * g[c] * sc * d[8 + c];
        }
        const vf gx = acc * sc * d[13];
        const vi e0 = blk * 8, xi = blk * 16 + pos;
        for (int l = 0; l < live; ++l) {
            float* e = gP + e0[l];
            for (int c = 0; c < 4; ++c) {
                e[c] += ga[c][l];
                e[4 + c] += gb[c][l];
            }
            gX[xi[l]] += gx[l];
        }
    }
}

// Samples [a, b): forward, loss and backward; gradients added into the chunk's rows; returns the
// sum of the (weighted) squared errors.
template <int F, bool q, bool sgn>
double step(const Args& A) {
    const int C = A.C, NI = A.n_in, H = A.hidden, NO = A.n_out;
    std::vector<vf> buf(size_t(NI) * 2 + size_t(H) * 3 + size_t(NO) + size_t(H) * NI + size_t(NO) * H + H + NO, S(0.0f));
    vf* p = buf.data();
    auto take = [&](size_t n) { vf* r = p; p += n; return r; };
    vf *feats = take(NI), *dfe = take(NI), *pre = take(H), *hid = take(H), *dh = take(H), *dout = take(NO);
    vf *gw1 = take(size_t(H) * NI), *gw2 = take(size_t(NO) * H), *gb1 = take(H), *gb2 = take(NO);  // per lane
    Taps T;
    double sse = 0.0;
    for (int64_t n0 = A.a; n0 < A.b; n0 += W) {
        const int live = int(std::min<int64_t>(W, A.b - n0));
        const vi idx = lanes(n0, live);
        features<F, q, sgn>(A, idx, T, feats);
        for (int h = 0; h < H; ++h) {
            const float* wr = A.w1 + size_t(h) * NI;
            vf acc = S(0.0f);
            for (int k = 0; k < NI; ++k) acc = madd(feats[k], S(wr[k]), acc);
            acc += A.b1[h];
            pre[h] = acc;
            hid[h] = sel(acc > 0.0f, acc, S(0.0f));
        }
        vf wn = A.weight ? gather(A.weight, idx) : S(1.0f);
        wn = sel(lanes(0, W) < live, wn, S(0.0f));
        const vf w2x = wn * (2.0f * A.loss_scale);
        vf e = S(0.0f);
        for (int o = 0; o < NO; ++o) {
            const float* wr = A.w2 + size_t(o) * H;
            vf acc = S(0.0f);
            for (int h = 0; h < H; ++h) acc = madd(hid[h], S(wr[h]), acc);
            acc += A.b2[o];
            vf dd = (acc * A.out_scale[o] + A.out_bias[o]) - gather(A.target, idx * NO + o);
            e += wn * dd * dd;
            dout[o] = w2x * dd * A.out_scale[o];
        }
        sse += double(hsum(e));
        // back through the MLP (per-lane gradient sums), and the inputs' gradient
        for (int o = 0; o < NO; ++o) {
            gb2[o] += dout[o];
            for (int h = 0; h < H; ++h) gw2[o * H + h] = madd(dout[o], hid[h], gw2[o * H + h]);
        }
        for (int h = 0; h < H; ++h) {
            vf acc = S(0.0f);
            for (int o = 0; o < NO; ++o) acc = madd(dout[o], S(A.w2[o * H + h]), acc);
            dh[h] = sel(pre[h] > 0.0f, acc, S(0.0f));
            gb1[h] += dh[h];
            for (int k = 0; k < NI; ++k) gw1[h * NI + k] = madd(dh[h], feats[k], gw1[h * NI + k]);
        }
        for (int k = 0; k < NI; ++k) {
            vf acc = S(0.0f);
            for (int h = 0; h < H; ++h) acc = madd(dh[h], S(A.w1[h * NI + k]), acc);
            dfe[k] = acc;
        }
        // back through the trilinear taps into the parameters
        for (int i = 0; i < NI / C; ++i) {
            const bool hi = A.slots[6 * (2 * i + 1)] != 0;
            const float tb = A.blend[i];
            for (int lv = 0; lv < 2; ++lv) {
                const int j = 2 * i + lv;
                if (A.slots[6 * j] != TRAINED) continue;
                vf gl[4], g[4];
                for (int c = 0; c < C; ++c) {
                    vf gc = dfe[C * i + c];
                    if (hi) gc = lv == 1 ? gc * tb : gc - gc * tb;
                    gl[c] = gc;
                }
                const vf fx = T.fx[j], fy = T.fy[j];
                for (int t = 0; t < 4; ++t) {
                    const vf wy = t >= 2 ? fy : 1.0f - fy, wx = (t & 1) ? fx : 1.0f - fx;
                    for (int c = 0; c < C; ++c) g[c] = gl[c] * wy * wx;
                    texel_backward<F, sgn>(A, j, t, T, g, live);
                }
            }
        }
    }
    for (int k = 0; k < H * NI; ++k) A.gw1[k] += hsum(gw1[k]);
    for (int k = 0; k < NO * H; ++k) A.gw2[k] += hsum(gw2[k]);
    for (int k = 0; k < H; ++k) A.gb1[k] += hsum(gb1[k]);
    for (int k = 0; k < NO; ++k) A.gb2[k] += hsum(gb2[k]);
    return sse;
}

// The features (b - a, n_in) of samples [a, b) into feats_out (tests against the torch path).
template <int F, bool q, bool sgn>
void features_out(const Args& A) {
    Taps T;
    vf feats[4 * MAX_LAYERS];
    for (int64_t n0 = A.a; n0 < A.b; n0 += W) {
        const int live = int(std::min<int64_t>(W, A.b - n0));
        features<F, q, sgn>(A, lanes(n0, live), T, feats);
        for (int l = 0; l < live; ++l)
            for (int k = 0; k < A.n_in; ++k) A.feats_out[(n0 - A.a + l) * A.n_in + k] = feats[k][l];
    }
}

// fn<F, q, sgn>(A) for the args' case; the flags a format does not read are fixed, so that it
// is compiled once (BC6H blocks 4 ways, BC7 blocks 2, free BC6H features 2, free BC7 features 1).
template <template <int, bool, bool> class Fn>
auto dispatch(const Args& A) {
    const bool q = A.quantized != 0, sg = A.sgn != 0;
    switch (A.fmt) {
        case FREE_BC7: return Fn<FREE_BC7, false, false>::run(A);
        case FREE_BC6H: return sg ? Fn<FREE_BC6H, false, true>::run(A) : Fn<FREE_BC6H, false, false>::run(A);
        case BLOCK_BC7: return q ? Fn<BLOCK_BC7, true, false>::run(A) : Fn<BLOCK_BC7, false, false>::run(A);
        default:
            if (q) return sg ? Fn<BLOCK_BC6H, true, true>::run(A) : Fn<BLOCK_BC6H, true, false>::run(A);
            return sg ? Fn<BLOCK_BC6H, false, true>::run(A) : Fn<BLOCK_BC6H, false, false>::run(A);
    }
}

template <int F, bool q, bool sgn>
struct StepFn {
    static double run(const Args& A) { return step<F, q, sgn>(A); }
};
template <int F, bool q, bool sgn>
struct FeaturesFn {
    static int run(const Args& A) { features_out<F, q, sgn>(A); return 0; }
};

}  // namespace

extern "C" {

double bcf_step(const Args* args) { return dispatch<StepFn>(*args); }

void bcf_features(const Args* args) { dispatch<FeaturesFn>(*args); }

}  // extern "C"
