/*
 * kernel.c - the kernels behind nf_sample, nf_pdf, the shading-point API, nf_loss_gradient and
 * the AdamW step. CMake compiles this file once per instruction set with NF_KERNEL_ISA set to
 * generic, avx2 or avx512 (and the matching -m flags); each copy defines the table
 * nf_kernels_<isa> (kernels.h). Inputs arrive validated from flow.c, point.c and train.c.
 * nf_sample and nf_pdf run on tiles of 16 samples (flow_tile.h), or through a shading point on
 * the stack (point.h) for calls of 1 or 2; the shading-point API runs one direction at a time,
 * on point.h, or for the presets in the AVX2 and AVX-512 kernels on point_vector.h (two
 * directions at a point in step; the AVX-512 copy hands the small preset's points to the AVX2
 * one); the gradient runs on tiles (flow_tile_backward.h), or per sample for calls of 1 to 3.
 */
#include <float.h>
#include <math.h>

#include "flow.h"
#include "flow_tile.h"
#include "flow_tile_backward.h"
#include "internal.h"
#include "kernels.h"
#include "point.h"
#include "point_vector.h"

#ifndef NF_KERNEL_ISA
#define NF_KERNEL_ISA generic
#endif
#define NF_KERNEL_CAT2(a, b) a##b
#define NF_KERNEL_CAT(a, b) NF_KERNEL_CAT2(a, b)
#define NF_KERNEL_STR2(a) #a
#define NF_KERNEL_STR(a) NF_KERNEL_STR2(a)

/* Calls with fewer samples than this go through a shading point on the stack (point.h): a
 * tile costs nearly as much for one sample as for sixteen, since its vector loops run over
 * all lanes, and the per-sample code is cheaper up to two samples (nf_bench, batch 1). */
#define NF_TILED_FROM 3u

/* The same for the gradient, whose per-sample code is cheaper up to this many samples. */
#define NF_GRADIENT_TILED_FROM 4u

#if defined(__GNUC__) || defined(__clang__)
#define NF_FLATTEN __attribute__((flatten))
#define NF_NOINLINE __attribute__((noinline))
#else
#define NF_FLATTEN
#define NF_NOINLINE
#endif

/* The per-direction functions for one shape: flattened, so that the presets' constant shapes
 * reach every inner loop (point.h, nf_point_shape), with scratch sized for the shape, and never
 * inlined, so that any shape's largest scratch is never held twice on the caller's stack. Two
 * directions at a point are two calls. */
#define NF_POINT_VARIANT(suffix, SHAPE_EXPR, WORK_FLOATS)                                          \
    static NF_NOINLINE NF_FLATTEN nf_status nf_point_sample_##suffix(                              \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float u[2],    \
        float dir[3], float *pdf)                                                                  \
    {                                                                                              \
        nf_point_shape sh = SHAPE_EXPR;                                                            \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        float work[WORK_FLOATS];                                                                   \
        nf_point_scratch sc;                                                                       \
        nf_point_scratch_in(work, sh, &sc);                                                        \
        return nf_point_sample_one(m, sh, p, user, u, dir, pdf, &sc);                              \
    }                                                                                              \
    static NF_NOINLINE NF_FLATTEN nf_status nf_point_pdf_##suffix(                                 \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float dir[3],  \
        float *pdf)                                                                                \
    {                                                                                              \
        nf_point_shape sh = SHAPE_EXPR;                                                            \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        float work[WORK_FLOATS];                                                                   \
        nf_point_scratch sc;                                                                       \
        nf_point_scratch_in(work, sh, &sc);                                                        \
        return nf_point_pdf_one(m, sh, p, user, dir, pdf, &sc);                                    \
    }

/* A shape's two questions at one point as two calls of its functions, and its points
 * prepared with the tile's arithmetic. */
