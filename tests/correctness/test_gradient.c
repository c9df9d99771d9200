/*
 * test_gradient.c - nf_loss_gradient's hand-written reverse mode against central differences
 * of the loss it returns, for every built-in prior and both presets, on models far from the
 * identity; the loss's invariances (zero weights, scaled weights, sharding); and the AdamW
 * step (nf_train_step, nf_apply_gradient) against AdamW written here in double.
 *
 * The loss has kinks (spline bin edges, ReLUs), so finite differences with a large step are
 * wrong for some parameters; with steps of ~1e-3 in float they converge to the analytic
 * gradient. Errors are therefore measured as norms over many parameters.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "gradient.h"

#define BATCH 16

static const nf_prior_kind builtin_priors[3] = {NF_PRIOR_UNIFORM_DIRECTION,
                                                NF_PRIOR_UNIFORM_ANGLE, NF_PRIOR_COSINE};

typedef struct batch {
    nf_context ctx[BATCH];
    float dir[3 * BATCH];
    float weight[BATCH];
} batch;

/* A model with parameters initial + uniform(-0.3, 0.3) each (the output layers non-zero). */
static nf_model *random_model(nf_preset preset, nf_prior_kind prior, uint64_t seed)
{
    nf_model *m = nft_make_model(preset, prior);
    assert_int_equal(nft_perturb_params(m, 0.3, 0, seed, 91u), NF_OK);
    return m;
}

/* Every third context a point in a medium (zero normal) with g of either sign, so that the
 * cosine prior's Henyey-Greenstein branch and its log-gradient are checked too. */
static void make_medium(int i, nf_context *c)
{
    static const float g[4] = {0.6f, -0.8f, 0.0f, 0.9f};
    if (i % 3 != 0)
        return;
    c->normal[0] = c->normal[1] = c->normal[2] = 0.0f;
    c->phase_g = g[(i / 3) % 4];
}

/* Random contexts (with_media: every third in a medium); directions half drawn from the model
 * itself (as in training), half uniform, all away from the poles (where sin(theta) is clamped
 * and the loss has a kink); random weights in [0.1, 2). */
static void make_batch_with(const nf_model *m, uint64_t seed, int with_media, batch *b)
{
    nft_rng r;
    nft_rng_seed(&r, seed, 5u);
    for (int i = 0; i < BATCH; ++i) {
        nft_random_context(&r, &b->ctx[i]);
        if (with_media)
            make_medium(i, &b->ctx[i]);
        for (;;) {
            float *d = b->dir + 3 * i;
            if (i % 2 == 0) {
                float u[2] = {nft_rng_float(&r), nft_rng_float(&r)};
                assert_int_equal(nf_sample(m, 1, &b->ctx[i], u, d, NULL), NF_OK);
            } else {
                nft_random_unit_vector(&r, d);
            }
            if (nft_sin_theta(d) > 0.1)
                break;
        }
        b->weight[i] = 0.1f + 1.9f * nft_rng_float(&r);
    }
}

/* Surface contexts only, the batches of the tests that predate media. */
static void make_batch(const nf_model *m, uint64_t seed, batch *b)
{
    make_batch_with(m, seed, 0, b);
}

static double loss_at(const nf_model *m, const batch *b, float *grad_scratch)
{
    float loss;
    assert_int_equal(nf_loss_gradient(m, BATCH, b->ctx, b->dir, b->weight, &loss, grad_scratch),
                     NF_OK);
    assert_true(isfinite(loss));
    return loss;
}

static double norm(const double *v, size_t n)
{
    double s = 0.0;
    for (size_t i = 0; i < n; ++i)
        s += v[i] * v[i];
    return sqrt(s);
}

/* ---- finite differences ---------------------------------------------------------------------- */

/* Central differences of the loss for `n_check` parameters (all of them, or a random subset),
 * step H per parameter (the step actually taken after rounding p +- H to float is used).
 *
 * Tolerance of ||g - fd|| / ||g||: the loss is returned as a float (values ~2..5, an ulp of
 * 2.4e-7..4.8e-7), and its rounding differs between the two evaluations, so each difference
 * quotient carries a noise of ~ulp / (2 H) ~ 1.2e-4..2.4e-4 wherever the parameter influences
 * the loss; over the ~4000 (small preset, all parameters) or ~200 (a subset of 300) active
 * ones that is ~1e-2 or ~3e-3 in norm, against gradient norms of ~2 and ~0.5: 4e-3..7e-3
 * relative. The truncation error O(H^2) is far smaller, except at the few parameters whose
 * stencil straddles a kink (a ReLU switching or a sample changing spline bin), whose FD is off
 * by up to their gradient. 2e-2 allows for both (measured 3e-3..6e-3, printed). */
