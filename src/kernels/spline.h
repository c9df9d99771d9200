/*
 * spline.h - the rational-quadratic spline of docs/theory.md section 3 as inline code for the
 * kernels: knots from raw parameters, bin search, evaluation, inversion, and the partial
 * derivatives reverse mode needs. spline.c wraps it for the public API.
 */
#ifndef NISFLOW_KERNELS_SPLINE_H
#define NISFLOW_KERNELS_SPLINE_H

#include "fastmath.h"
#include "internal.h"

/* The knots of one spline, computed from its raw parameters. */
typedef struct nf_spline {
    uint32_t bins;
    float x[NF_MAX_SPLINE_BINS + 1]; /* knot abscissae, x[0] = 0, x[K] = 1 exactly          */
    float y[NF_MAX_SPLINE_BINS + 1]; /* knot ordinates, y[0] = 0, y[K] = 1 exactly          */
    float sw[NF_MAX_SPLINE_BINS];    /* softmax of the raw widths (kept for gradients)      */
    float sh[NF_MAX_SPLINE_BINS];    /* softmax of the raw heights                          */
    const float *raw_d;              /* K+1 raw derivatives, borrowed: only the two of the
                                        bin in use are ever transformed                     */
} nf_spline;

/* One bin's local quantities at a point, shared by evaluation and reverse mode. */
typedef struct nf_spline_bin {
    uint32_t k;
    float xk, wk, yk, hk, d0, d1;
    float x1, y1;   /* the bin's upper knots, exactly as stored */
    float sd0, sd1; /* d d_k / d raw, d d_{k+1} / d raw: sigmoid(raw + c) */
} nf_spline_bin;

/* Partial derivatives of y and l = log(dy/dx) with respect to the bin's local quantities. */
typedef struct nf_spline_partials {
    float dy_dx, dy_dxk, dy_dwk, dy_dhk, dy_dd0, dy_dd1; /* dy/dyk = 1 */
    float dl_dx, dl_dxk, dl_dwk, dl_dhk, dl_dd0, dl_dd1; /* dl/dyk = 0 */
} nf_spline_partials;

/* Knots 0 = t_0 < ... < t_K = 1 from the K exponentials e[i] = exp(raw[i] - max raw), as
 * m + (1 - K m) softmax(raw); soft receives the softmax (it may be e itself). The sum runs in
 * bin order, as the tile kernels sum. */
static inline void nf_spline_knots_from_exps(uint32_t bins, const float *e, float *knots,
                                             float *soft)
{
    float sum = 0.0f;
    for (uint32_t i = 0; i < bins; ++i)
        sum += e[i];
    float inv = 1.0f / sum, scale = 1.0f - (float)bins * NF_SPLINE_MIN, acc = 0.0f;
    knots[0] = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        soft[i] = e[i] * inv;
        acc += NF_SPLINE_MIN + scale * soft[i];
        knots[i + 1] = acc;
    }
    /* The sum is 1 in exact arithmetic; pin it so the domain is exactly [0,1]. */
    knots[bins] = 1.0f;
}

/* Knots from K raw values. The exps have a loop of their own, with no branch, call or sum to
 * keep it from vectorizing over the bins. */
static inline void nf_spline_knots(uint32_t bins, const float *raw, float *knots, float *soft)
{
    float top = raw[0];
    for (uint32_t i = 1; i < bins; ++i)
        top = nf_maxf(top, raw[i]);
    for (uint32_t i = 0; i < bins; ++i)
        soft[i] = nf_fast_exp(raw[i] - top);
    nf_spline_knots_from_exps(bins, soft, knots, soft);
}

/* e[i] = exp(raw[i] - max) for the K widths and then the K heights, each with its own max,
 * in one loop over 2K values (one AVX-512 vector for K = 8): a single sample has no other
 * lanes to fill, and these 2K exps were a third of its time. */
static inline void nf_spline_exps(uint32_t bins, const float *raw, float *e)
{
    float top_w = raw[0], top_h = raw[bins];
    for (uint32_t i = 1; i < bins; ++i) {
        top_w = nf_maxf(top_w, raw[i]);
        top_h = nf_maxf(top_h, raw[bins + i]);
    }
    for (uint32_t i = 0; i < 2 * bins; ++i)
        e[i] = nf_fast_exp(raw[i] - (i < bins ? top_w : top_h));
}

/* `raw` must outlive `s`: the knot derivatives are computed from it on demand. */
static inline void nf_spline_build(nf_spline *s, uint32_t bins, const float *raw)
{
    float e[2 * NF_MAX_SPLINE_BINS];
    nf_spline_exps(bins, raw, e);
    s->bins = bins;
    nf_spline_knots_from_exps(bins, e, s->x, s->sw);
    nf_spline_knots_from_exps(bins, e + bins, s->y, s->sh);
    s->raw_d = raw + 2 * bins;
}

