// Adam for the feature parameters of the levels a fused step touched (step.py's FusedStep.adam):
// the chunks' gradient rows added in order, torch's Adam update, the clamp to the encodable range,
// and the rows zeroed for the next step, in one pass over the level instead of four.
#include <cmath>
#include <cstdint>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

namespace {

// Denormal moments flushed to zero for the call (MXCSR's FTZ and DAZ, restored after). An element
// a step leaves without a gradient keeps decaying m by beta1; after some 600 such steps m is
// denormal, and every operation on it takes the slow microcode path: Adam at 2k grew from 7 to 16
// ms per step over 4,000 constrained steps as 4 % of the indices' m went denormal. Such an m moves
// its parameter by under 1e-29, which a float parameter cannot hold, so the flush changes no
// parameter.
struct FlushDenormals {
#if defined(__SSE__)
    unsigned saved = _mm_getcsr();
    FlushDenormals() { _mm_setcsr(saved | 0x8040); }
    ~FlushDenormals() { _mm_setcsr(saved); }
#endif
};

}  // namespace

extern "C" {

// p[0, n): parameters; g: `rows` gradient rows of `stride` floats each (row 0 holds their sum
// afterwards, then every row is zero); m, v: Adam's moments. `step` counts this level's updates,
// this one included. The update is ATen's fused CPU Adam (no weight decay, no amsgrad).
void bcf_adam(float* __restrict__ p, float* __restrict__ g, int rows, int64_t stride, float* __restrict__ m,
              float* __restrict__ v, int64_t n, double lr, double beta1, double beta2, double eps, int64_t step, float lo,
              float hi) {
    const FlushDenormals flush;
    const double bc1 = 1.0 - std::pow(beta1, double(step));
    const double bc2_sqrt = std::sqrt(1.0 - std::pow(beta2, double(step)));
    const float b1 = float(beta1), b2 = float(beta2), c1 = float(1.0 - beta1), c2 = float(1.0 - beta2);
    const float step_size = float(lr / bc1), bc2s = float(bc2_sqrt), e = float(eps);
    for (int q = 1; q < rows; ++q) {  // the chunks' rows, added in order
        float* __restrict__ gq = g + q * stride;
        for (int64_t k = 0; k < n; ++k) {
            g[k] += gq[k];
            gq[k] = 0.0f;
        }
    }
    for (int64_t k = 0; k < n; ++k) {
        float gk = g[k];
        g[k] = 0.0f;
        float mk = b1 * m[k] + c1 * gk;
        float vk = b2 * v[k] + c2 * gk * gk;
        m[k] = mk;
        v[k] = vk;
        float pk = p[k] - step_size * mk / (std::sqrt(vk) / bc2s + e);
        p[k] = pk < lo ? lo : (pk > hi ? hi : pk);
    }
}

}  // extern "C"
