/*
 * test_normalization.c - every model density integrates to one over the sphere.
 *
 * The integral of nf_pdf over the sphere is computed by a deterministic quadrature (midpoint
 * rule on the (theta, phi) square with the analytic Jacobian sin(theta), directions from the
 * test's own double-precision trig), never by Monte Carlo, for every prior, fresh and
 * randomized models, and contexts whose normals sit on the poles and on the phi seam. A
 * rotated quadrature frame puts the library's poles and seam inside the grid, which checks
 * the library's (theta, phi) parameterization and its sin(theta) Jacobian independently.
 */
#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

/* The quadrature grid. The midpoint rule's error is O(h^2) for the integrands here: the
 * densities are C^1 (rational-quadratic splines share derivatives at their knots, the
 * one-blob kernel is C^2) except for ReLU kinks in the conditioners and the max(0, n.w) kink
 * of the cosine prior, each of which costs O(h^2) too. Measured on randomized models
 * (RANDOM_SCALE) for all four priors and all six contexts below, against a 1024 x 2048
 * grid: |I(192 x 384) - I| <= 2.0e-4 and |I(384 x 768) - I| <= 6e-5. The 192 x 384 grid
 * (cells of 0.016 rad, some 6 per one-blob bin of the conditioner's input) therefore leaves
 * a margin of 10 under TOLERANCE, and test_quadrature_convergence re-estimates it on the
 * roughest case each run; nf_pdf costs ~1-2 us, so this grid keeps the executable fast. A density that is wrong by a constant
 * factor (a missing (1 - eps), a Jacobian off by a factor) errs by 1e-2 or more. The sum
 * runs in double over float densities (relative rounding 6e-8 each), negligible. */
#define THETA_RES 192u
#define PHI_RES 384u
#define FINE_THETA_RES 384u
#define FINE_PHI_RES 768u
#define TOLERANCE 2e-3

/* Randomized parameters: uniform in [-RANDOM_SCALE, RANDOM_SCALE]. The densities then range
 * over a factor ~100 (e.g. 0.0097 to 0.9 per sr for the uniform-direction prior, whose own
 * density is 0.08), and assert_far_from_prior checks a factor 2 in every context; larger
 * scales give spikes of 1e5 per sr that no fixed grid resolves. */
#define RANDOM_SCALE 0.3f

#define CONTEXT_COUNT 6

/* Contexts with normals exactly on the poles, on the phi = 0 seam, pointing at the seam
 * from phi just below 2 pi, and a random one; positions in, on and outside the bounds. */
static void make_contexts(nf_context ctx[CONTEXT_COUNT])
{
    const double below = 2.0 * NFT_PI - 1e-3; /* phi of the normal, just below 2 pi */
    ctx[0] = nft_context(0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.3f, -0.5f, 0.81f);
    ctx[1] = nft_context(0.0f, 0.0f, 0.0f, 0.0f, 0.0f, -1.0f, 0.2f, 0.4f, -0.89f);
    ctx[2] = nft_context(1.0f, 1.0f, 1.0f, 1.0f, 0.0f, 0.0f, 0.8f, 0.3f, 0.52f);
    ctx[3] = nft_context(0.25f, 0.9f, 0.1f, 0.6f, 0.0f, 0.8f, 0.0f, 0.0f, 1.0f);
    ctx[4] = nft_context(-3.0f, 0.5f, 7.0f, (float)(0.8 * cos(below)), (float)(0.8 * sin(below)),
                         0.6f, (float)cos(below), (float)sin(below), 0.0f);
    nft_rng r;
    nft_rng_seed(&r, 2024u, 7u);
    nft_random_context(&r, &ctx[5]);
}

/* The density of `m` differs from the density of `fresh` (its prior) by more than a factor
 * 2 somewhere, so the randomized flow is far from the identity. */
static void assert_far_from_prior(const nf_model *m, const nf_model *fresh,
                                  const nf_context *ctx)
{
    enum { N = 512 };
    static float dir[3 * N];
    static nf_context c[N];
    float p[N], q[N];
    nft_rng r;
    nft_rng_seed(&r, 99u, 1u);
    for (int i = 0; i < N; ++i) {
        nft_random_unit_vector(&r, dir + 3 * i);
        c[i] = *ctx;
    }
    assert_int_equal(nf_pdf(m, N, c, dir, p), NF_OK);
    assert_int_equal(nf_pdf(fresh, N, c, dir, q), NF_OK);
    double worst = 0.0;
    for (int i = 0; i < N; ++i)
        worst = fmax(worst, fabs(log((double)p[i] / (double)q[i])));
    if (!(worst > log(2.0)))
        fail_msg("randomized model too close to its prior: max |log ratio| %.3f", worst);
}

