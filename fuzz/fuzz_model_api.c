/*
 * fuzz_model_api.c - libFuzzer target: whatever loads from hostile bytes must be safe to use
 * (docs/robustness.md). The input is a model file (its checksum is recomputed, so mutations
 * reach the content); when it loads, the whole API runs on it, on contexts and directions
 * at the poles, on the seam, along the axes, far outside the scene bounds and of odd
 * lengths, with u at the ends of [0, 1). Invariants, checked by abort():
 *   - nf_sample succeeds with unit directions and finite, positive densities;
 *   - nf_pdf and nf_model_prior_pdf give finite, positive densities;
 *   - nf_loss_gradient gives a finite loss and gradient, or NF_ERROR_NUMERIC, and
 *     nf_loss_gradient_with_work the same status and bits;
 *   - nf_train_step succeeds with finite parameters, or is refused with NF_ERROR_NUMERIC and
 *     leaves the model bit-identical;
 *   - nf_model_clone and a save / load round trip give identical bytes;
 *   - shading points (point.h) prepared at every context give the same bits as nf_sample
 *     and nf_pdf (the batch of 24 runs tiled; the points one by one and as a batch), with the
 *     model's prior callbacks or per-point ones; after an accepted training step they are
 *     NF_ERROR_STALE and write nothing, after a refused one they still give the same bits;
 *     the clone refuses them with NF_ERROR_INVALID_ARGUMENT.
 * The parameters are whatever the input holds: any finite float, up to +-FLT_MAX.
 * (fuzz_point.c drives the shading-point API with hostile contexts and points.)
 */
#include <float.h>

#include "fuzz_common.h"
#include "gradient.h"
#include "point_batch.h"
#include "shading_point.h"

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

/* The shading points of the batch's contexts against the batch calls' bits: dir_ref and
 * pdf_ref from nf_sample(u), eval_ref from nf_pdf(dir). */
static void check_points(const nf_model *m, const nf_shading_point *pts, const float *u,
                         const float *dir, const float *dir_ref, const float *pdf_ref,
                         const float *eval_ref)
{
    float d[3 * N], p[N], e[N];
    for (int i = 0; i < N; ++i) {
        NF_FUZZ_CHECK(nf_point_sample(m, &pts[i], 1, u + 2 * i, d + 3 * i, p + i) == NF_OK,
                      "nf_point_sample %d", i);
        NF_FUZZ_CHECK(nf_point_pdf(m, &pts[i], 1, dir + 3 * i, e + i) == NF_OK,
                      "nf_point_pdf %d", i);
    }
    NF_FUZZ_CHECK(memcmp(d, dir_ref, sizeof d) == 0 && memcmp(p, pdf_ref, sizeof p) == 0,
                  "nf_point_sample differs from nf_sample");
    NF_FUZZ_CHECK(memcmp(e, eval_ref, sizeof e) == 0, "nf_point_pdf differs from nf_pdf");
    NF_FUZZ_CHECK(nf_point_sample_batch(m, N, pts, u, d, p) == NF_OK, "nf_point_sample_batch");
    NF_FUZZ_CHECK(nf_point_pdf_batch(m, N, pts, dir, e) == NF_OK, "nf_point_pdf_batch");
    NF_FUZZ_CHECK(memcmp(d, dir_ref, sizeof d) == 0 && memcmp(p, pdf_ref, sizeof p) == 0,
                  "nf_point_sample_batch differs from nf_sample");
    NF_FUZZ_CHECK(memcmp(e, eval_ref, sizeof e) == 0, "nf_point_pdf_batch differs from nf_pdf");
}

/* Every function refuses the points on `m` with `expected` and writes nothing. */
static void check_points_refused(const nf_model *m, const nf_shading_point *pts,
                                 const float *u, const float *dir, nf_status expected)
{
    const float sentinel = -3.5e33f;
    float d[3 * N], p[N];
    for (int i = 0; i < 3 * N; ++i)
        d[i] = sentinel;
    for (int i = 0; i < N; ++i)
        p[i] = sentinel;
    nf_status st[4] = {nf_point_sample(m, &pts[N - 1], N, u, d, p),
                       nf_point_pdf(m, &pts[0], N, dir, p), nf_point_sample_batch(m, N, pts, u, d, p),
                       nf_point_pdf_batch(m, N, pts, dir, p)};
    for (int k = 0; k < 4; ++k)
        NF_FUZZ_CHECK(st[k] == expected, "point call %d: status %d, expected %d", k, (int)st[k],
                      (int)expected);
    for (int i = 0; i < 3 * N; ++i)
        NF_FUZZ_CHECK(memcmp(&d[i], &sentinel, sizeof sentinel) == 0, "a refused call wrote");
    for (int i = 0; i < N; ++i)
        NF_FUZZ_CHECK(memcmp(&p[i], &sentinel, sizeof sentinel) == 0, "a refused call wrote");
}

