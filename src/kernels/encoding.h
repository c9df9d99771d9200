/*
 * encoding.h - the conditioner's input encodings (docs/theory.md section 5) as inline code for the
 * kernels: sparse one-blob and real spherical harmonics. encoding.c wraps them for the API.
 */
#ifndef NISFLOW_KERNELS_ENCODING_H
#define NISFLOW_KERNELS_ENCODING_H

#include <math.h>

#include "internal.h"

/* Q of docs/theory.md section 5, the CDF of a quartic kernel, with its argument already scaled:
 * tb = t * B. */
static inline float nf_quartic_cdf(float tb)
{
    float u = nf_clampf(tb, -1.0f, 1.0f);
    float u2 = u * u;
    float q = (15.0f / 16.0f) * u * (1.0f - (2.0f / 3.0f) * u2 + 0.2f * u2 * u2) + 0.5f;
    /* At u = -1 the polynomial rounds to 2^-25 instead of 0, which would make the bins next
     * to a blob slightly negative: the kernel's ends are pinned to 0 and 1 exactly. */
    float r = nf_clampf(q, 0.0f, 1.0f);
    r = u <= -1.0f ? 0.0f : r;
    return u >= 1.0f ? 1.0f : r; /* one select at a time: the kernels' loops if-convert it */
}

/* dQ / d(tb) = 15/16 (1 - u^2)^2 inside the kernel, 0 outside. */
static inline float nf_quartic_kernel(float tb)
{
    float u = nf_clampf(tb, -1.0f, 1.0f);
    float w = 1.0f - u * u;
    return (15.0f / 16.0f) * w * w;
}

/* The bin a slot j of a one-blob with B bins lands in: j itself, or j +- B when the encoding
 * wraps around (a coordinate on the circle, where the blob of v near 1 continues at bin 0);
 * -1 for a slot outside an encoding that does not wrap. */
static inline int nf_oneblob_bin(int j, uint32_t bins, int wrap)
{
    int b = (int)bins;
    int wrapped = j < 0 ? j + b : (j >= b ? j - b : j);
    return wrap ? wrapped : (j >= 0 && j < b ? j : -1);
}

/* The non-zero bins of the one-blob encoding of v (clamped to [0,1]). Bin j is non-zero only
 * when j - vB lies in (-2, 1): at most three bins around floor(vB). Evaluating exactly those
 * with the same Q as the dense encoding gives identical values; every other bin is exactly
 * zero because both of its Q terms clamp to the same end. With `wrap` the slots beyond either
 * end land in the bins at the other (nf_oneblob_bin), so v = 0 and v = 1 encode alike. */
static inline void nf_oneblob_sparse(float v, uint32_t bins, int wrap, nf_blob *out)
{
    float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    int first = (int)vb - 1; /* vb >= 0, so truncation is floor */
    out->count = 0;
    for (int j = first; j < first + 3; ++j) {
        int bin = nf_oneblob_bin(j, bins, wrap);
        if (bin < 0)
            continue;
        float hi = (float)(j + 1) - vb, lo = (float)j - vb;
        uint32_t c = out->count++;
        out->bin[c] = (uint32_t)bin;
        out->value[c] = nf_quartic_cdf(hi) - nf_quartic_cdf(lo);
        out->dvalue[c] = (float)bins * (nf_quartic_kernel(lo) - nf_quartic_kernel(hi));
    }
}

/* The one-blob of v as exactly three slots j = floor(vB) - 1 .. floor(vB) + 1 (the bins that
 * can be non-zero, see nf_oneblob_sparse). A slot outside the encoding has value 0 and row
 * row_offset, so every encoded scalar has three slots and no branch: the tile kernels and the
 * per-sample kernels use this same form, which keeps their sums in the same order. With
 * `wrap` no slot is outside (nf_oneblob_bin). */