/* Counting interior knots <= v has no data-dependent branch; v = 1 lands in the last bin. */
static inline uint32_t nf_spline_find(const float *knots, uint32_t bins, float v)
{
    uint32_t k = 0;
    for (uint32_t i = 1; i < bins; ++i)
        k += (v >= knots[i]);
    return k;
}

/* softplus(a) = max(a, 0) + log(1 + e^-|a|) and its derivative sigmoid(a). */
static inline void nf_softplus(float a, float *value, float *slope)
{
    float e = nf_fast_exp(-(a < 0.0f ? -a : a));
    *value = nf_maxf(a, 0.0f) + nf_fast_log(1.0f + e);
    float inv = 1.0f / (1.0f + e);
    *slope = a >= 0.0f ? inv : e * inv;
}

/* c = log(exp(1 - m) - 1) makes softplus(0 + c) = 1 - m, so zero raw derivatives give 1. */
#define NF_SPLINE_DERIVATIVE_SHIFT 0.53974242f

/* The bin's knots and slopes, with the knot derivatives d and their slopes sd given. */
static inline void nf_spline_bin_with(const float *x, const float *y, uint32_t k, float d0,
                                      float sd0, float d1, float sd1, nf_spline_bin *b)
{
    b->k = k;
    b->xk = x[k];
    b->wk = x[k + 1] - b->xk;
    b->yk = y[k];
    b->hk = y[k + 1] - b->yk;
    b->x1 = x[k + 1];
    b->y1 = y[k + 1];
    b->d0 = d0;
    b->sd0 = sd0;
    b->d1 = d1;
    b->sd1 = sd1;
}

static inline void nf_spline_bin_at(const nf_spline *s, uint32_t k, nf_spline_bin *b)
{
    float sp0, sd0, sp1, sd1;
    nf_softplus(s->raw_d[k] + NF_SPLINE_DERIVATIVE_SHIFT, &sp0, &sd0);
    nf_softplus(s->raw_d[k + 1] + NF_SPLINE_DERIVATIVE_SHIFT, &sp1, &sd1);
    nf_spline_bin_with(s->x, s->y, k, NF_SPLINE_MIN + sp0, sd0, NF_SPLINE_MIN + sp1, sd1, b);
}

/* Every knot derivative d[i] = m + softplus(raw_d[i] + c) and its slope sd[i], i <= K, in a
 * loop that vectorizes: a single sample computes all K + 1 at once, off the critical path
 * (they do not wait for the bin search), instead of two after it. Same values as
 * nf_spline_bin_at's. */
static inline void nf_spline_derivatives(uint32_t bins, const float *raw_d, float *d, float *sd)
{
    for (uint32_t i = 0; i <= bins; ++i) {
        float sp;
        nf_softplus(raw_d[i] + NF_SPLINE_DERIVATIVE_SHIFT, &sp, &sd[i]);
        d[i] = NF_SPLINE_MIN + sp;
    }
}

/* y and dy/dx at x (clamped into the bin). */
static inline float nf_spline_bin_eval(const nf_spline_bin *b, float x, float *dydx)
{
    float xi = nf_clampf((x - b->xk) / b->wk, 0.0f, 1.0f);
    float sk = b->hk / b->wk, e = xi * (1.0f - xi), om = 1.0f - xi;
    float den = sk + (b->d1 + b->d0 - 2.0f * sk) * e;
    float inv_den = 1.0f / den;
    float p = b->d1 * xi * xi + 2.0f * sk * e + b->d0 * om * om;
    *dydx = sk * sk * p * inv_den * inv_den;
    /* At the bin's upper end (xi = 1 exactly) y_k + h_k r may miss the stored knot by an ulp:
     * take the knot itself, so that forward(1) = 1. */
    float r = (sk * xi * xi + b->d0 * e) * inv_den;
    return xi >= 1.0f ? b->y1 : nf_clampf(b->yk + b->hk * r, 0.0f, 1.0f);
}

/* x in the bin with forward(x) = y, by the root 2c / (-b - sqrt(disc)) that avoids the
 * cancellation of the textbook formula. The coefficients are formed in double: with extreme
 * raw parameters s_k and d_k nearly cancel in a, and float would lose the root's monotonicity
 * in y. */
static inline float nf_spline_bin_solve(const nf_spline_bin *b, float y)
{
    double hk = b->hk, d0 = b->d0, d1 = b->d1, sk = hk / (double)b->wk;
    double t = (double)y - (double)b->yk, sum = d1 + d0 - 2.0 * sk;
    double qa = hk * (sk - d0) + t * sum;
    double qb = hk * d0 - t * sum;
    double qc = -sk * t;
    double disc = qb * qb - 4.0 * qa * qc;
    double denom = -qb - sqrt(disc > 0.0 ? disc : 0.0);
    double xi = denom != 0.0 ? 2.0 * qc / denom : 0.0;
    xi = xi < 0.0 ? 0.0 : (xi > 1.0 ? 1.0 : xi);
    /* The bin's upper end inverts exactly (the root's rounding would miss it by an ulp). */
    return y >= b->y1 ? b->x1 : nf_clampf((float)(b->xk + xi * b->wk), 0.0f, b->x1);
}