#define NF_POINT_CALL_PAIRS(suffix)                                                                \
    static void nf_point_prepare_##suffix(const nf_model *m, const nf_context *ctx,                \
                                          const nf_prior_callbacks *prior, nf_shading_point *p)    \
    {                                                                                              \
        nf_point_prepare_at(m, ctx, prior, p);                                                     \
    }                                                                                              \
    static nf_status nf_point_pdf_pair_##suffix(const nf_model *m, const nf_shading_point *p,      \
                                                const nf_context *user, const float dir[6],        \
                                                float pdf[2])                                      \
    {                                                                                              \
        nf_status st = nf_point_pdf_##suffix(m, p, user, dir, &pdf[0]);                            \
        return st != NF_OK ? st : nf_point_pdf_##suffix(m, p, user, dir + 3, &pdf[1]);             \
    }                                                                                              \
    static nf_status nf_point_sample_and_pdf_##suffix(                                             \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float u[2],    \
        float dir[3], float *pdf, const float eval_dir[3], float *eval_pdf)                        \
    {                                                                                              \
        float q;                                                                                   \
        nf_status st = nf_point_pdf_##suffix(m, p, user, eval_dir, &q);                            \
        if (st == NF_OK && (st = nf_point_sample_##suffix(m, p, user, u, dir, pdf)) == NF_OK)      \
            *eval_pdf = q;                                                                         \
        return st;                                                                                 \
    }

NF_POINT_VARIANT(small, NF_POINT_SHAPE_SMALL, NF_POINT_WORK_FLOATS(32u, 8u, 16u))
NF_POINT_VARIANT(large, NF_POINT_SHAPE_LARGE, NF_POINT_WORK_FLOATS(64u, 16u, 16u))
NF_POINT_VARIANT(any, nf_point_shape_of(m),
                 NF_POINT_WORK_FLOATS(NF_MAX_RAW_PADDED, NF_MAX_SPLINE_BINS,
                                      NF_PAD(NF_MAX_HIDDEN_WIDTH)))
NF_POINT_CALL_PAIRS(any)

/* The shading-point API's per-direction functions for one preset shape in the AVX2 and AVX-512
 * kernels (point_vector.h: vectors across units and bins, within a stated bound of the tile);
 * the same signatures as NF_POINT_VARIANT's. */
#if defined(NF_PV_AVAILABLE)
#define NF_PV_VARIANT(suffix, SHAPE)                                                               \
    static NF_NOINLINE NF_FLATTEN void nf_pv_prepare_##suffix(                                     \
        const nf_model *m, const nf_context *ctx, const nf_prior_callbacks *prior,                 \
        nf_shading_point *p)                                                                       \
    {                                                                                              \
        nf_point_shape sh = SHAPE;                                                                 \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        nf_pv_prepare(m, sh, ctx, prior, p);                                                       \
    }                                                                                              \
    static NF_NOINLINE NF_FLATTEN nf_status nf_pv_sample_##suffix(                                 \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float u[2],    \
        float dir[3], float *pdf)                                                                  \
    {                                                                                              \
        (void)user;                                                                                \
        nf_point_shape sh = SHAPE;                                                                 \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        return nf_pv_sample_one(m, sh, p, u, dir, pdf);                                            \
    }                                                                                              \
    static NF_NOINLINE NF_FLATTEN nf_status nf_pv_pdf_##suffix(                                    \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float dir[3],  \
        float *pdf)                                                                                \
    {                                                                                              \
        (void)user;                                                                                \
        nf_point_shape sh = SHAPE;                                                                 \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        return nf_pv_pdf_one(m, sh, p, dir, pdf);                                                  \
    }                                                                                              \
    static NF_NOINLINE NF_FLATTEN nf_status nf_pv_pdf_pair_##suffix(                               \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float dir[6],  \
        float pdf[2])                                                                              \
    {                                                                                              \
        (void)user;                                                                                \
        nf_point_shape sh = SHAPE;                                                                 \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        return nf_pv_pdf_pair(m, sh, p, dir, pdf);                                                 \
    }                                                                                              \
    static NF_NOINLINE NF_FLATTEN nf_status nf_pv_sample_and_pdf_##suffix(                         \
        const nf_model *m, const nf_shading_point *p, const nf_context *user, const float u[2],    \
        float dir[3], float *pdf, const float eval_dir[3], float *eval_pdf)                        \
    {                                                                                              \
        (void)user;                                                                                \
        nf_point_shape sh = SHAPE;                                                                 \
        sh.circular = m->cfg.phi_map == NF_PHI_CIRCULAR;                                           \
        return nf_pv_sample_and_pdf(m, sh, p, u, dir, pdf, eval_dir, eval_pdf);                    \
    }
