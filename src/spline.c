/*
 * spline.c - the monotone rational-quadratic spline of Durkan et al. 2019 on [0,1]
 * (SPEC section 3): knots from raw parameters, evaluation, inversion, and the partial
 * derivatives that reverse mode needs.
 */
#include <math.h>

#include "internal.h"

/* softplus(a) without overflow for large a and without losing small values for negative a. */
static float nf_softplus(float a)
{
    return a > 0.0f ? a + log1pf(expf(-a)) : log1pf(expf(a));
}

static float nf_sigmoid(float a)
{
    return 1.0f / (1.0f + expf(-a));
}

/* The knots x_0 = 0 < ... < x_K = 1 from K raw values: m + (1 - K m) softmax(raw). The
 * softmax itself is kept for the backward pass. */
static void nf_spline_knots(uint32_t bins, const float *raw, float *knots, float *soft)
{
    float top = raw[0];
    for (uint32_t i = 1; i < bins; ++i)
        top = nf_maxf(top, raw[i]);
    float sum = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        soft[i] = expf(raw[i] - top);
        sum += soft[i];
    }
    float inv = 1.0f / sum, scale = 1.0f - (float)bins * NF_SPLINE_MIN, acc = 0.0f;
    knots[0] = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        soft[i] *= inv;
        acc += NF_SPLINE_MIN + scale * soft[i];
        knots[i + 1] = acc;
    }
    /* The sum is 1 in exact arithmetic; pin it so the domain is exactly [0,1]. */
    knots[bins] = 1.0f;
}

void nf_spline_build(nf_spline *s, uint32_t bins, const float *raw)
{
    s->bins = bins;
    nf_spline_knots(bins, raw, s->x, s->sw);
    nf_spline_knots(bins, raw + bins, s->y, s->sh);
    s->raw_d = raw + 2 * bins;
}

/* The derivatives d_k, d_{k+1} at the ends of bin k, and (if sd != NULL) their derivatives
 * with respect to the raw values, sigmoid(raw + c). Computing two instead of K+1 saves most
 * of the spline's transcendental functions. */
static void nf_bin_derivatives(const nf_spline *s, uint32_t k, float d[2], float sd[2])
{
    /* c = log(exp(1 - m) - 1) makes softplus(0 + c) = 1 - m, so zero raw derivatives give 1. */
    const float shift = 0.53974242f;
    for (int j = 0; j < 2; ++j) {
        float a = s->raw_d[k + (uint32_t)j] + shift;
        d[j] = NF_SPLINE_MIN + nf_softplus(a);
        if (sd)
            sd[j] = nf_sigmoid(a);
    }
}

uint32_t nf_spline_bin_of_x(const nf_spline *s, float x)
{
    /* Counting interior knots <= x has no data-dependent branch; x = 1 lands in the last bin. */
    uint32_t k = 0;
    for (uint32_t i = 1; i < s->bins; ++i)
        k += (x >= s->x[i]);
    return k;
}

uint32_t nf_spline_bin_of_y(const nf_spline *s, float y)
{
    uint32_t k = 0;
    for (uint32_t i = 1; i < s->bins; ++i)
        k += (y >= s->y[i]);
    return k;
}

void nf_spline_eval(const nf_spline *s, uint32_t k, float x, float *y, float *log_dydx)
{
    float xk = s->x[k], wk = s->x[k + 1] - xk;
    float yk = s->y[k], hk = s->y[k + 1] - yk;
    float d[2];
    nf_bin_derivatives(s, k, d, NULL);
    float d0 = d[0], d1 = d[1];
    float xi = nf_clampf((x - xk) / wk, 0.0f, 1.0f);
    float sk = hk / wk, e = xi * (1.0f - xi), om = 1.0f - xi;
    float den = sk + (d1 + d0 - 2.0f * sk) * e;
    float num = hk * (sk * xi * xi + d0 * e);
    *y = nf_clampf(yk + num / den, 0.0f, 1.0f);
    float p = d1 * xi * xi + 2.0f * sk * e + d0 * om * om;
    *log_dydx = 2.0f * logf(sk) + logf(p) - 2.0f * logf(den);
}

