/*
 * test_kernels.c - every instruction-set variant of the kernels this CPU can run computes the
 * same samples, densities, gradients and AdamW steps as the portable one, and a variant the
 * CPU or build lacks is refused with a clear error.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"
#include "gradient.h"

enum { N = 512 };

/* A model with moderately randomized parameters, identical for every ISA. */
static nf_model *make_model(nf_preset preset, nf_prior_kind prior, nf_isa isa)
{
    nf_config cfg;
    nf_config_init(&cfg, preset);
    nft_apply_phi_map(&cfg);
    cfg.prior = prior;
    cfg.isa = isa;
    nf_model *m = NULL;
    if (nf_model_create(&cfg, &m) != NF_OK)
        return NULL;
    assert_int_equal(nft_randomize_params(m, 0.3f, 17u), NF_OK);
    return m;
}

static double rel_diff(double a, double b)
{
    return fabs(a - b) / fmax(fabs(a), fabs(b));
}

/* N random contexts, sample pairs u[2N] and training weights w[N] from one seed. */
static void random_inputs(uint64_t seed, nf_context *ctx, float *u, float *w)
{
    nft_rng rng;
    nft_rng_seed(&rng, seed, 1u);
    for (int i = 0; i < N; ++i) {
        nft_random_context(&rng, &ctx[i]);
        u[2 * i] = nft_rng_float(&rng);
        u[2 * i + 1] = nft_rng_float(&rng);
        w[i] = nft_rng_float(&rng);
    }
}

static void compare_with_generic(nf_isa isa)
{
    static nf_context ctx[N];
    static float u[2 * N], dir_g[3 * N], dir_v[3 * N], pdf_g[N], pdf_v[N], w[N];
    random_inputs(99u, ctx, u, w);
    for (int preset = 0; preset < 2; ++preset) {
        for (int prior = 0; prior < 3; ++prior) {
            nf_model *g = make_model((nf_preset)preset, (nf_prior_kind)prior, NF_ISA_GENERIC);
            nf_model *v = make_model((nf_preset)preset, (nf_prior_kind)prior, isa);
            assert_non_null(g);
            assert_non_null(v);
            assert_int_equal(nf_sample(g, N, ctx, u, dir_g, pdf_g), NF_OK);
            assert_int_equal(nf_sample(v, N, ctx, u, dir_v, pdf_v), NF_OK);
            /* The variants run the conditioners' multiply-adds fused, the generic kernels
             * rounded twice (lanes.h): one rounding per step apart, ~1e-6 relative through
             * the MLP (printed below), amplified by the spline slopes of a randomized model;
             * 1e-4 still catches any real divergence (a wrong lane or padding is O(1)). */
            double worst_dir = 0.0, worst_pdf = 0.0;
            for (int i = 0; i < N; ++i) {
                for (int a = 0; a < 3; ++a)
                    worst_dir = fmax(worst_dir, fabs(dir_g[3 * i + a] - dir_v[3 * i + a]));
                /* The returned density carries 1 / sin(theta) of the sampled s0, a float: one
                 * ulp of s0 (<= 2^-24) changes it by pi 2^-24 |cot theta| relative, 1e-3 at
                 * sin(theta) = 1e-3 (measured: a sample at sin(theta) = 0.00135 whose s0
                 * differs by ~2 ulps between variants). Eight ulps of that are allowed on top;
                 * away from the poles the bound stays ~1e-4. */
                double z = dir_g[3 * i + 2], sin_t = sqrt(fmax(1.0 - z * z, 1e-12));
                double allowed = 1e-4 + 8.0 * 3.14159265 * 0x1p-24 * fabs(z) / sin_t;
                assert_true(rel_diff(pdf_g[i], pdf_v[i]) < allowed);
                worst_pdf = fmax(worst_pdf, rel_diff(pdf_g[i], pdf_v[i]) / allowed);
            }
            assert_true(worst_dir < 1e-4);
            assert_int_equal(nf_pdf(v, N, ctx, dir_g, pdf_v), NF_OK);
            assert_int_equal(nf_pdf(g, N, ctx, dir_g, pdf_g), NF_OK);
            for (int i = 0; i < N; ++i)
                assert_true(rel_diff(pdf_g[i], pdf_v[i]) < 1e-4);

            size_t count = nf_model_param_count(g);
            float *grad_g = malloc(count * sizeof(float)), *grad_v = malloc(count * sizeof(float));
            float loss_g, loss_v;
            assert_int_equal(nf_loss_gradient(g, N, ctx, dir_g, w, &loss_g, grad_g), NF_OK);
            assert_int_equal(nf_loss_gradient(v, N, ctx, dir_g, w, &loss_v, grad_v), NF_OK);
            /* The loss is an average of logs: rounding differences stay ~1e-6 relative. The
             * gradient is compared as a whole vector, 1e-4 of its norm, for the same reason
             * as the densities. */
            assert_true(rel_diff(loss_g, loss_v) < 1e-5);
            double num = 0.0, den = 0.0;
            for (size_t i = 0; i < count; ++i) {
                num += ((double)grad_g[i] - grad_v[i]) * ((double)grad_g[i] - grad_v[i]);
                den += (double)grad_g[i] * grad_g[i];
            }
            print_message("%s preset %d prior %d: dir %.2g, pdf %.2g of its bound, gradient %.2g\n",
                          nf_model_isa_name(v), preset, prior, worst_dir, worst_pdf,
                          sqrt(num / den));
            assert_true(sqrt(num / den) < 1e-4);
            /* AdamW runs in the variant's vectors too. It is elementwise (no sum whose order a
             * compiler could change) of multiplies, adds, sqrt and divisions, which IEEE
             * rounds exactly, with contraction off: the same gradient must give the same
             * parameters to the bit, twice over so that the moments are compared as well. */
            float *params_g = malloc(count * sizeof(float));
            float *params_v = malloc(count * sizeof(float));
            for (int step = 0; step < 2; ++step) {
                assert_int_equal(nf_apply_gradient(g, grad_g), NF_OK);
                assert_int_equal(nf_apply_gradient(v, grad_g), NF_OK);
            }
            assert_int_equal(nf_model_get_params(g, params_g), NF_OK);
            assert_int_equal(nf_model_get_params(v, params_v), NF_OK);
            assert_memory_equal(params_g, params_v, count * sizeof(float));
            free(params_g);
            free(params_v);
            free(grad_g);
            free(grad_v);
            nf_model_destroy(g);
            nf_model_destroy(v);
        }
    }
}