#define H 1e-3
#define FD_TOLERANCE 2e-2

static void check_fd_with(nf_preset preset, nf_prior_kind prior, size_t n_check, uint64_t seed,
                          int with_media)
{
    nf_model *m = random_model(preset, prior, seed);
    batch b;
    make_batch_with(m, seed + 1u, with_media, &b);
    size_t count = nf_model_param_count(m);
    float *params = malloc(count * sizeof *params), *grad = malloc(count * sizeof *grad);
    float *scratch = malloc(count * sizeof *scratch);
    size_t *index = malloc(count * sizeof *index);
    double *g = malloc(count * sizeof *g), *fd = malloc(count * sizeof *fd);
    assert_true(params && grad && scratch && index && g && fd);
    assert_int_equal(nf_model_get_params(m, params), NF_OK);
    float loss0;
    assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &loss0, grad), NF_OK);
    /* The parameters to check: a random subset (partial Fisher-Yates), or all. */
    nft_rng r;
    nft_rng_seed(&r, seed + 2u, 9u);
    for (size_t i = 0; i < count; ++i)
        index[i] = i;
    if (n_check > count)
        n_check = count;
    for (size_t i = 0; i < n_check && n_check < count; ++i) {
        size_t j = i + nft_rng_u32(&r) % (count - i);
        size_t t = index[i];
        index[i] = index[j];
        index[j] = t;
    }
    size_t nonzero = 0;
    double worst = 0.0;
    size_t worst_i = 0;
    for (size_t k = 0; k < n_check; ++k) {
        size_t i = index[k];
        float p = params[i], hi = (float)(p + H), lo = (float)(p - H);
        params[i] = hi;
        assert_int_equal(nf_model_set_params(m, params), NF_OK);
        double l_hi = loss_at(m, &b, scratch);
        params[i] = lo;
        assert_int_equal(nf_model_set_params(m, params), NF_OK);
        double l_lo = loss_at(m, &b, scratch);
        params[i] = p;
        g[k] = grad[i];
        fd[k] = (l_hi - l_lo) / ((double)hi - (double)lo);
        nonzero += grad[i] != 0.0f;
        if (fabs(g[k] - fd[k]) > worst) {
            worst = fabs(g[k] - fd[k]);
            worst_i = i;
        }
    }
    assert_int_equal(nf_model_set_params(m, params), NF_OK);
    for (size_t k = 0; k < n_check; ++k)
        fd[k] -= g[k];
    double gnorm = norm(g, n_check), err = norm(fd, n_check) / gnorm;
    print_message("%s preset %d: %zu parameters (%zu with non-zero gradient), loss %.5g, "
                  "||g|| %.4g, ||g - fd|| / ||g|| = %.3g (worst at parameter %zu: %.3g)\n",
                  nft_prior_name(prior), (int)preset, n_check, nonzero, (double)loss0, gnorm,
                  err, worst_i, worst);
    /* The gradient must be non-trivial for the comparison to mean something. */
    assert_true(gnorm > 1e-2);
    assert_true(nonzero > n_check / 20);
    if (!(err <= FD_TOLERANCE))
        fail_msg("%s preset %d: gradient differs from central differences by %.3g (relative "
                 "norm)",
                 nft_prior_name(prior), (int)preset, err);
    free(params);
    free(grad);
    free(scratch);
    free(index);
    free(g);
    free(fd);
    nf_model_destroy(m);
}

static void check_fd(nf_preset preset, nf_prior_kind prior, size_t n_check, uint64_t seed)
{
    check_fd_with(preset, prior, n_check, seed, 0);
}

/* Small preset: every parameter for the cosine prior (whose gradient also flows through the
 * prior's density), a random third of them for the other two (for speed). */
static void test_fd_small(void **state)
{
    (void)state;
    for (int p = 0; p < 3; ++p)
        check_fd(NF_PRESET_SMALL, builtin_priors[p],
                 builtin_priors[p] == NF_PRIOR_COSINE ? (size_t)-1 : 2000, 100u + (uint64_t)p);
}

static void test_fd_large(void **state)
{
    (void)state;
    for (int p = 0; p < 3; ++p)
        check_fd(NF_PRESET_LARGE, builtin_priors[p], 300, 200u + (uint64_t)p);
}

