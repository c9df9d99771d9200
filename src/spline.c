/*
 * spline.c - the public nf_spline_forward / nf_spline_inverse over the kernels' inline spline
 * (spline.h), with argument checking.
 */
#include <math.h>

#include "blocks.h"
#include "kernels/spline.h"

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

/* The raw parameters clamped as the conditioners clamp theirs (internal.h, NF_RAW_LIMIT):
 * without it a raw derivative near FLT_MAX overflowed the slope to Inf or NaN. */
static void nf_spline_clamp_raw(uint32_t bins, const float *raw, float *out)
{
    for (uint32_t i = 0; i < 3u * bins + 1u; ++i)
        out[i] = nf_clampf(raw[i], -NF_RAW_LIMIT, NF_RAW_LIMIT);
}

nf_status nf_spline_forward(uint32_t bins, const float *raw_in, float x, float *y, float *dydx)
{
    nf_status st = nf_spline_check("nf_spline_forward", bins, raw_in, x, y);
    if (st != NF_OK)
        return st;
    float raw[NF_MAX_RAW];
    nf_spline_clamp_raw(bins, raw_in, raw);
    nf_spline s;
    nf_spline_bin bin;
    nf_spline_build(&s, bins, raw);
    x = nf_clampf(x, 0.0f, 1.0f);
    nf_spline_bin_at(&s, nf_spline_find(s.x, bins, x), &bin);
    float slope;
    *y = nf_spline_bin_eval(&bin, x, &slope);
    if (dydx)
        *dydx = slope;
    return NF_OK;
}

nf_status nf_spline_inverse(uint32_t bins, const float *raw_in, float y, float *x, float *dydx)
{
    nf_status st = nf_spline_check("nf_spline_inverse", bins, raw_in, y, x);
    if (st != NF_OK)
        return st;
    float raw[NF_MAX_RAW];
    nf_spline_clamp_raw(bins, raw_in, raw);
    nf_spline s;
    nf_spline_bin bin;
    nf_spline_build(&s, bins, raw);
    y = nf_clampf(y, 0.0f, 1.0f);
    nf_spline_bin_at(&s, nf_spline_find(s.y, bins, y), &bin);
    *x = nf_spline_bin_solve(&bin, y);
    if (dydx)
        nf_spline_bin_eval(&bin, *x, dydx);
    return NF_OK;
}