static void test_variants_agree(void **state)
{
    (void)state;
    int compared = 0;
    for (int isa = NF_ISA_AVX2; isa <= NF_ISA_AVX512; ++isa) {
        nf_config cfg;
        nf_config_init(&cfg, NF_PRESET_SMALL);
        cfg.isa = (nf_isa)isa;
        nf_model *m = NULL;
        nf_status st = nf_model_create(&cfg, &m);
        if (st != NF_OK) {
            /* a CPU without the extension: refused, with a message, and nothing leaked */
            assert_int_equal(st, NF_ERROR_INVALID_ARGUMENT);
            assert_null(m);
            assert_true(strlen(nf_last_error_message()) > 0);
            continue;
        }
        assert_string_equal(nf_model_isa_name(m), isa == NF_ISA_AVX2 ? "avx2" : "avx512");
        nf_model_destroy(m);
        compare_with_generic((nf_isa)isa);
        ++compared;
    }
    print_message("compared %d instruction-set variants with the generic kernels\n", compared);
}

/* AVX2 and AVX-512 perform the same IEEE operations (both fuse the conditioners' multiply-adds;
 * AVX2 holds a tile in two registers, lane by lane the same): a renderer gets the same
 * samples, densities and gradients on either kind of machine, to the bit. */
static void test_fused_variants_agree_to_the_bit(void **state)
{
    (void)state;
    static nf_context ctx[N];
    static float u[2 * N], dir_a[3 * N], dir_b[3 * N], pdf_a[N], pdf_b[N], w[N];
    random_inputs(7u, ctx, u, w);
    for (int preset = 0; preset < 2; ++preset) {
        for (int prior = 0; prior < 3; ++prior) {
            nf_model *a = make_model((nf_preset)preset, (nf_prior_kind)prior, NF_ISA_AVX2);
            nf_model *b = make_model((nf_preset)preset, (nf_prior_kind)prior, NF_ISA_AVX512);
            if (!a || !b) {
                /* a CPU or build without both: nothing to compare (test_variants_agree
                 * checks the refusal) */
                nf_model_destroy(a);
                nf_model_destroy(b);
                print_message("AVX2 and AVX-512 not both available: skipped\n");
                return;
            }
            /* n = 1 takes the per-sample path, N the tiles: both must match */
            for (int n = 1; n <= N; n += N - 1) {
                assert_int_equal(nf_sample(a, (size_t)n, ctx, u, dir_a, pdf_a), NF_OK);
                assert_int_equal(nf_sample(b, (size_t)n, ctx, u, dir_b, pdf_b), NF_OK);
                assert_memory_equal(dir_a, dir_b, 3 * (size_t)n * sizeof(float));
                assert_memory_equal(pdf_a, pdf_b, (size_t)n * sizeof(float));
                assert_int_equal(nf_pdf(a, (size_t)n, ctx, dir_a, pdf_a), NF_OK);
                assert_int_equal(nf_pdf(b, (size_t)n, ctx, dir_a, pdf_b), NF_OK);
                assert_memory_equal(pdf_a, pdf_b, (size_t)n * sizeof(float));
            }
            size_t count = nf_model_param_count(a);
            float *grad_a = malloc(count * sizeof(float)), *grad_b = malloc(count * sizeof(float));
            float loss_a, loss_b;
            assert_non_null(grad_a);
            assert_non_null(grad_b);
            assert_int_equal(nf_loss_gradient(a, N, ctx, dir_a, w, &loss_a, grad_a), NF_OK);
            assert_int_equal(nf_loss_gradient(b, N, ctx, dir_a, w, &loss_b, grad_b), NF_OK);
            assert_memory_equal(&loss_a, &loss_b, sizeof loss_a);
            assert_memory_equal(grad_a, grad_b, count * sizeof(float));
            free(grad_a);
            free(grad_b);
            nf_model_destroy(a);
            nf_model_destroy(b);
        }
    }
}

static void test_auto_and_invalid(void **state)
{
    (void)state;
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    nf_model *m = nft_model_from(&cfg);
    assert_true(strlen(nf_model_isa_name(m)) > 0);
    nf_model_destroy(m);
    memset(&cfg.isa, 0x7f, sizeof cfg.isa); /* not an nf_isa value */
    m = (nf_model *)&cfg;                   /* must be overwritten with NULL */
    assert_int_equal(nf_model_create(&cfg, &m), NF_ERROR_INVALID_ARGUMENT);
    assert_null(m);
    assert_string_equal(nf_model_isa_name(NULL), "");
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_variants_agree),
    cmocka_unit_test(test_fused_variants_agree_to_the_bit),
    cmocka_unit_test(test_auto_and_invalid),
)
