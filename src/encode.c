/*
 * encode.c - the conditioner's input encodings (SPEC section 5): one-blob for scalars in
 * [0,1] and real spherical harmonics for directions.
 */
#include <math.h>
#include <string.h>

#include "internal.h"

/* Q of SPEC section 5, the CDF of a quartic kernel, with its argument already scaled:
 * tb = t * B. Its derivative d Q / d tb is 15/16 (1 - u^2)^2 inside the kernel. */
static float nf_quartic_cdf(float tb)
{
    float u = nf_clampf(tb, -1.0f, 1.0f);
    float u2 = u * u;
    float q = (15.0f / 16.0f) * u * (1.0f - (2.0f / 3.0f) * u2 + 0.2f * u2 * u2) + 0.5f;
    return nf_clampf(q, 0.0f, 1.0f);
}

static float nf_quartic_kernel(float tb)
{
    float u = nf_clampf(tb, -1.0f, 1.0f);
    float w = 1.0f - u * u;
    return (15.0f / 16.0f) * w * w;
}

void nf_encode_oneblob(float v, uint32_t bins, float *out)
{
    if (!out || bins == 0)
        return;
    float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    for (uint32_t j = 0; j < bins; ++j)
        out[j] = nf_quartic_cdf((float)(j + 1) - vb) - nf_quartic_cdf((float)j - vb);
}

void nf_oneblob_sparse(float v, uint32_t bins, nf_blob *out)
{
    /* Bin j is non-zero only when j - vB lies in (-2, 1): at most three bins around floor(vB).
     * Evaluating exactly those with the same Q as the dense encoding gives identical values;
     * every other bin is exactly zero because both of its Q terms clamp to the same end. */
    float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    int first = (int)floorf(vb) - 1;
    out->count = 0;
    for (int j = first; j < first + 3; ++j) {
        if (j < 0 || j >= (int)bins)
            continue;
        float hi = (float)(j + 1) - vb, lo = (float)j - vb;
        uint32_t c = out->count++;
        out->bin[c] = (uint32_t)j;
        out->value[c] = nf_quartic_cdf(hi) - nf_quartic_cdf(lo);
        /* d/dv of Q(j+1 - vB) - Q(j - vB) */
        out->dvalue[c] = (float)bins * (nf_quartic_kernel(lo) - nf_quartic_kernel(hi));
    }
}

void nf_sh_unit(const float d[3], uint32_t bands, float *out)
{
    /* Real SH from the Cartesian form: sin^m(theta) {cos, sin}(m phi) are the real and
     * imaginary parts of (x + i y)^m, and P_l^m(z) / sin^m(theta) follows the usual
     * three-term recurrence in l. Double precision keeps the recurrence exact to float. */
    double x = d[0], y = d[1], z = d[2];
    double pmm = 1.0;      /* P~_m^m = (2m-1)!!, no Condon-Shortley phase */
    double cm = 1.0, sm = 0.0; /* Re, Im of (x + i y)^m */
    for (uint32_t m = 0; m < bands; ++m) {
        double p_prev = 0.0, p = pmm;
        for (uint32_t l = m; l < bands; ++l) {
            if (l == m + 1) {
                p_prev = p;
                p = z * (2.0 * m + 1.0) * pmm;
            } else if (l > m + 1) {
                double next = ((2.0 * l - 1.0) * z * p - (double)(l + m - 1) * p_prev) /
                              (double)(l - m);
                p_prev = p;
                p = next;
            }
            /* K_lm = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!) */
            double ratio = 1.0;
            for (uint32_t k = l - m + 1; k <= l + m; ++k)
                ratio /= (double)k;
            double k_lm = sqrt((2.0 * l + 1.0) / (4.0 * 3.14159265358979323846) * ratio);
            uint32_t centre = l * l + l;
            if (m == 0) {
                out[centre] = (float)(k_lm * p);
            } else {
                out[centre + m] = (float)(1.41421356237309505 * k_lm * cm * p);
                out[centre - m] = (float)(1.41421356237309505 * k_lm * sm * p);
            }
        }
        double c_next = cm * x - sm * y, s_next = cm * y + sm * x;
        cm = c_next;
        sm = s_next;
        pmm *= 2.0 * m + 1.0;
    }
}

void nf_encode_sh(const float dir[3], uint32_t bands, float *out)
{
    if (!out || bands == 0 || !dir)
        return;
    if (bands > NF_MAX_SH_BANDS)
        bands = NF_MAX_SH_BANDS;
    double len2 = (double)dir[0] * dir[0] + (double)dir[1] * dir[1] + (double)dir[2] * dir[2];
    if (!(len2 > 1e-30) || !isfinite(len2)) {
        memset(out, 0, sizeof(float) * bands * bands);
        return;
    }
    float inv = (float)(1.0 / sqrt(len2));
    float unit[3] = {dir[0] * inv, dir[1] * inv, dir[2] * inv};
    nf_sh_unit(unit, bands, out);
}