/* The cosine prior with every third context in a medium: the gradient flows through the
 * Henyey-Greenstein density's log-gradient (prior.h) and the zero normal encodings; every
 * parameter of the small preset, a subset of the large one, tolerance as above. */
static void test_fd_media(void **state)
{
    (void)state;
    /* (Seed 300's model has a parameter whose stencil straddles a kink under NF_PHI_INTERVAL,
     * 0.11 with or without media; 302 is the next.) */
    check_fd_with(NF_PRESET_SMALL, NF_PRIOR_COSINE, (size_t)-1, 302u, 1);
    check_fd_with(NF_PRESET_LARGE, NF_PRIOR_COSINE, 300, 301u, 1);
}

/* Directional derivatives: along 3 random unit directions v in parameter space and along the
 * normalized gradient, the central difference L(p + t v) - L(p - t v) against g . (p+ - p-),
 * the displacement actually taken after rounding to float. A random direction sees a
 * directional derivative of only ~||g|| / sqrt(P) ~ 5e-3..3e-2, and every kink (ReLU, bin
 * edge) that the simultaneous move of all P parameters crosses adds an error O(t^2): with
 * t = 0.02 single kinks were measured to cost 40% of such a small derivative, with t = 0.005
 * (each parameter moves by ~5e-5) they cost < 1e-6 in the loss difference. Along the gradient,
 * where the loss changes fastest and curves most (t = 0.04 is 8% off), t = 0.001. Errors: the
 * float loss carries ~1e-6 of rounding per evaluation (terms of order 1..10 rounded in float),
 * 2e-6 in the difference, plus the kinks' and the O(t^3) truncation's share: 2e-2 relative of
 * the predicted change plus 4e-6 absolute. The predicted changes are ~5e-5..3e-4 (random) and
 * ~5e-3 (gradient), so a gradient off by more than ~10% in any substantial part fails. */
static void check_directional(nf_preset preset, nf_prior_kind prior, uint64_t seed)
{
    nf_model *m = random_model(preset, prior, seed);
    batch b;
    make_batch(m, seed + 1u, &b);
    size_t count = nf_model_param_count(m);
    float *params = malloc(count * sizeof *params), *grad = malloc(count * sizeof *grad);
    float *moved = malloc(count * sizeof *moved), *scratch = malloc(count * sizeof *scratch);
    double *v = malloc(count * sizeof *v);
    assert_true(params && grad && moved && scratch && v);
    assert_int_equal(nf_model_get_params(m, params), NF_OK);
    float loss0;
    assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &loss0, grad), NF_OK);
    nft_rng r;
    nft_rng_seed(&r, seed + 3u, 4u);
    for (int dir = 0; dir < 4; ++dir) {
        const double t = dir < 3 ? 0.005 : 0.001;
        for (size_t i = 0; i < count; ++i) {
            if (dir < 3) {
                /* Gaussian components (Box-Muller) give a uniformly random direction. */
                double u1 = 1.0 - nft_rng_double(&r), u2 = nft_rng_double(&r);
                v[i] = sqrt(-2.0 * log(u1)) * cos(2.0 * NFT_PI * u2);
            } else {
                v[i] = grad[i];
            }
        }
        double vn = norm(v, count);
        for (size_t i = 0; i < count; ++i)
            v[i] /= vn;
        double predicted = 0.0, l[2];
        for (int side = 0; side < 2; ++side) {
            double sign = side ? -1.0 : 1.0;
            for (size_t i = 0; i < count; ++i)
                moved[i] = (float)(params[i] + sign * t * v[i]);
            assert_int_equal(nf_model_set_params(m, moved), NF_OK);
            l[side] = loss_at(m, &b, scratch);
            /* g . (p+ - p-) accumulated from the float displacements actually applied. */
            for (size_t i = 0; i < count; ++i)
                predicted += sign * (double)grad[i] * ((double)moved[i] - params[i]);
        }
        assert_int_equal(nf_model_set_params(m, params), NF_OK);
        double fd = l[0] - l[1];
        double tol = 2e-2 * fabs(predicted) + 4e-6;
        print_message("%s preset %d direction %d: L(p+) - L(p-) = %.6g, g . (p+ - p-) = %.6g\n",
                      nft_prior_name(prior), (int)preset, dir, fd, predicted);
        if (fabs(fd - predicted) > tol)
            fail_msg("%s preset %d direction %d: finite difference %.6g, gradient predicts "
                     "%.6g",
                     nft_prior_name(prior), (int)preset, dir, fd, predicted);
        if (dir == 3)
            assert_true(predicted > 1e-4); /* along the gradient the loss increases */
    }
    free(params);
    free(grad);
    free(moved);
    free(scratch);
    free(v);
    nf_model_destroy(m);
}