static void check_integral(double integral, const char *what, nf_prior_kind prior, int c)
{
    if (!(fabs(integral - 1.0) <= TOLERANCE))
        fail_msg("%s model, prior %s, context %d: integral %.6f, |I - 1| = %.2e > %.1e", what,
                 nft_prior_name(prior), c, integral, fabs(integral - 1.0), TOLERANCE);
}

/* A fresh model with the normal aimed just below phi = 2 pi (so the cosine kink crosses the
 * seam; fresh densities are the analytic priors, which test_identity checks pointwise), and
 * a randomized model with the normal on both poles, on the seam and aimed below 2 pi. */
static void check_prior(nf_prior_kind prior)
{
    nf_context ctx[CONTEXT_COUNT];
    make_contexts(ctx);
    nf_model *fresh = nft_make_model(NF_PRESET_SMALL, prior);
    nf_model *randomized = nft_make_model(NF_PRESET_SMALL, prior);
    assert_int_equal(nft_randomize_params(randomized, RANDOM_SCALE, 11u + (uint64_t)prior),
                     NF_OK);
    const int seam = 2 + ((int)prior & 1); /* (1,0,0) or (0.6,0,0.8), alternately */
    for (int c = 0; c < CONTEXT_COUNT; ++c) {
        if (c == 5 || (c == 2 && seam != 2) || (c == 3 && seam != 3))
            continue; /* the random context: see test_quadrature_convergence */
        if (c == 4)
            check_integral(nft_integrate_model(fresh, &ctx[c], THETA_RES, PHI_RES, NULL),
                           "fresh", prior, c);
        assert_far_from_prior(randomized, fresh, &ctx[c]);
        check_integral(nft_integrate_model(randomized, &ctx[c], THETA_RES, PHI_RES, NULL),
                       "randomized", prior, c);
    }
    nf_model_destroy(fresh);
    nf_model_destroy(randomized);
}

/* The integral of the density under the prior in *state. */
static void test_normalization(void **state) { check_prior((nf_prior_kind)nft_case(state)); }

/* A large-preset model (4 coupling layers, 16 bins, 2 hidden layers) also integrates to 1. */
static void test_normalization_large_preset(void **state)
{
    (void)state;
    nf_context ctx[CONTEXT_COUNT];
    make_contexts(ctx);
    nf_model *m = nft_make_model(NF_PRESET_LARGE, NF_PRIOR_COSINE);
    assert_int_equal(nft_randomize_params(m, RANDOM_SCALE, 5u), NF_OK);
    check_integral(nft_integrate_model(m, &ctx[3], THETA_RES, PHI_RES, NULL), "large randomized",
                   NF_PRIOR_COSINE, 3);
    nf_model_destroy(m);
}

/* Quadrature frames whose pole lies along x (the library's phi seam) and along a generic
 * axis, so the library's poles and seam fall inside the grid. The uniform-angle prior is
 * left out: its density 1/(2 pi^2 sin theta) is unbounded at the library's poles, where
 * the midpoint rule would then err by O(h) ~ 1e-3. The others are bounded there. */
static void test_normalization_rotated_frame(void **state)
{
    (void)state;
    const double axes[2][3] = {{1.0, 0.0, 0.0}, {0.3, -0.7, 0.5}};
    const nf_prior_kind priors[3] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_COSINE,
                                     NF_PRIOR_CUSTOM};
    const int axis_of[3] = {0, 0, 1}, context_of[3] = {2, 3, 4};
    nf_context ctx[CONTEXT_COUNT];
    make_contexts(ctx);
    for (int k = 0; k < 3; ++k) {
        const double *axis = axes[axis_of[k]];
        double frame[3][3];
        nft_frame(axis, frame[0], frame[1], frame[2]);
        nf_model *m = nft_make_model(NF_PRESET_SMALL, priors[k]);
        assert_int_equal(nft_randomize_params(m, RANDOM_SCALE, 31u + (uint64_t)k), NF_OK);
        int c = context_of[k];
        double integral =
            nft_integrate_model(m, &ctx[c], THETA_RES, PHI_RES, (const double(*)[3])frame);
        if (!(fabs(integral - 1.0) <= TOLERANCE))
            fail_msg("rotated frame (pole %.1f %.1f %.1f), prior %s, context %d: "
                     "integral %.6f",
                     axis[0], axis[1], axis[2], nft_prior_name(priors[k]), c, integral);
        nf_model_destroy(m);
    }
}

/* The quadrature's own error, estimated by halving h on the roughest case measured (custom
 * prior, random context): the midpoint rule's error is O(h^2), so the coarse grid's error
 * is about (4/3) |I(h) - I(2h)|. Requiring it below TOLERANCE / 4 shows that the tolerance
 * is not eaten by discretization error; the fine grid must pass TOLERANCE as well. */