float nf_spline_solve(const nf_spline *s, uint32_t k, float y)
{
    float xk = s->x[k], wk = s->x[k + 1] - xk;
    float yk = s->y[k], hk = s->y[k + 1] - yk;
    float d[2];
    nf_bin_derivatives(s, k, d, NULL);
    float d0 = d[0], d1 = d[1];
    float sk = hk / wk, t = y - yk, sum = d1 + d0 - 2.0f * sk;
    float a = hk * (sk - d0) + t * sum;
    float b = hk * d0 - t * sum;
    float c = -sk * t;
    float disc = nf_maxf(b * b - 4.0f * a * c, 0.0f);
    /* The root 2c / (-b - sqrt(disc)) avoids the cancellation of the textbook formula. */
    float denom = -b - sqrtf(disc);
    float xi = denom != 0.0f ? 2.0f * c / denom : 0.0f;
    xi = nf_clampf(xi, 0.0f, 1.0f);
    return nf_clampf(xk + xi * wk, 0.0f, 1.0f);
}

void nf_spline_partials_at(const nf_spline *s, uint32_t k, float x, nf_spline_partials *p)
{
    float xk = s->x[k], wk = s->x[k + 1] - xk;
    float hk = s->y[k + 1] - s->y[k];
    float d[2], sd[2];
    nf_bin_derivatives(s, k, d, sd);
    float d0 = d[0], d1 = d[1];
    float xi = nf_clampf((x - xk) / wk, 0.0f, 1.0f);
    float sk = hk / wk, e = xi * (1.0f - xi), ep = 1.0f - 2.0f * xi, om = 1.0f - xi;
    float sum = d1 + d0 - 2.0f * sk;
    float den = sk + sum * e;
    float num = hk * (sk * xi * xi + d0 * e);
    float r = num / den;
    float poly = d1 * xi * xi + 2.0f * sk * e + d0 * om * om;

    /* y = y_k + N/D as a function of (xi, s, d0, d1, h) */
    float ry_xi = (hk * (2.0f * sk * xi + d0 * ep) - r * sum * ep) / den;
    float ry_s = (hk * xi * xi - r * (1.0f - 2.0f * e)) / den;
    float ry_d0 = (hk * e - r * e) / den;
    float ry_d1 = -r * e / den;
    float ry_h = (sk * xi * xi + d0 * e) / den;
    /* l = 2 log s + log P - 2 log D */
    float l_xi = (2.0f * d1 * xi + 2.0f * sk * ep - 2.0f * d0 * om) / poly - 2.0f * sum * ep / den;
    float l_s = 2.0f / sk + 2.0f * e / poly - 2.0f * (1.0f - 2.0f * e) / den;
    float l_d0 = om * om / poly - 2.0f * e / den;
    float l_d1 = xi * xi / poly - 2.0f * e / den;

    /* xi = (x - x_k) / w_k and s = h_k / w_k */
    float inv_w = 1.0f / wk;
    p->dy_dx = ry_xi * inv_w;
    p->dy_dxk = -ry_xi * inv_w;
    p->dy_dwk = -(ry_xi * xi + ry_s * sk) * inv_w;
    p->dy_dyk = 1.0f;
    p->dy_dhk = ry_h + ry_s * inv_w;
    p->dy_dd0 = ry_d0;
    p->dy_dd1 = ry_d1;
    p->dl_dx = l_xi * inv_w;
    p->dl_dxk = -l_xi * inv_w;
    p->dl_dwk = -(l_xi * xi + l_s * sk) * inv_w;
    p->dl_dhk = l_s * inv_w;
    p->dl_dd0 = l_d0;
    p->dl_dd1 = l_d1;
    p->dd0_draw = sd[0];
    p->dd1_draw = sd[1];
}