static void test_directional_derivatives(void **state)
{
    (void)state;
    for (int preset = 0; preset < 2; ++preset)
        for (int p = 0; p < 3; ++p)
            check_directional((nf_preset)preset, builtin_priors[p], 300u + 10u * preset + p);
}

/* ---- invariances ------------------------------------------------------------------------------ */

/* All weights zero: loss 0 and a zero gradient (overwritten, not accumulated). */
static void test_zero_weights(void **state)
{
    (void)state;
    nf_model *m = random_model(NF_PRESET_SMALL, NF_PRIOR_COSINE, 400u);
    batch b;
    make_batch(m, 401u, &b);
    for (int i = 0; i < BATCH; ++i)
        b.weight[i] = 0.0f;
    size_t count = nf_model_param_count(m);
    float *grad = malloc(count * sizeof *grad);
    assert_non_null(grad);
    for (size_t i = 0; i < count; ++i)
        grad[i] = 3.0f;
    float loss = 5.0f;
    assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &loss, grad), NF_OK);
    assert_true(loss == 0.0f);
    for (size_t i = 0; i < count; ++i)
        assert_true(grad[i] == 0.0f);
    /* nf_train_step with zero weights: no step, loss 0, the model unchanged. */
    nft_snapshot snap = nft_snapshot_of(m);
    loss = 5.0f;
    assert_int_equal(nf_train_step(m, BATCH, b.ctx, b.dir, b.weight, &loss), NF_OK);
    assert_true(loss == 0.0f);
    assert_true(nft_snapshot_equal(m, &snap));
    nft_snapshot_free(&snap);
    free(grad);
    nf_model_destroy(m);
}

/* Batches of 4 or more samples run on tiles of 16 (src/kernels/flow_tile_backward.h), single samples on the
 * per-sample code (src/kernels/flow.h): two implementations of the same reverse mode. A batch of
 * 37 with every fifth weight zero (so tiles are compacted and the last one is partial) must
 * give the weighted sum of its samples' single-sample gradients, for every prior including a
 * custom one, on both presets and on a deep, wide network whose layers do not all fit on the
 * tiles' tape (the reverse pass then recomputes each conditioner).
 *
 * Tolerance: both sum the same float terms in different orders (over lanes then into grad,
 * against sample by sample) and the tiles sum one-blob slope rows before their dot product:
 * rounding of ~1e-7 relative per term; measured 1.5e-7..8.8e-7 of the gradient's norm
 * (printed). 1e-5 is far above that and far below any real difference (a missing sample
 * moves the gradient by ~1/30 of its norm, a wrong row or lane by O(1)). */
static void test_tiles_match_single_samples(void **state)
{
    (void)state;
    enum { N = 37 };
    static nf_context ctx[N];
    static float dir[3 * N], weight[N];
    nft_rng r;
    nft_rng_seed(&r, 700u, 3u);
    for (int i = 0; i < N; ++i) {
        nft_random_context(&r, &ctx[i]);
        make_medium(i, &ctx[i]);
        nft_random_unit_vector(&r, dir + 3 * i);
        weight[i] = i % 5 == 3 ? 0.0f : 0.1f + nft_rng_float(&r);
    }
    double total = 0.0;
    for (int i = 0; i < N; ++i)
        total += weight[i];
    const nf_prior_kind priors[4] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_UNIFORM_ANGLE,
                                     NF_PRIOR_COSINE, NF_PRIOR_CUSTOM};
    for (int preset = 0; preset < 3; ++preset) {
        for (int p = 0; p < 4; ++p) {
            nf_config cfg = nft_config(preset == 0 ? NF_PRESET_SMALL : NF_PRESET_LARGE, priors[p]);
            if (preset == 2) {
                /* 3 layers x (8 x 80 activation rows + 32 raw rows) = 2016 rows, more than the
                 * tape's 1232 */
                cfg.coupling_layers = 3;
                cfg.hidden_layers = 8;
                cfg.hidden_width = 80;
            }
            nf_model *m = nft_model_from(&cfg);
            assert_int_equal(nft_randomize_params(m, 0.3f, 701u + (uint64_t)p), NF_OK);
            size_t count = nf_model_param_count(m);
            float *batch_grad = malloc(count * sizeof(float));
            float *one = malloc(count * sizeof(float));
            double *sum = calloc(count, sizeof(double));
            assert_true(batch_grad && one && sum);
            float batch_loss, one_loss;
            assert_int_equal(nf_loss_gradient(m, N, ctx, dir, weight, &batch_loss, batch_grad),
                             NF_OK);
            double loss_sum = 0.0;
            for (int i = 0; i < N; ++i) {
                if (weight[i] == 0.0f)
                    continue;
                assert_int_equal(nf_loss_gradient(m, 1, &ctx[i], dir + 3 * i, &weight[i],
                                                  &one_loss, one),
                                 NF_OK);
                double share = weight[i] / total;
                loss_sum += share * one_loss;
                for (size_t k = 0; k < count; ++k)
                    sum[k] += share * one[k];
            }
            double num = 0.0, den = 0.0;
            for (size_t k = 0; k < count; ++k) {
                num += (batch_grad[k] - sum[k]) * (batch_grad[k] - sum[k]);
                den += sum[k] * sum[k];
            }
            double rel = sqrt(num / den);
            print_message("%s preset %d: tiles vs single samples, loss %.7g vs %.7g, gradient "
                          "%.3g of its norm %.3g\n",
                          nft_prior_name(priors[p]), preset, (double)batch_loss, loss_sum, rel,
                          sqrt(den));
            assert_true(den > 1e-4);
            assert_true(fabs(batch_loss - loss_sum) <= 1e-5 * fabs(loss_sum));
            assert_true(rel < 1e-5);
            free(batch_grad);
            free(one);
            free(sum);
            nf_model_destroy(m);
        }
    }
}