static void exercise(nf_model *m, const uint8_t *data, size_t size)
{
    nf_context ctx[N];
    float u[2 * N], dir[3 * N], w[N], out_dir[3 * N], pdf[N];
    float ref_dir[3 * N], ref_pdf[N], ref_eval[N];
    static nf_shading_point pts[N];
    make_batch(data, size, ctx, u, dir, w);

    NF_FUZZ_CHECK(nf_sample(m, N, ctx, u, out_dir, pdf) == NF_OK, "nf_sample");
    memcpy(ref_dir, out_dir, sizeof ref_dir);
    memcpy(ref_pdf, pdf, sizeof ref_pdf);
    for (int i = 0; i < N; ++i) {
        const float *d = out_dir + 3 * i;
        double len = sqrt((double)d[0] * d[0] + (double)d[1] * d[1] + (double)d[2] * d[2]);
        /* tests/robustness/test_numeric_robustness.c: unit within 2e-6 */
        NF_FUZZ_CHECK(fabs(len - 1.0) <= 2e-6, "sample %d has length %.9g", i, len);
        check_finite_positive(pdf[i], "sample pdf", i);
    }
    NF_FUZZ_CHECK(nf_pdf(m, N, ctx, out_dir, pdf) == NF_OK, "nf_pdf of samples");
    for (int i = 0; i < N; ++i)
        check_finite_positive(pdf[i], "pdf of sample", i);
    NF_FUZZ_CHECK(nf_pdf(m, N, ctx, dir, pdf) == NF_OK, "nf_pdf");
    for (int i = 0; i < N; ++i) {
        check_finite_positive(pdf[i], "pdf", i);
        float q = -1.0f;
        NF_FUZZ_CHECK(nf_model_prior_pdf(m, &ctx[i], dir + 3 * i, &q) == NF_OK,
                      "nf_model_prior_pdf");
        check_finite_positive(q, "prior pdf", i);
    }
    memcpy(ref_eval, pdf, sizeof ref_eval);

    /* Shading points at every context; on a custom-prior model every other one with
     * per-point callbacks (the same functions with a user pointer of their own). */
    nf_config cfg;
    NF_FUZZ_CHECK(nf_model_get_config(m, &cfg) == NF_OK, "nf_model_get_config");
    nf_prior_callbacks own = nf_fuzz_callbacks();
    own.user = pts;
    for (int i = 0; i < N; ++i) {
        const nf_prior_callbacks *prior = cfg.prior == NF_PRIOR_CUSTOM && i % 2 ? &own : NULL;
        NF_FUZZ_CHECK(nf_point_prepare(m, &ctx[i], prior, &pts[i]) == NF_OK,
                      "nf_point_prepare %d", i);
    }
    check_points(m, pts, u, dir, ref_dir, ref_pdf, ref_eval);

    const size_t count = nf_model_param_count(m);
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
    /* The same call with its work area in caller memory (misaligned on purpose): the same
     * status, and the same bits. */
    const size_t work_bytes = nf_training_work_bytes();
    unsigned char *work = (unsigned char *)malloc(work_bytes + 1);
    float *grad2 = (float *)malloc(count * sizeof *grad2);
    NF_FUZZ_CHECK(work != NULL && grad2 != NULL, "malloc");
    float loss2 = NAN;
    nf_status st2 =
        nf_loss_gradient_with_work(m, N, ctx, dir, w, &loss2, grad2, work + 1, work_bytes);
    NF_FUZZ_CHECK(st2 == st, "nf_loss_gradient_with_work status %d, nf_loss_gradient %d",
                  (int)st2, (int)st);
    NF_FUZZ_CHECK(st != NF_OK || (memcmp(&loss, &loss2, sizeof loss) == 0 &&
                                  memcmp(grad, grad2, count * sizeof *grad) == 0),
                  "nf_loss_gradient_with_work differs from nf_loss_gradient");
    free(work);
    free(grad2);

    size_t before_size = 0, after_size = 0;
    unsigned char *before = nf_fuzz_serialize(m, &before_size);
    NF_FUZZ_CHECK(before != NULL, "serialize");
    st = nf_train_step(m, N, ctx, dir, w, &loss);
    unsigned char *after = nf_fuzz_serialize(m, &after_size);
    NF_FUZZ_CHECK(after != NULL && after_size == before_size, "serialize after the step");
    if (st == NF_OK) {
        NF_FUZZ_CHECK(isfinite(loss), "train loss %g", (double)loss);
        NF_FUZZ_CHECK(nf_model_get_params(m, grad) == NF_OK, "get params");
        for (size_t i = 0; i < count; ++i)
            NF_FUZZ_CHECK(isfinite(grad[i]), "param[%zu] = %g after a step", i, (double)grad[i]);
        /* A step with positive weights changed the parameters: the points are stale. */
        check_points_refused(m, pts, u, dir, NF_ERROR_STALE);
    } else {
        NF_FUZZ_CHECK(st == NF_ERROR_NUMERIC, "nf_train_step status %d", (int)st);
        NF_FUZZ_CHECK(memcmp(before, after, before_size) == 0, "a refused step changed the model");
        check_points(m, pts, u, dir, ref_dir, ref_pdf, ref_eval);
    }
    free(grad);

    /* The trained (or untouched) model: clone and round trip through bytes. */
    nf_model *copy = NULL;
    NF_FUZZ_CHECK(nf_model_clone(m, &copy) == NF_OK, "clone");
    size_t copy_size = 0;
    unsigned char *copy_bytes = nf_fuzz_serialize(copy, &copy_size);
    NF_FUZZ_CHECK(copy_bytes && copy_size == after_size &&
                      memcmp(copy_bytes, after, after_size) == 0, "the clone differs");
    check_points_refused(copy, pts, u, dir, NF_ERROR_INVALID_ARGUMENT);
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
    if (size < NF_FUZZ_HEADER_V1 + NF_FUZZ_TRAILER)
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