NF_PV_VARIANT(large, NF_POINT_SHAPE_LARGE)
#define NF_PV_LARGE(name) nf_pv_##name##_large
#else
NF_POINT_CALL_PAIRS(large)
#define NF_PV_LARGE(name) nf_point_##name##_large
#endif

/* The AVX-512 kernels hand the small preset's shading points (prepare, sample, pdf) to the
 * AVX2 kernels, whose 8-lane layer gives the same bits (test_point): on an AVX-512 Xeon the
 * 512-bit layer slowed a per-path renderer as a whole, beyond what its own calls cost
 * (docs/performance.md, "The small preset's points on 256-bit code"). The large preset's 16
 * bins fill a 16-lane register, and its 512-bit layer measured faster. */
#if defined(NF_PV_AVAILABLE) && defined(__AVX512F__) && defined(NF_HAVE_X86_KERNELS)
#define NF_POINT_SMALL_KERNELS (&nf_kernels_avx2)
#endif

/* The small preset's functions where these kernels run its points themselves; in the AVX-512
 * kernels the same-bits ones stand in the tables, never reached (NF_POINT_SMALL_KERNELS). */
#if defined(NF_PV_AVAILABLE) && !defined(NF_POINT_SMALL_KERNELS)
NF_PV_VARIANT(small, NF_POINT_SHAPE_SMALL)
#define NF_PV_SMALL(name) nf_pv_##name##_small
#else
NF_POINT_CALL_PAIRS(small)
#define NF_PV_SMALL(name) nf_point_##name##_small
#endif

typedef nf_status (*nf_point_sample_fn)(const nf_model *, const nf_shading_point *,
                                        const nf_context *, const float *, float *, float *);
typedef nf_status (*nf_point_pdf_fn)(const nf_model *, const nf_shading_point *, const nf_context *,
                                     const float *, float *);

/* The variant for the model's shape, an index into the tables below: any shape, the small
 * preset's, the large preset's. Comparing the shape costs a few compares per call, far less
 * than what the constants save. */
enum { NF_VARIANT_ANY, NF_VARIANT_SMALL, NF_VARIANT_LARGE };

static int nf_point_variant(const nf_model *m)
{
    const nf_point_shape small = NF_POINT_SHAPE_SMALL, large = NF_POINT_SHAPE_LARGE;
    nf_point_shape sh = nf_point_shape_of(m);
    return nf_point_shape_equal(sh, small)   ? NF_VARIANT_SMALL
           : nf_point_shape_equal(sh, large) ? NF_VARIANT_LARGE
                                             : NF_VARIANT_ANY;
}

/* The kernels that run this model's shading points instead of these (NF_POINT_SMALL_KERNELS),
 * or NULL where these run them. */
static const nf_kernels *nf_points_elsewhere(const nf_model *m)
{
#if defined(NF_POINT_SMALL_KERNELS)
    return nf_point_variant(m) == NF_VARIANT_SMALL ? NF_POINT_SMALL_KERNELS : NULL;
#else
    (void)m;
    return NULL;
#endif
}

static nf_point_sample_fn nf_point_sampler(const nf_model *m)
{
    static const nf_point_sample_fn fns[3] = {nf_point_sample_any, nf_point_sample_small,
                                              nf_point_sample_large};
    return fns[nf_point_variant(m)];
}

static nf_point_pdf_fn nf_point_evaluator(const nf_model *m)
{
    static const nf_point_pdf_fn fns[3] = {nf_point_pdf_any, nf_point_pdf_small,
                                           nf_point_pdf_large};
    return fns[nf_point_variant(m)];
}

/* The public shading-point API's functions: the presets' vector path where the kernels have
 * one (point_vector.h), the same-bits path for other shapes and instruction sets. Small
 * nf_sample / nf_pdf calls keep the same-bits path, so that they agree with tiles. */
static nf_point_sample_fn nf_point_api_sampler(const nf_model *m)
{
    static const nf_point_sample_fn fns[3] = {nf_point_sample_any, NF_PV_SMALL(sample),
                                              NF_PV_LARGE(sample)};
    return fns[nf_point_variant(m)];
}

static nf_point_pdf_fn nf_point_api_evaluator(const nf_model *m)
{
    static const nf_point_pdf_fn fns[3] = {nf_point_pdf_any, NF_PV_SMALL(pdf), NF_PV_LARGE(pdf)};
    return fns[nf_point_variant(m)];
}

