/*
 * fuzz_blocks.c - libFuzzer target for the building blocks of blocks.h (docs/robustness.md),
 * the public entry points that take caller floats without a model: the spline, the encodings
 * and the direction <-> square maps. The input is read as a bin count, a band count and then
 * little-endian floats (any bit pattern: NaN, infinities, denormals, +-FLT_MAX), zero-padded.
 * Invariants, checked by abort():
 *   - nf_spline_forward / nf_spline_inverse: NF_ERROR_INVALID_ARGUMENT for bins outside
 *     [2, NF_MAX_SPLINE_BINS] or a non-finite raw parameter or argument, and nothing written;
 *     otherwise NF_OK with y (x) in [0, 1] and a finite slope > 0;
 *   - nf_encode_oneblob: finite entries in [0, 1] up to rounding (1e-3 is far above any float
 *     rounding of a CDF difference and far below a wrong value), for any v, NaN included;
 *   - nf_encode_sh: finite entries of magnitude <= 1 (the largest real SH of bands 0..5 is
 *     sqrt(11 / (4 pi)) = 0.94), zeros for a zero or non-finite direction;
 *   - nf_direction_to_square: s0 in [0, 1] and s1 in [0, 1) for any direction;
 *   - nf_square_to_direction: a unit vector (within 2e-6, as the API's samples) for any s.
 */
#include <float.h>

#include "fuzz_common.h"
#include "blocks.h"

enum { MAX_RAW = 3 * NF_MAX_SPLINE_BINS + 1 };

typedef struct reader {
    const uint8_t *p;
    size_t left;
} reader;

static float next_f32(reader *r)
{
    uint32_t bits = 0;
    for (int i = 0; i < 4; ++i, ++r->p, --r->left)
        if (r->left)
            bits |= (uint32_t)*r->p << (8 * i);
        else
            break;
    float v;
    memcpy(&v, &bits, 4);
    return v;
}

static void check_spline(uint32_t bins, const float *raw, float x, float y)
{
    int params_ok = bins >= 2 && bins <= NF_MAX_SPLINE_BINS;
    for (uint32_t i = 0; params_ok && i < 3 * bins + 1; ++i)
        params_ok = isfinite(raw[i]);
    int valid = params_ok && isfinite(x);
    const float sentinel = -7.5e33f;
    float out = sentinel, slope = sentinel;
    nf_status st = nf_spline_forward(bins, raw, x, &out, &slope);
    if (!valid) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "forward status %d", (int)st);
        NF_FUZZ_CHECK(out == sentinel && slope == sentinel, "a refused forward wrote");
    } else {
        NF_FUZZ_CHECK(st == NF_OK, "forward status %d", (int)st);
        NF_FUZZ_CHECK(out >= 0.0f && out <= 1.0f, "forward y = %g", (double)out);
        NF_FUZZ_CHECK(isfinite(slope) && slope > 0.0f, "forward slope %g", (double)slope);
    }
    out = slope = sentinel;
    valid = params_ok && isfinite(y);
    st = nf_spline_inverse(bins, raw, y, &out, &slope);
    if (!valid) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT, "inverse status %d", (int)st);
        NF_FUZZ_CHECK(out == sentinel && slope == sentinel, "a refused inverse wrote");
    } else {
        NF_FUZZ_CHECK(st == NF_OK, "inverse status %d", (int)st);
        NF_FUZZ_CHECK(out >= 0.0f && out <= 1.0f, "inverse x = %g", (double)out);
        NF_FUZZ_CHECK(isfinite(slope) && slope > 0.0f, "inverse slope %g", (double)slope);
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 2)
        return 0;
    /* bins 0..255: most are valid, some are not. */
    uint32_t bins = data[0], bands = data[1] % (NF_MAX_SH_BANDS + 1u);
    reader r = {data + 2, size - 2};
    float raw[MAX_RAW];
    uint32_t count = bins >= 2 && bins <= NF_MAX_SPLINE_BINS ? 3 * bins + 1 : MAX_RAW;
    for (uint32_t i = 0; i < count; ++i)
        raw[i] = next_f32(&r);
    float x = next_f32(&r), y = next_f32(&r);
    check_spline(bins, raw, x, y);

    float v = next_f32(&r), blob[NF_MAX_ONEBLOB_BINS];
    uint32_t blob_bins = 2u + bins % (NF_MAX_ONEBLOB_BINS - 1u);
    nf_encode_oneblob(v, blob_bins, blob);
    for (uint32_t j = 0; j < blob_bins; ++j)
        NF_FUZZ_CHECK(isfinite(blob[j]) && blob[j] >= -1e-3f && blob[j] <= 1.001f,
                      "one-blob v = %g, bin %u of %u: %g", (double)v, j, blob_bins,
                      (double)blob[j]);

    float dir[3] = {next_f32(&r), next_f32(&r), next_f32(&r)};
    float sh[NF_MAX_SH_BANDS * NF_MAX_SH_BANDS];
    nf_encode_sh(dir, bands, sh);
    for (uint32_t j = 0; j < bands * bands; ++j)
        NF_FUZZ_CHECK(isfinite(sh[j]) && fabsf(sh[j]) <= 1.0f, "sh %u of (%g, %g, %g): %g", j,
                      (double)dir[0], (double)dir[1], (double)dir[2], (double)sh[j]);

    float s[2];
    nf_direction_to_square(dir, s);
    NF_FUZZ_CHECK(s[0] >= 0.0f && s[0] <= 1.0f && s[1] >= 0.0f && s[1] < 1.0f,
                  "square of (%g, %g, %g): (%g, %g)", (double)dir[0], (double)dir[1],
                  (double)dir[2], (double)s[0], (double)s[1]);

    float t[2] = {next_f32(&r), next_f32(&r)}, w[3];
    nf_square_to_direction(t, w);
    double len = sqrt((double)w[0] * w[0] + (double)w[1] * w[1] + (double)w[2] * w[2]);
    NF_FUZZ_CHECK(fabs(len - 1.0) <= 2e-6, "direction of (%g, %g) has length %.9g", (double)t[0],
                  (double)t[1], len);
    return 0;
}