static void test_quadrature_convergence(void **state)
{
    (void)state;
    nf_context ctx[CONTEXT_COUNT];
    make_contexts(ctx);
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_CUSTOM);
    assert_int_equal(nft_randomize_params(m, RANDOM_SCALE, 11u + (uint64_t)NF_PRIOR_CUSTOM),
                     NF_OK);
    double fine = nft_integrate_model(m, &ctx[5], FINE_THETA_RES, FINE_PHI_RES, NULL);
    double coarse = nft_integrate_model(m, &ctx[5], THETA_RES, PHI_RES, NULL);
    double err = 4.0 / 3.0 * fabs(fine - coarse);
    print_message("quadrature: %ux%u %.7f, %ux%u %.7f, estimated error of the coarse grid "
                  "%.2e\n",
                  FINE_THETA_RES, FINE_PHI_RES, fine, THETA_RES, PHI_RES, coarse, err);
    check_integral(fine, "randomized (fine grid)", NF_PRIOR_CUSTOM, 5);
    if (!(err < TOLERANCE / 4.0))
        fail_msg("estimated quadrature error %.2e too close to the tolerance", err);
    nf_model_destroy(m);
}

/* ---- the quadrature itself on analytic densities -------------------------------------------- */

typedef struct analytic {
    double scale;   /* multiplies the density (to check that errors are seen) */
    double axis[3]; /* Phong lobe axis; exponent 0 means uniform */
    double exponent;
} analytic;

static int analytic_pdf(void *user, size_t n, const float *dir, float *pdf)
{
    const analytic *a = user;
    for (size_t i = 0; i < n; ++i) {
        const float *w = dir + 3 * i;
        double len = nft_length3f(w);
        double c = (a->axis[0] * w[0] + a->axis[1] * w[1] + a->axis[2] * w[2]) / len;
        double p = a->exponent == 0.0 ? 1.0 / (4.0 * NFT_PI)
                                      : (a->exponent + 1.0) / (2.0 * NFT_PI) *
                                            pow(fmax(c, 0.0), a->exponent);
        pdf[i] = (float)(a->scale * p);
    }
    return 0;
}

static void test_quadrature_self_check(void **state)
{
    (void)state;
    double frame[3][3];
    const double pole[3] = {0.3, -0.7, 0.5};
    nft_frame(pole, frame[0], frame[1], frame[2]);
    const double inv = 1.0 / sqrt(0.3 * 0.3 + 0.7 * 0.7 + 0.5 * 0.5);
    analytic uniform = {1.0, {0.0, 0.0, 1.0}, 0.0};
    analytic lobe = {1.0, {0.6, 0.0, 0.8}, 8.0};
    analytic lobe_on_pole = {1.0, {0.3 * inv, -0.7 * inv, 0.5 * inv}, 8.0};
    analytic doubled = {2.0, {0.0, 0.0, 1.0}, 0.0};
    /* The midpoint rule's error for a smooth integrand g(theta) on [0, pi] is about
     * h^2/24 (g'(pi) - g'(0)). For the lobe centred on the grid's pole g = (e + 1) cos^e
     * sin, g'(0) = e + 1, so the error is -(e + 1) h^2/24 = -1.0e-4 at h = pi/192, the
     * largest of these cases (the others are below 1e-5). 2e-4 bounds it; a wrong
     * Jacobian or frame errs by order 1. */
    const double tol = 2e-4;
    const double(*rotated)[3] = (const double(*)[3])frame;
    struct {
        const char *name;
        analytic *density;
        const double(*frame)[3];
        double want;
    } cases[] = {
        {"uniform", &uniform, NULL, 1.0},
        {"uniform, rotated frame", &uniform, rotated, 1.0},
        {"lobe", &lobe, NULL, 1.0},
        {"lobe, rotated frame", &lobe, rotated, 1.0},
        {"lobe on the rotated grid's pole", &lobe_on_pole, rotated, 1.0},
        {"density twice too large", &doubled, NULL, 2.0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; ++i) {
        double v = nft_integrate_sphere(analytic_pdf, cases[i].density, THETA_RES, PHI_RES,
                                        cases[i].frame);
        if (!(fabs(v - cases[i].want) <= tol * cases[i].want))
            fail_msg("quadrature of %s: %.8f, want %.1f", cases[i].name, v, cases[i].want);
    }
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_quadrature_self_check),
    NFT_TEST_CASE("test_normalization_uniform_direction", test_normalization,
                  NF_PRIOR_UNIFORM_DIRECTION),
    NFT_TEST_CASE("test_normalization_uniform_angle", test_normalization, NF_PRIOR_UNIFORM_ANGLE),
    NFT_TEST_CASE("test_normalization_cosine", test_normalization, NF_PRIOR_COSINE),
    NFT_TEST_CASE("test_normalization_custom", test_normalization, NF_PRIOR_CUSTOM),
    cmocka_unit_test(test_normalization_large_preset),
    cmocka_unit_test(test_normalization_rotated_frame),
    cmocka_unit_test(test_quadrature_convergence),
)