typedef void (*nf_point_prepare_fn)(const nf_model *, const nf_context *,
                                    const nf_prior_callbacks *, nf_shading_point *);

static nf_point_prepare_fn nf_point_api_preparer(const nf_model *m)
{
    static const nf_point_prepare_fn fns[3] = {nf_point_prepare_any, NF_PV_SMALL(prepare),
                                               NF_PV_LARGE(prepare)};
    return fns[nf_point_variant(m)];
}

static nf_point_pdf_fn nf_point_api_pair_evaluator(const nf_model *m)
{
    static const nf_point_pdf_fn fns[3] = {nf_point_pdf_pair_any, NF_PV_SMALL(pdf_pair),
                                           NF_PV_LARGE(pdf_pair)};
    return fns[nf_point_variant(m)];
}

/* A point prepared on the stack for one context of a small nf_sample / nf_pdf call: the
 * shading-point path, with callbacks receiving the caller's own context as documented. */
static nf_status nf_sample_one(const nf_model *m, const nf_context *ctx, const float u[2],
                               float dir[3], float *pdf)
{
    nf_shading_point p;
    nf_point_prepare_at(m, ctx, NULL, &p);
    return nf_point_sampler(m)(m, &p, ctx, u, dir, pdf);
}

static nf_status nf_pdf_one(const nf_model *m, const nf_context *ctx, const float dir[3],
                            float *pdf)
{
    nf_shading_point p;
    nf_point_prepare_at(m, ctx, NULL, &p);
    return nf_point_evaluator(m)(m, &p, ctx, dir, pdf);
}

/* nf_point_prepare. */
static void nf_kernel_point_prepare(const nf_model *m, const nf_context *ctx,
                                    const nf_prior_callbacks *prior, nf_shading_point *point)
{
    const nf_kernels *elsewhere = nf_points_elsewhere(m);
    if (elsewhere) {
        elsewhere->point_prepare(m, ctx, prior, point);
        return;
    }
    nf_point_api_preparer(m)(m, ctx, prior, point);
}