static inline void nf_spline_partials_at(const nf_spline_bin *b, float x, nf_spline_partials *p)
{
    float hk = b->hk, wk = b->wk, d0 = b->d0, d1 = b->d1;
    float xi = nf_clampf((x - b->xk) / wk, 0.0f, 1.0f);
    float sk = hk / wk, e = xi * (1.0f - xi), ep = 1.0f - 2.0f * xi, om = 1.0f - xi;
    float sum = d1 + d0 - 2.0f * sk;
    float inv_den = 1.0f / (sk + sum * e);
    float r = hk * (sk * xi * xi + d0 * e) * inv_den;
    float inv_poly = 1.0f / (d1 * xi * xi + 2.0f * sk * e + d0 * om * om);

    /* y = y_k + N/D as a function of (xi, s, d0, d1, h) */
    float ry_xi = (hk * (2.0f * sk * xi + d0 * ep) - r * sum * ep) * inv_den;
    float ry_s = (hk * xi * xi - r * (1.0f - 2.0f * e)) * inv_den;
    float ry_d0 = (hk * e - r * e) * inv_den;
    float ry_d1 = -r * e * inv_den;
    float ry_h = (sk * xi * xi + d0 * e) * inv_den;
    /* l = 2 log s + log P - 2 log D */
    float l_xi =
        (2.0f * d1 * xi + 2.0f * sk * ep - 2.0f * d0 * om) * inv_poly - 2.0f * sum * ep * inv_den;
    float l_s = 2.0f / sk + 2.0f * e * inv_poly - 2.0f * (1.0f - 2.0f * e) * inv_den;
    float l_d0 = om * om * inv_poly - 2.0f * e * inv_den;
    float l_d1 = xi * xi * inv_poly - 2.0f * e * inv_den;

    /* xi = (x - x_k) / w_k and s = h_k / w_k */
    float inv_w = 1.0f / wk;
    p->dy_dx = ry_xi * inv_w;
    p->dy_dxk = -ry_xi * inv_w;
    p->dy_dwk = -(ry_xi * xi + ry_s * sk) * inv_w;
    p->dy_dhk = ry_h + ry_s * inv_w;
    p->dy_dd0 = ry_d0;
    p->dy_dd1 = ry_d1;
    p->dl_dx = l_xi * inv_w;
    p->dl_dxk = -l_xi * inv_w;
    p->dl_dwk = -(l_xi * xi + l_s * sk) * inv_w;
    p->dl_dhk = l_s * inv_w;
    p->dl_dd0 = l_d0;
    p->dl_dd1 = l_d1;
}

/* Gradient on knot k (as position) and on t_{k+1} - t_k (as width) back to the raw softmax
 * inputs. Only interior knots depend on the raw values (t_0 = 0, t_K = 1), and knot
 * j = sum_{i<j} w_i. */
static inline void nf_knots_backward(uint32_t bins, uint32_t k, const float *soft, float g_pos,
                                     float g_width, float *raw_grad)
{
    float g_lo = g_pos - g_width;                 /* gradient on knot k     */
    float g_hi = (k + 1 < bins) ? g_width : 0.0f; /* gradient on knot k + 1 */
    float dot = 0.0f;
    for (uint32_t i = 0; i < bins; ++i)
        dot += soft[i] * ((i < k ? g_lo : 0.0f) + (i <= k ? g_hi : 0.0f));
    float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    for (uint32_t i = 0; i < bins; ++i) {
        float gw = (i < k ? g_lo : 0.0f) + (i <= k ? g_hi : 0.0f);
        raw_grad[i] += scale * soft[i] * (gw - dot);
    }
}

/* Adds to raw_grad (3K+1) the gradient of  a*y + b*log(dy/dx)  at a point of the bin. */
static inline void nf_spline_raw_backward(const nf_spline *s, const nf_spline_bin *bin,
                                          const nf_spline_partials *p, float a, float b,
                                          float *raw_grad)
{
    uint32_t bins = s->bins, k = bin->k;
    nf_knots_backward(bins, k, s->sw, a * p->dy_dxk + b * p->dl_dxk, a * p->dy_dwk + b * p->dl_dwk,
                      raw_grad);
    nf_knots_backward(bins, k, s->sh, a, a * p->dy_dhk + b * p->dl_dhk, raw_grad + bins);
    raw_grad[2 * bins + k] += (a * p->dy_dd0 + b * p->dl_dd0) * bin->sd0;
    raw_grad[2 * bins + k + 1] += (a * p->dy_dd1 + b * p->dl_dd1) * bin->sd1;
}

#endif /* NISFLOW_KERNELS_SPLINE_H */