static inline void nf_oneblob_slots(float v, uint32_t bins, uint32_t row_offset, int wrap,
                                    uint32_t row[3], float value[3])
{
    float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    int first = (int)vb - 1; /* vb >= 0, so truncation is floor */
    /* Slot c is Q(t_{c+1}) - Q(t_c) with t_k = (first + k) - vb: adjacent slots share a Q,
     * so four evaluations serve the three slots (the same values as two per slot). */
    float q[4];
    for (int k = 0; k < 4; ++k)
        q[k] = nf_quartic_cdf((float)(first + k) - vb);
    for (int c = 0; c < 3; ++c) {
        int j = first + c;
        int inside = wrap | ((j >= 0) & (j < (int)bins));
        int bin = wrap ? nf_oneblob_bin(j, bins, 1) : j;
        row[c] = row_offset + (uint32_t)(inside ? bin : 0);
        value[c] = inside ? q[c + 1] - q[c] : 0.0f;
    }
}

/* Real SH, any band count, from the Cartesian form: sin^m(theta) {cos, sin}(m phi) are the
 * real and imaginary parts of (x + i y)^m, and P_l^m(z) / sin^m(theta) follows the usual
 * three-term recurrence in l (no Condon-Shortley phase). Double keeps it exact to float. */
static inline void nf_sh_recurrence(const float d[3], uint32_t bands, float *out)
{
    double x = d[0], y = d[1], z = d[2];
    double pmm = 1.0;          /* P~_m^m = (2m-1)!! */
    double cm = 1.0, sm = 0.0; /* Re, Im of (x + i y)^m */
    for (uint32_t m = 0; m < bands; ++m) {
        double p_prev = 0.0, p = pmm;
        for (uint32_t l = m; l < bands; ++l) {
            if (l == m + 1) {
                p_prev = p;
                p = z * (2.0 * m + 1.0) * pmm;
            } else if (l > m + 1) {
                double next =
                    ((2.0 * l - 1.0) * z * p - (double)(l + m - 1) * p_prev) / (double)(l - m);
                p_prev = p;
                p = next;
            }
            double ratio = 1.0; /* (l-m)! / (l+m)! */
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

/* The first four bands (16 values) of the real SH of a unit vector (x, y, z), written out:
 * the recurrence's values expanded by hand. Straight-line code, so a loop over directions
 * vectorizes. */
static inline void nf_sh4(float x, float y, float z, float v[16])
{
    v[0] = 0.28209479177387814f;
    v[1] = 0.48860251190291992f * y;
    v[2] = 0.48860251190291992f * z;
    v[3] = 0.48860251190291992f * x;
    v[4] = 1.0925484305920792f * x * y;
    v[5] = 1.0925484305920792f * y * z;
    v[6] = 0.31539156525252005f * (3.0f * z * z - 1.0f);
    v[7] = 1.0925484305920792f * x * z;
    v[8] = 0.54627421529603959f * (x * x - y * y);
    v[9] = 0.59004358992664352f * y * (3.0f * x * x - y * y);
    v[10] = 2.8906114426405538f * x * y * z;
    v[11] = 0.45704579946446572f * y * (5.0f * z * z - 1.0f);
    v[12] = 0.37317633259011546f * z * (5.0f * z * z - 3.0f);
    v[13] = 0.45704579946446572f * x * (5.0f * z * z - 1.0f);
    v[14] = 1.4453057213202769f * z * (x * x - y * y);
    v[15] = 0.59004358992664352f * x * (x * x - 3.0f * y * y);
}

/* Real SH of a unit vector, bands 0..bands-1. Higher bands come from the recurrence, and the
 * first four are always nf_sh4's, so an encoding with fewer bands is always a prefix of one
 * with more. */
static inline void nf_sh_unit(const float d[3], uint32_t bands, float *out)
{
    if (bands > 4)
        nf_sh_recurrence(d, bands, out);
    if (bands >= 4) {
        /* Straight into out: a copy of a count known only at run time became a `rep movs`
         * whose start-up cost was a third of a shading point's features. */
        nf_sh4(d[0], d[1], d[2], out);
        return;
    }
    float v[16];
    nf_sh4(d[0], d[1], d[2], v);
    for (uint32_t i = 0; i < bands * bands; ++i)
        out[i] = v[i];
}

#endif /* NISFLOW_KERNELS_ENCODING_H */