/* nf_point_sample (stride 0: one point, n directions) and nf_point_sample_batch (stride 1). */
static nf_status nf_kernel_point_sample(const nf_model *m, const nf_shading_point *points, size_t n,
                                        size_t stride, const float *u, float *dir, float *pdf)
{
    const nf_kernels *elsewhere = nf_points_elsewhere(m);
    if (elsewhere)
        return elsewhere->point_sample(m, points, n, stride, u, dir, pdf);
    const nf_point_sample_fn sample = nf_point_api_sampler(m);
    for (size_t i = 0; i < n; ++i) {
        const nf_shading_point *p = points + i * stride;
        nf_status st = sample(m, p, &p->context_, u + 2 * i, dir + 3 * i, pdf ? pdf + i : NULL);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

static nf_status nf_kernel_point_pdf(const nf_model *m, const nf_shading_point *points, size_t n,
                                     size_t stride, const float *dir, float *pdf)
{
    const nf_kernels *elsewhere = nf_points_elsewhere(m);
    if (elsewhere)
        return elsewhere->point_pdf(m, points, n, stride, dir, pdf);
    const nf_point_pdf_fn eval = nf_point_api_evaluator(m);
    size_t i = 0;
    if (stride == 0) /* directions at one point: two at a time, in step (point.h) */
        for (const nf_point_pdf_fn pair = nf_point_api_pair_evaluator(m); i + 2 <= n; i += 2) {
            nf_status st = pair(m, points, &points->context_, dir + 3 * i, pdf + i);
            if (st != NF_OK)
                return st;
        }
    for (; i < n; ++i) {
        const nf_shading_point *p = points + i * stride;
        nf_status st = eval(m, p, &p->context_, dir + 3 * i, pdf + i);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

/* nf_point_sample_and_pdf: a draw and another direction's density, in step. */
static nf_status nf_kernel_point_sample_and_pdf(const nf_model *m, const nf_shading_point *p,
                                                const float u[2], float dir[3], float *pdf,
                                                const float eval_dir[3], float *eval_pdf)
{
    const nf_kernels *elsewhere = nf_points_elsewhere(m);
    if (elsewhere)
        return elsewhere->point_sample_and_pdf(m, p, u, dir, pdf, eval_dir, eval_pdf);
    typedef nf_status (*fn)(const nf_model *, const nf_shading_point *, const nf_context *,
                            const float *, float *, float *, const float *, float *);
    static const fn fns[3] = {nf_point_sample_and_pdf_any, NF_PV_SMALL(sample_and_pdf),
                              NF_PV_LARGE(sample_and_pdf)};
    return fns[nf_point_variant(m)](m, p, &p->context_, u, dir, pdf, eval_dir, eval_pdf);
}

/* Tiles of NF_TILE samples (flow_tile.h): the scratch is declared once per call. */
static nf_status nf_kernel_sample(const nf_model *m, size_t n, const nf_context *ctx,
                                  const float *u, float *dir, float *pdf)
{
    if (n < NF_TILED_FROM) {
        for (size_t i = 0; i < n; ++i) {
            nf_status st = nf_sample_one(m, &ctx[i], u + 2 * i, dir + 3 * i, pdf ? pdf + i : NULL);
            if (st != NF_OK)
                return st;
        }
        return NF_OK;
    }
    nf_tile_work w;
    for (size_t i = 0; i < n; i += NF_TILE) {
        uint32_t count = (uint32_t)(n - i < NF_TILE ? n - i : NF_TILE);
        nf_status st =
            nf_tile_sample(m, ctx + i, u + 2 * i, count, dir + 3 * i, pdf ? pdf + i : NULL, &w);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

static nf_status nf_kernel_pdf(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                               float *pdf)
{
    if (n < NF_TILED_FROM) {
        for (size_t i = 0; i < n; ++i) {
            nf_status st = nf_pdf_one(m, &ctx[i], dir + 3 * i, pdf + i);
            if (st != NF_OK)
                return st;
        }
        return NF_OK;
    }
    nf_tile_work w;
    for (size_t i = 0; i < n; i += NF_TILE) {
        uint32_t count = (uint32_t)(n - i < NF_TILE ? n - i : NF_TILE);
        nf_status st = nf_tile_pdf(m, ctx + i, dir + 3 * i, count, pdf + i, &w);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

/* The per-sample gradient of flow.h, for calls too small to fill a tile. */
static nf_status nf_gradient_per_sample(const nf_model *m, size_t n, const nf_context *ctx,
                                        const float *dir, const float *weight, double total,
                                        double *loss, float *grad)
{
    nf_scratch sc;
    double acc = 0.0;
    for (size_t i = 0; i < n; ++i) {
        if (weight[i] == 0.0f)
            continue; /* contributes nothing, and its context need not be evaluated */
        nf_point pt;
        nf_context_features(m, &ctx[i], &pt);
        float s[2];
        double p_s = 0.0, log_p = 0.0, share = (double)weight[i] / total;
        nf_to_square(dir + 3 * i, s);
        nf_status st = nf_flow_density(m, &pt, s, (float)-share, grad, &p_s, &log_p, &sc);
        if (st != NF_OK)
            return st;
        /* log p_w = log p_s - log(2 pi^2 sin theta) */
        double sin_theta = (double)nf_maxf(nf_sin_pi(s[0]), NF_SIN_THETA_MIN);
        acc -= share * (log_p - log((double)NF_TWO_PI_SQUARED * sin_theta));
    }
    *loss = acc;
    return NF_OK;
}

/* Samples with weight zero contribute nothing and are left out, so tiles are filled with the
 * others, in order: the loss is summed in the same order as by the per-sample code. */
static nf_status nf_gradient_tiles(const nf_model *m, size_t n, const nf_context *ctx,
                                   const float *dir, const float *weight, double total,
                                   double *loss, float *grad, nf_tile_gradient_work *w)
{
    const nf_context *tile_ctx[NF_TILE];
    const float *tile_dir[NF_TILE];
    double share[NF_TILE], acc = 0.0;
    uint32_t count = 0;
    for (size_t i = 0; i < n; ++i) {
        if (weight[i] == 0.0f)
            continue;
        tile_ctx[count] = &ctx[i];
        tile_dir[count] = dir + 3 * i;
        share[count] = (double)weight[i] / total;
        if (++count < NF_TILE)
            continue;
        nf_status st = nf_tile_gradient(m, tile_ctx, tile_dir, share, count, grad, &acc, w);
        if (st != NF_OK)
            return st;
        count = 0;
    }
    if (count > 0) {
        nf_status st = nf_tile_gradient(m, tile_ctx, tile_dir, share, count, grad, &acc, w);
        if (st != NF_OK)
            return st;
    }
    *loss = acc;
    return NF_OK;
}

/* The work area on the stack, in a frame of its own: inlined into nf_kernel_gradient, its
 * 160 KiB would be reserved for calls that bring their own work area too. */
__attribute__((noinline)) static nf_status nf_gradient_tiles_on_stack(
    const nf_model *m, size_t n, const nf_context *ctx, const float *dir, const float *weight,
    double total, double *loss, float *grad)
{
    nf_tile_gradient_work w;
    return nf_gradient_tiles(m, n, ctx, dir, weight, total, loss, grad, &w);
}

static nf_status nf_kernel_gradient(const nf_model *m, size_t n, const nf_context *ctx,
                                    const float *dir, const float *weight, double total,
                                    double *loss, float *grad, void *work)
{
    if (n < NF_GRADIENT_TILED_FROM)
        return nf_gradient_per_sample(m, n, ctx, dir, weight, total, loss, grad);
    if (work)
        return nf_gradient_tiles(m, n, ctx, dir, weight, total, loss, grad,
                                 (nf_tile_gradient_work *)work);
    return nf_gradient_tiles_on_stack(m, n, ctx, dir, weight, total, loss, grad);
}

/* AdamW here rather than in train.c so that it runs in the widest vectors the CPU has: sqrt
 * and division are correctly rounded in every instruction set, so the variants agree to the
 * bit. The arrays are restrict parameters (GCC ignores restrict on local pointers) and the
 * constants are locals: with six arrays that might overlap, or a store that might change
 * beta1, GCC needs more run-time alias checks than it will emit and leaves the loop scalar.
 * The finiteness of the results is checked in a second pass over them: folded into the
 * first loop, the test kept GCC 12 from vectorizing it. */
static int nf_kernel_adamw(const nf_adamw_step *step, size_t count, const float *restrict g,
                           const float *restrict p, const float *restrict m,
                           const float *restrict v, float *restrict p_new, float *restrict m_new,
                           float *restrict v_new)
{
    const float beta1 = step->beta1, beta2 = step->beta2, epsilon = step->epsilon;
    const float step_size = step->step_size, inv_sqrt_bias2 = step->inv_sqrt_bias2;
    const float decay = step->decay;
    for (size_t i = 0; i < count; ++i) {
        float mi = beta1 * m[i] + (1.0f - beta1) * g[i];
        float vi = beta2 * v[i] + (1.0f - beta2) * g[i] * g[i];
        /* Moments of parameters that receive no gradient (one-blob rows never hit) decay
         * geometrically into subnormals, which cost ~100 cycles per operation on x86: a
         * single-sample training loop slowed 5x over 4000 steps. Flushing them here, rather
         * than setting FTZ in the caller's floating-point environment, changes the step by
         * less than FLT_MIN / sqrt(FLT_MIN) ~ 1e-19. */
        mi = fabsf(mi) < FLT_MIN ? 0.0f : mi;
        vi = vi < FLT_MIN ? 0.0f : vi;
        float denom = sqrtf(vi) * inv_sqrt_bias2 + epsilon;
        p_new[i] = p[i] * decay - step_size * mi / denom;
        m_new[i] = mi;
        v_new[i] = vi;
    }
    return nf_floats_finite(p_new, count) && nf_floats_finite(m_new, count) &&
           nf_floats_finite(v_new, count);
}

const nf_kernels NF_KERNEL_CAT(nf_kernels_, NF_KERNEL_ISA) = {NF_KERNEL_STR(NF_KERNEL_ISA),
                                                              nf_kernel_sample,
                                                              nf_kernel_pdf,
                                                              nf_kernel_gradient,
                                                              nf_kernel_point_prepare,
                                                              nf_kernel_point_sample,
                                                              nf_kernel_point_pdf,
                                                              nf_kernel_point_sample_and_pdf,
                                                              nf_kernel_adamw,
                                                              sizeof(nf_tile_gradient_work)};
_Static_assert(_Alignof(nf_tile_gradient_work) <= NF_WORK_ALIGN,
               "a caller's work area is aligned to NF_WORK_ALIGN");
