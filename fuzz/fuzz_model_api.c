/*
 * fuzz_model_api.c - libFuzzer target: whatever loads from hostile bytes must be safe to use
 * (docs/robustness.md). The input is a model file (its checksum is recomputed, so mutations
 * reach the content); when it loads, the whole API runs on it, on contexts and directions
 * at the poles, on the seam, along the axes, far outside the scene bounds and of odd
 * lengths, with u at the ends of [0, 1). Invariants, checked by abort():
 *   - nf_sample succeeds with unit directions and finite, positive densities;
 *   - nf_pdf and nf_prior_pdf give finite, positive densities;
 *   - nf_loss_gradient gives a finite loss and gradient, or NF_ERROR_NUMERIC;
 *   - nf_train_step succeeds with finite parameters, or is refused with NF_ERROR_NUMERIC and
 *     leaves the model bit-identical;
 *   - nf_model_clone and a save / load round trip give identical bytes.
 * The parameters are whatever the input holds: any finite float, up to +-FLT_MAX.
 */
#include <float.h>

#include "fuzz_common.h"

enum { N = 24 };

static const float dirs[][3] = {
    {0.0f, 0.0f, 1.0f},    {0.0f, 0.0f, -1.0f},  {1.0f, 0.0f, 0.0f},    {-1.0f, 0.0f, 0.0f},
    {0.0f, 1.0f, 0.0f},    {0.0f, -1.0f, 0.0f},  {1.0f, -1e-7f, 0.0f},  {1.0f, -0.0f, 0.3f},
    {1e-7f, 0.0f, -1.0f},  {0.3f, 0.4f, 0.5f},   {-0.6f, 0.2f, -0.7f},  {1e30f, -1e30f, 1e29f},
    {1e-15f, 2e-15f, 0.0f}, {FLT_MAX, 0.0f, FLT_MAX}, {0.0f, FLT_TRUE_MIN, 1.0f},
    {-1.0f, -1e-30f, 0.0f},
};
#define DIRS (sizeof dirs / sizeof dirs[0])

static const float positions[][3] = {
    {0.5f, 0.5f, 0.5f}, {0.0f, 0.0f, 0.0f}, {1.0f, 1.0f, 1.0f}, {-1e30f, 1e30f, 0.5f},
    {FLT_MAX, -FLT_MAX, FLT_MAX}, {2.0f, -3.0f, 0.25f},
};
#define POSITIONS (sizeof positions / sizeof positions[0])

static const float us[] = {0.0f, 1e-7f, 0.25f, 0.5f, 0.98999995f, 0.99f, 0x1.fffffep-1f, 1.0f};
#define US (sizeof us / sizeof us[0])

static void make_batch(const uint8_t *data, size_t size, nf_context *ctx, float *u, float *dir,
                       float *w)
{
    for (int i = 0; i < N; ++i) {
        /* Vary the combinations with the input, so the fuzzer can steer them a little. */
        size_t k = size ? data[(size_t)i * 7u % size] : 0u;
        const float *n = dirs[(i + k) % DIRS], *d = dirs[(3u * (size_t)i + k / 3u) % DIRS];
        memcpy(ctx[i].position, positions[(i + k / 5u) % POSITIONS], sizeof ctx[i].position);
        memcpy(ctx[i].normal, n, sizeof ctx[i].normal);
        for (int a = 0; a < 3; ++a)
            ctx[i].wo[a] = (i % 3 == 0) ? -n[a] : (i % 3 == 1 ? n[a] : d[a]);
        u[2 * i] = us[(i + k) % US];
        u[2 * i + 1] = us[(i * 5 + k / 7u) % US];
        memcpy(dir + 3 * i, d, 3 * sizeof(float));
        /* weights from 0 to 1e30 */
        w[i] = (i % 4 == 0) ? 0.0f : powf(10.0f, (float)((k + (size_t)i) % 61u) - 30.0f);
    }
}

static void check_finite_positive(float v, const char *what, int i)
{
    NF_FUZZ_CHECK(isfinite(v) && v > 0.0f, "%s[%d] = %g", what, i, (double)v);
}