/* The weights are normalized by their sum: scaling all of them by 7 leaves the loss and the
 * gradient unchanged up to rounding, and zero-weight samples contribute nothing. */
static void test_weight_normalization(void **state)
{
    (void)state;
    nf_model *m = random_model(NF_PRESET_LARGE, NF_PRIOR_UNIFORM_DIRECTION, 500u);
    batch b, scaled;
    make_batch(m, 501u, &b);
    scaled = b;
    for (int i = 0; i < BATCH; ++i)
        scaled.weight[i] = 7.0f * b.weight[i]; /* exact in float: 7 w has 3 more bits */
    size_t count = nf_model_param_count(m);
    float *g1 = malloc(count * sizeof *g1), *g7 = malloc(count * sizeof *g7);
    assert_true(g1 && g7);
    float l1, l7;
    assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &l1, g1), NF_OK);
    assert_int_equal(nf_loss_gradient(m, BATCH, scaled.ctx, scaled.dir, scaled.weight, &l7, g7),
                     NF_OK);
    /* Each sample's share w_i / sum w changes by at most an ulp of double, which becomes at
     * most an ulp of float in the per-sample coefficient: relative 1e-6 of the loss, and of
     * the gradient's norm per component. */
    assert_true(fabs((double)l7 - l1) <= 1e-6 * fabs((double)l1));
    double gn = 0.0;
    for (size_t i = 0; i < count; ++i)
        gn += (double)g1[i] * g1[i];
    gn = sqrt(gn);
    assert_true(gn > 1e-2);
    for (size_t i = 0; i < count; ++i)
        if (fabs((double)g7[i] - g1[i]) > 1e-6 * gn)
            fail_msg("parameter %zu: gradient %.9g with weights w, %.9g with 7 w", i,
                     (double)g1[i], (double)g7[i]);

    /* Zero-weight samples (anywhere, even at a pole) change nothing. */
    nf_context ctx[BATCH + 2];
    float dir[3 * (BATCH + 2)], weight[BATCH + 2];
    memcpy(ctx, b.ctx, sizeof b.ctx);
    memcpy(dir, b.dir, sizeof b.dir);
    memcpy(weight, b.weight, sizeof b.weight);
    ctx[BATCH] = b.ctx[0];
    ctx[BATCH + 1] = b.ctx[1];
    const float pole[3] = {0.0f, 0.0f, 1.0f}, other[3] = {0.3f, -0.4f, 0.5f};
    memcpy(dir + 3 * BATCH, pole, sizeof pole);
    memcpy(dir + 3 * (BATCH + 1), other, sizeof other);
    weight[BATCH] = 0.0f;
    weight[BATCH + 1] = 0.0f;
    float lz;
    assert_int_equal(nf_loss_gradient(m, BATCH + 2, ctx, dir, weight, &lz, g7), NF_OK);
    assert_true(lz == l1);
    assert_memory_equal(g7, g1, count * sizeof *g1);
    free(g1);
    free(g7);
    nf_model_destroy(m);
}

/* Sharding (train.h): the gradient of a batch A + B is (F_A g_A + F_B g_B) / (F_A + F_B), and
 * the loss likewise, F the weight sums. */