/* Gradient of the knots x_k (as position) and x_{k+1} - x_k (as width) back to the raw
 * softmax inputs. Only interior knots depend on the raw values (x_0 = 0, x_K = 1), and
 * knot j = sum_{i<j} w_i. */
static void nf_knots_backward(uint32_t bins, uint32_t k, const float *soft, float g_pos,
                              float g_width, float *raw_grad)
{
    float g_lo = g_pos - g_width;                  /* gradient on knot k     */
    float g_hi = (k + 1 < bins) ? g_width : 0.0f;  /* gradient on knot k + 1 */
    float gw[NF_MAX_SPLINE_BINS];
    float dot = 0.0f;
    for (uint32_t i = 0; i < bins; ++i) {
        gw[i] = (i < k ? g_lo : 0.0f) + (i <= k ? g_hi : 0.0f);
        dot += soft[i] * gw[i];
    }
    float scale = 1.0f - (float)bins * NF_SPLINE_MIN;
    for (uint32_t i = 0; i < bins; ++i)
        raw_grad[i] += scale * soft[i] * (gw[i] - dot);
}

void nf_spline_raw_backward(const nf_spline *s, uint32_t k, const nf_spline_partials *p,
                            float a, float b, float *raw_grad)
{
    uint32_t bins = s->bins;
    float g_xk = a * p->dy_dxk + b * p->dl_dxk;
    float g_wk = a * p->dy_dwk + b * p->dl_dwk;
    float g_yk = a * p->dy_dyk;
    float g_hk = a * p->dy_dhk + b * p->dl_dhk;
    nf_knots_backward(bins, k, s->sw, g_xk, g_wk, raw_grad);
    nf_knots_backward(bins, k, s->sh, g_yk, g_hk, raw_grad + bins);
    raw_grad[2 * bins + k] += (a * p->dy_dd0 + b * p->dl_dd0) * p->dd0_draw;
    raw_grad[2 * bins + k + 1] += (a * p->dy_dd1 + b * p->dl_dd1) * p->dd1_draw;
}

static nf_status nf_spline_check(const char *fn, uint32_t bins, const float *raw, float v,
                                 const void *out)
{
    if (!raw || !out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: raw or output pointer is NULL", fn);
    if (bins < 2 || bins > NF_MAX_SPLINE_BINS)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: bins = %u is outside [2, %u]", fn, bins,
                       NF_MAX_SPLINE_BINS);
    if (!nf_all_finite(raw, 3u * bins + 1u) || !isfinite(v))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: non-finite input", fn);
    return NF_OK;
}

nf_status nf_spline_forward(uint32_t bins, const float *raw, float x, float *y, float *dydx)
{
    nf_status st = nf_spline_check("nf_spline_forward", bins, raw, x, y);
    if (st != NF_OK)
        return st;
    nf_spline s;
    nf_spline_build(&s, bins, raw);
    x = nf_clampf(x, 0.0f, 1.0f);
    float log_d;
    nf_spline_eval(&s, nf_spline_bin_of_x(&s, x), x, y, &log_d);
    if (dydx)
        *dydx = expf(log_d);
    return NF_OK;
}

nf_status nf_spline_inverse(uint32_t bins, const float *raw, float y, float *x, float *dydx)
{
    nf_status st = nf_spline_check("nf_spline_inverse", bins, raw, y, x);
    if (st != NF_OK)
        return st;
    nf_spline s;
    nf_spline_build(&s, bins, raw);
    y = nf_clampf(y, 0.0f, 1.0f);
    uint32_t k = nf_spline_bin_of_y(&s, y);
    *x = nf_spline_solve(&s, k, y);
    if (dydx) {
        float y_again, log_d;
        nf_spline_eval(&s, k, *x, &y_again, &log_d);
        *dydx = expf(log_d);
    }
    return NF_OK;
}