static void exercise(nf_model *m, const uint8_t *data, size_t size)
{
    nf_context ctx[N];
    float u[2 * N], dir[3 * N], w[N], out_dir[3 * N], pdf[N];
    make_batch(data, size, ctx, u, dir, w);

    NF_FUZZ_CHECK(nf_sample(m, N, ctx, u, out_dir, pdf) == NF_OK, "nf_sample");
    for (int i = 0; i < N; ++i) {
        const float *d = out_dir + 3 * i;
        double len = sqrt((double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2]);
        /* tests/test_numeric_robustness.c: unit within 2e-6 */
        NF_FUZZ_CHECK(fabs(len - 1.0) <= 2e-6, "sample %d has length %.9g", i, len);
        check_finite_positive(pdf[i], "sample pdf", i);
    }
    NF_FUZZ_CHECK(nf_pdf(m, N, ctx, out_dir, pdf) == NF_OK, "nf_pdf of samples");
    for (int i = 0; i < N; ++i)
        check_finite_positive(pdf[i], "pdf of sample", i);
    NF_FUZZ_CHECK(nf_pdf(m, N, ctx, dir, pdf) == NF_OK, "nf_pdf");
    for (int i = 0; i < N; ++i) {
        check_finite_positive(pdf[i], "pdf", i);
        check_finite_positive(nf_prior_pdf(m, &ctx[i], dir + 3 * i), "prior pdf", i);
    }

    const size_t count = nf_param_count(m);
    float *grad = (float *)malloc(count * sizeof *grad);
    NF_FUZZ_CHECK(grad != NULL, "malloc");
    float loss = NAN;
    nf_status st = nf_loss_gradient(m, N, ctx, dir, w, &loss, grad);
    NF_FUZZ_CHECK(st == NF_OK || st == NF_ERROR_NUMERIC, "nf_loss_gradient status %d", (int)st);
    if (st == NF_OK) {
        NF_FUZZ_CHECK(isfinite(loss), "loss %g", (double)loss);
        for (size_t i = 0; i < count; ++i)
            NF_FUZZ_CHECK(isfinite(grad[i]), "grad[%zu] = %g", i, (double)grad[i]);
    }

    size_t before_size = 0, after_size = 0;
    unsigned char *before = nf_fuzz_serialize(m, &before_size);
    NF_FUZZ_CHECK(before != NULL, "serialize");
    st = nf_train_step(m, N, ctx, dir, w, &loss);
    unsigned char *after = nf_fuzz_serialize(m, &after_size);
    NF_FUZZ_CHECK(after != NULL && after_size == before_size, "serialize after the step");
    if (st == NF_OK) {
        NF_FUZZ_CHECK(isfinite(loss), "train loss %g", (double)loss);
        NF_FUZZ_CHECK(nf_get_params(m, grad) == NF_OK, "get params");
        for (size_t i = 0; i < count; ++i)
            NF_FUZZ_CHECK(isfinite(grad[i]), "param[%zu] = %g after a step", i, (double)grad[i]);
    } else {
        NF_FUZZ_CHECK(st == NF_ERROR_NUMERIC, "nf_train_step status %d", (int)st);
        NF_FUZZ_CHECK(memcmp(before, after, before_size) == 0, "a refused step changed the model");
    }
    free(grad);

    /* The trained (or untouched) model: clone and round trip through bytes. */
    nf_model *copy = NULL;
    NF_FUZZ_CHECK(nf_model_clone(m, &copy) == NF_OK, "clone");
    size_t copy_size = 0;
    unsigned char *copy_bytes = nf_fuzz_serialize(copy, &copy_size);
    NF_FUZZ_CHECK(copy_bytes && copy_size == after_size &&
                      memcmp(copy_bytes, after, after_size) == 0, "the clone differs");
    const nf_prior_callbacks cb = nf_fuzz_callbacks();
    nf_model *back = NULL;
    NF_FUZZ_CHECK(nf_model_deserialize(after, after_size, &cb, &back) == NF_OK, "reload");
    nf_model_destroy(back);
    nf_model_destroy(copy);
    free(copy_bytes);
    free(before);
    free(after);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < NF_FUZZ_HEADER + NF_FUZZ_TRAILER)
        return 0;
    unsigned char *copy = (unsigned char *)malloc(size);
    if (!copy)
        return 0;
    memcpy(copy, data, size);
    nf_fuzz_fix_crc(copy, size);
    const nf_prior_callbacks cb = nf_fuzz_callbacks();
    nf_model *m = NULL;
    if (nf_model_deserialize(copy, size, &cb, &m) == NF_OK)
        exercise(m, data, size);
    nf_model_destroy(m);
    free(copy);
    return 0;
}