static void test_sharding(void **state)
{
    (void)state;
    nf_model *m = random_model(NF_PRESET_SMALL, NF_PRIOR_COSINE, 600u);
    batch b;
    make_batch(m, 601u, &b);
    size_t count = nf_model_param_count(m);
    float *ga = malloc(count * sizeof *ga), *gb = malloc(count * sizeof *gb);
    float *gall = malloc(count * sizeof *gall);
    assert_true(ga && gb && gall);
    const int na = 5;
    float la, lb, lall;
    assert_int_equal(nf_loss_gradient(m, na, b.ctx, b.dir, b.weight, &la, ga), NF_OK);
    assert_int_equal(nf_loss_gradient(m, BATCH - na, b.ctx + na, b.dir + 3 * na, b.weight + na,
                                      &lb, gb),
                     NF_OK);
    assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &lall, gall), NF_OK);
    double fa = 0.0, fb = 0.0;
    for (int i = 0; i < BATCH; ++i)
        *(i < na ? &fa : &fb) += b.weight[i];
    double loss = (fa * la + fb * lb) / (fa + fb);
    /* The shards' float results combine with a few roundings: 1e-6 relative. */
    assert_true(fabs(loss - lall) <= 1e-6 * fabs(loss) + 1e-7);
    double gn = 0.0;
    for (size_t i = 0; i < count; ++i)
        gn += (double)gall[i] * gall[i];
    gn = sqrt(gn);
    for (size_t i = 0; i < count; ++i) {
        double combined = (fa * ga[i] + fb * gb[i]) / (fa + fb);
        /* Each component sums per-sample terms in float (up to 16 of them, magnitudes up to
         * the norm): 1e-5 of the norm. */
        if (fabs(combined - gall[i]) > 1e-5 * gn)
            fail_msg("parameter %zu: combined shards %.9g, whole batch %.9g", i, combined,
                     (double)gall[i]);
    }
    free(ga);
    free(gb);
    free(gall);
    nf_model_destroy(m);
}

/* nf_loss_gradient_with_work (train.h): the same loss and gradient to the bit as
 * nf_loss_gradient, for batches on the per-sample path (1, 3) and on tiles (4, 16, 37 with a
 * partial tile and zero weights), both presets, every prior, every instruction set the CPU has,
 * through a work area at every offset modulo 64 (the library aligns it). */
static void test_gradient_with_work(void **state)
{
    (void)state;
    enum { MAX_N = 37 };
    static const nf_isa isas[3] = {NF_ISA_GENERIC, NF_ISA_AVX2, NF_ISA_AVX512};
    static const size_t sizes[5] = {1, 3, 4, 16, MAX_N};
    static nf_context ctx[MAX_N];
    static float dir[3 * MAX_N], weight[MAX_N];
    nft_rng r;
    nft_rng_seed(&r, 77u, 3u);
    nft_random_samples(&r, MAX_N, ctx, dir, weight, 0.1f);
    for (int i = 3; i < MAX_N; i += 7)
        weight[i] = 0.0f; /* zero-weight samples inside the batch */
    const size_t bytes = nf_training_work_bytes();
    /* At least the tile work area: NF_TRAINING_STACK_BYTES says it is most of 160 KiB. */
    assert_true(bytes > 64 * 1024);
    unsigned char *area = malloc(bytes + 64);
    assert_non_null(area);
    int compared = 0;
    for (int k = 0; k < 3; ++k)
        for (int preset = 0; preset < 2; ++preset)
            for (int p = 0; p < 4; ++p) {
                if (p == 3)
                    continue; /* the custom prior: test_prior_context covers its callbacks */
                nf_model *m = random_model(preset ? NF_PRESET_LARGE : NF_PRESET_SMALL,
                                           builtin_priors[p % 3], 900u + (uint64_t)(k * 8 + p));
                if (nf_model_set_isa(m, isas[k]) != NF_OK) { /* a CPU without the set */
                    nf_model_destroy(m);
                    continue;
                }
                size_t count = nf_model_param_count(m);
                float *g1 = malloc(count * sizeof *g1), *g2 = malloc(count * sizeof *g2);
                assert_true(g1 && g2);
                for (int b = 0; b < 5; ++b) {
                    size_t n = sizes[b], offset = (size_t)(b * 13 + p * 5 + k) % 64;
                    float l1 = -1.0f, l2 = -2.0f;
                    memset(area, 0xA5, bytes + 64); /* the area's content must not matter */
                    assert_int_equal(nf_loss_gradient(m, n, ctx, dir, weight, &l1, g1), NF_OK);
                    assert_int_equal(nf_loss_gradient_with_work(m, n, ctx, dir, weight, &l2, g2,
                                                                area + offset, bytes),
                                     NF_OK);
                    if (memcmp(&l1, &l2, sizeof l1) != 0 ||
                        memcmp(g1, g2, count * sizeof *g1) != 0)
                        fail_msg("%s, preset %d, prior %d, n = %zu, offset %zu: the gradient "
                                 "with a work area differs from nf_loss_gradient's",
                                 nf_model_isa_name(m), preset, p, n, offset);
                    compared++;
                }
                free(g1);
                free(g2);
                nf_model_destroy(m);
            }
    assert_true(compared >= 2 * 3 * 5); /* the generic kernels run everywhere */
    free(area);
}

/* ---- AdamW ---------------------------------------------------------------------------------- */

/* The spacing of floats at |x| (an ulp). */
static double ulp_of(double x)
{
    float a = (float)fabs(x);
    return (double)nextafterf(a, INFINITY) - (double)a;
}

/* nf_train_step: its loss is nf_loss_gradient's; it takes one AdamW step with that gradient
 * (step count + 1, parameters changed) that matches AdamW written here in double: at t = 1 the
 * bias-corrected moments are g and g^2, so p' = p (1 - lr wd) - lr g / (|g| + eps): every
 * parameter with a gradient well above eps moves by lr against its gradient (plus the decay). */
static void test_train_step_adamw(void **state)
{
    (void)state;
    for (int preset = 0; preset < 2; ++preset) {
        nf_model *m = random_model((nf_preset)preset, NF_PRIOR_COSINE, 700u + preset);
        nf_config cfg;
        assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
        batch b;
        make_batch(m, 701u, &b);
        size_t count = nf_model_param_count(m);
        float *p0 = malloc(count * sizeof *p0), *p1 = malloc(count * sizeof *p1);
        float *g = malloc(count * sizeof *g);
        assert_true(p0 && p1 && g);
        assert_int_equal(nf_model_get_params(m, p0), NF_OK);
        float loss_grad, loss_step;
        assert_int_equal(nf_loss_gradient(m, BATCH, b.ctx, b.dir, b.weight, &loss_grad, g),
                         NF_OK);
        assert_true(nf_model_step_count(m) == 0);
        assert_int_equal(nf_train_step(m, BATCH, b.ctx, b.dir, b.weight, &loss_step), NF_OK);
        /* The same computation: equal up to a rounding of the float result (1e-6). */
        assert_true(fabs((double)loss_step - loss_grad) <= 1e-6 * fabs((double)loss_grad));
        assert_true(nf_model_step_count(m) == 1);
        assert_int_equal(nf_model_get_params(m, p1), NF_OK);
        const double lr = cfg.learning_rate, wd = cfg.weight_decay, eps = cfg.adam_epsilon;
        size_t moved = 0, big = 0, changed = 0;
        for (size_t i = 0; i < count; ++i) {
            double gi = g[i];
            double expect = (double)p0[i] * (1.0 - lr * wd) - lr * gi / (fabs(gi) + eps);
            /* Float evaluation: the decay product, the step and the subtraction each round
             * to half an ulp of values <= max(|p|, |p'|), and the step's quotient carries a
             * few ulps of lr: 2 ulps + 4 2^-24 lr. */
            double tol = 2.0 * ulp_of(fmax(fabs(p0[i]), fabs(expect))) + 4.0 * lr / 16777216.0;
            if (fabs(p1[i] - expect) > tol)
                fail_msg("preset %d parameter %zu: p %.9g, g %.6g: AdamW gives %.9g, library "
                         "%.9g",
                         preset, i, (double)p0[i], gi, expect, (double)p1[i]);
            changed += p1[i] != p0[i];
            if (fabs(gi) > 1e-4) {
                /* eps / |g| <= 1e-4: the step is lr (1 - 1e-4) against the gradient; the
                 * decay -lr wd p is removed first; float rounding of p' (an ulp of ~0.5,
                 * 6e-8) is 6e-5 of lr: 1e-3 relative. */
                double step = ((double)p1[i] - p0[i] * (1.0 - lr * wd)) / lr;
                ++big;
                if (fabs(step + (gi > 0 ? 1.0 : -1.0)) > 1e-3)
                    fail_msg("preset %d parameter %zu: gradient %.6g, step %.6g lr", preset, i,
                             gi, step);
                moved += 1;
            } else if (gi == 0.0) {
                /* No gradient: decay only, p (1 - lr wd), to 2 ulps. */
                if (fabs(p1[i] - p0[i] * (1.0 - lr * wd)) > 2.0 * ulp_of(p0[i]))
                    fail_msg("preset %d parameter %zu without gradient moved to %.9g from "
                             "%.9g",
                             preset, i, (double)p1[i], (double)p0[i]);
            }
        }
        print_message("preset %d: %zu of %zu parameters changed, %zu with |g| > 1e-4 moved by "
                      "lr\n",
                      preset, changed, count, big);
        assert_true(big > count / 20);
        assert_true(moved == big);
        free(p0);
        free(p1);
        free(g);
        nf_model_destroy(m);
    }
}

/* Several nf_apply_gradient steps with given gradients (random, tiny, zero, huge) against
 * AdamW in double with bias correction 1 - beta^t, on a model with non-default AdamW
 * settings. */
static void test_apply_gradient_adamw(void **state)
{
    (void)state;
    nf_config cfg = nft_config(NF_PRESET_SMALL, NF_PRIOR_UNIFORM_DIRECTION);
    cfg.learning_rate = 3e-3f;
    cfg.beta1 = 0.8f;
    cfg.beta2 = 0.95f;
    cfg.adam_epsilon = 1e-6f;
    cfg.weight_decay = 0.1f;
    nf_model *m = nft_model_from(&cfg);
    size_t count = nf_model_param_count(m);
    float *p = malloc(count * sizeof *p), *g = malloc(count * sizeof *g);
    double *P = malloc(count * sizeof *P), *M = calloc(count, sizeof *M);
    double *V = calloc(count, sizeof *V);
    assert_true(p && g && P && M && V);
    assert_int_equal(nf_model_get_params(m, p), NF_OK);
    for (size_t i = 0; i < count; ++i)
        P[i] = p[i];
    nft_rng r;
    nft_rng_seed(&r, 800u, 1u);
    const double lr = cfg.learning_rate, b1 = cfg.beta1, b2 = cfg.beta2;
    const double eps = cfg.adam_epsilon, wd = cfg.weight_decay;
    for (int t = 1; t <= 6; ++t) {
        for (size_t i = 0; i < count; ++i) {
            switch (i % 5) {
            case 0: g[i] = 0.0f; break;
            case 1: g[i] = 1e-9f * (2.0f * nft_rng_float(&r) - 1.0f); break;
            case 2: g[i] = 100.0f * (2.0f * nft_rng_float(&r) - 1.0f); break;
            default: g[i] = 2.0f * nft_rng_float(&r) - 1.0f; break;
            }
        }
        assert_int_equal(nf_apply_gradient(m, g), NF_OK);
        assert_true(nf_model_step_count(m) == (uint64_t)t);
        assert_int_equal(nf_model_get_params(m, p), NF_OK);
        double c1 = 1.0 - pow(b1, t), c2 = 1.0 - pow(b2, t);
        for (size_t i = 0; i < count; ++i) {
            M[i] = b1 * M[i] + (1.0 - b1) * g[i];
            V[i] = b2 * V[i] + (1.0 - b2) * (double)g[i] * g[i];
            P[i] = P[i] * (1.0 - lr * wd) - lr * (M[i] / c1) / (sqrt(V[i] / c2) + eps);
            /* The library keeps p, m, v in float: each step rounds p (half an ulp, twice) and
             * the step (a few ulps of lr, more where m nearly cancels: 1e-4 lr); the rounding
             * of earlier steps carries over: t (2 ulps + 1e-4 lr). */
            double tol = t * (2.0 * ulp_of(P[i]) + 1e-4 * lr);
            if (fabs(p[i] - P[i]) > tol)
                fail_msg("step %d parameter %zu (g %.6g): AdamW %.9g, library %.9g", t, i,
                         (double)g[i], P[i], (double)p[i]);
        }
    }
    free(p);
    free(g);
    free(P);
    free(M);
    free(V);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_fd_small),
    cmocka_unit_test(test_fd_large),
    cmocka_unit_test(test_fd_media),
    cmocka_unit_test(test_directional_derivatives),
    cmocka_unit_test(test_zero_weights),
    cmocka_unit_test(test_tiles_match_single_samples),
    cmocka_unit_test(test_weight_normalization),
    cmocka_unit_test(test_sharding),
    cmocka_unit_test(test_gradient_with_work),
    cmocka_unit_test(test_train_step_adamw),
    cmocka_unit_test(test_apply_gradient_adamw),
)
