/*
 * test_set_isa.c - nf_model_set_isa (model.h): a model switched to an instruction set computes
 * the same bits as one created with it, before and after training, and a loaded model resumes
 * a checkpoint to the same bits as the model it was saved from. Bad values are refused and
 * leave the model unchanged.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_support.h"
#include "shading_point.h"

#define N 53u    /* three tiles, the last partial                        */
#define STEPS 6u /* enough for AdamW's moments to matter in every weight */

typedef struct batch {
    nf_context ctx[N];
    float u[2 * N], dir[3 * N], w[N];
} batch;

static void make_batch(uint64_t seed, batch *b)
{
    nft_rng r;
    nft_rng_seed(&r, seed, 5u);
    for (size_t i = 0; i < N; ++i) {
        nft_random_context(&r, &b->ctx[i]);
        nft_random_unit_vector(&r, b->dir + 3 * i);
        b->u[2 * i] = nft_rng_float(&r);
        b->u[2 * i + 1] = nft_rng_float(&r);
        b->w[i] = nft_rng_float(&r) * 4.0f;
    }
}

static nf_model *make_model(nf_isa isa)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_LARGE);
    nft_apply_phi_map(&cfg);
    cfg.isa = isa;
    cfg.learning_rate = 1e-2f; /* large steps: any difference of kernels shows at once */
    nf_model *m = nft_model_from(&cfg);
    return m;
}

static void train(nf_model *m, unsigned steps, uint64_t seed)
{
    static batch b;
    for (unsigned s = 0; s < steps; ++s) {
        make_batch(seed + s, &b);
        assert_int_equal(nf_train_step(m, N, b.ctx, b.dir, b.w, NULL), NF_OK);
    }
}

/* Bit equality, as the generic kernels promise on every machine: parameters, optimizer
 * state (through the serialized bytes), samples and densities. No tolerance: the point of
 * choosing the set is identical results. */
static void assert_same_bits(const nf_model *a, const nf_model *b)
{
    size_t count = nf_model_param_count(a);
    assert_int_equal(count, nf_model_param_count(b));
    assert_int_equal(nf_model_step_count(a), nf_model_step_count(b));
    float *pa = malloc(count * sizeof(float)), *pb = malloc(count * sizeof(float));
    assert_non_null(pa);
    assert_non_null(pb);
    assert_int_equal(nf_model_get_params(a, pa), NF_OK);
    assert_int_equal(nf_model_get_params(b, pb), NF_OK);
    assert_memory_equal(pa, pb, count * sizeof(float));
    free(pa);
    free(pb);
    size_t sa = 0, sb = 0;
    assert_int_equal(nf_model_serialize(a, NULL, 0, &sa), NF_OK);
    assert_int_equal(nf_model_serialize(b, NULL, 0, &sb), NF_OK);
    assert_int_equal(sa, sb);
    unsigned char *ba = malloc(sa), *bb = malloc(sb);
    assert_non_null(ba);
    assert_non_null(bb);
    assert_int_equal(nf_model_serialize(a, ba, sa, &sa), NF_OK);
    assert_int_equal(nf_model_serialize(b, bb, sb, &sb), NF_OK);
    assert_memory_equal(ba, bb, sa);
    free(ba);
    free(bb);

    static batch q;
    static float da[3 * N], db[3 * N], qa[N], qb[N];
    make_batch(99u, &q);
    for (size_t n = 1; n <= N; n += N - 1) { /* the per-sample path and the tiles */
        assert_int_equal(nf_sample(a, n, q.ctx, q.u, da, qa), NF_OK);
        assert_int_equal(nf_sample(b, n, q.ctx, q.u, db, qb), NF_OK);
        assert_memory_equal(da, db, 3 * n * sizeof(float));
        assert_memory_equal(qa, qb, n * sizeof(float));
        assert_int_equal(nf_pdf(a, n, q.ctx, q.dir, qa), NF_OK);
        assert_int_equal(nf_pdf(b, n, q.ctx, q.dir, qb), NF_OK);
        assert_memory_equal(qa, qb, n * sizeof(float));
    }
}

static void test_switched_model_trains_like_a_created_one(void **state)
{
    (void)state;
    nf_model *created = make_model(NF_ISA_GENERIC);
    nf_model *switched = make_model(NF_ISA_AUTO);
    assert_int_equal(nf_model_set_isa(switched, NF_ISA_GENERIC), NF_OK);
    assert_string_equal(nf_model_isa_name(switched), "generic");
    nf_config cfg;
    assert_int_equal(nf_model_get_config(switched, &cfg), NF_OK);
    assert_int_equal(cfg.isa, NF_ISA_GENERIC);
    train(created, STEPS, 1000u);
    train(switched, STEPS, 1000u);
    assert_same_bits(created, switched);
    nf_model_destroy(created);
    nf_model_destroy(switched);
}

/* The render-farm case: a checkpoint written on one machine, loaded (NF_ISA_AUTO) and set to
 * the generic kernels, resumes training to the same bits as the model that wrote it. */
static void test_loaded_model_resumes_like_the_original(void **state)
{
    (void)state;
    nf_model *original = make_model(NF_ISA_GENERIC);
    train(original, STEPS, 2000u);
    size_t size = 0;
    assert_int_equal(nf_model_serialize(original, NULL, 0, &size), NF_OK);
    unsigned char *buf = malloc(size);
    assert_non_null(buf);
    assert_int_equal(nf_model_serialize(original, buf, size, &size), NF_OK);
    nf_model *loaded = NULL;
    assert_int_equal(nf_model_deserialize(buf, size, NULL, &loaded), NF_OK);
    free(buf);
    assert_int_equal(nf_model_set_isa(loaded, NF_ISA_GENERIC), NF_OK);
    assert_same_bits(original, loaded);
    train(original, STEPS, 3000u);
    train(loaded, STEPS, 3000u);
    assert_same_bits(original, loaded);
    /* a clone keeps the chosen set */
    nf_model *copy = NULL;
    assert_int_equal(nf_model_clone(loaded, &copy), NF_OK);
    assert_string_equal(nf_model_isa_name(copy), "generic");
    nf_model_destroy(copy);
    nf_model_destroy(original);
    nf_model_destroy(loaded);
}

/* Refusals: NULL, values outside the enum, and sets the CPU lacks leave the model as it was. */
static void test_refusals_leave_the_model_unchanged(void **state)
{
    (void)state;
    nf_model *m = make_model(NF_ISA_GENERIC);
    nf_model *reference = make_model(NF_ISA_GENERIC);
    train(m, 2, 4000u);
    train(reference, 2, 4000u);
    assert_int_equal(nf_model_set_isa(NULL, NF_ISA_GENERIC), NF_ERROR_INVALID_ARGUMENT);
    assert_non_null(strstr(nf_last_error_message(), "nf_model_set_isa"));
    const int bad[] = {4, -1, 0x7f7f7f7f};
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; ++k) {
        nf_isa isa;
        int v = bad[k];
        memcpy(&isa, &v, sizeof isa < sizeof v ? sizeof isa : sizeof v);
        assert_int_equal(nf_model_set_isa(m, isa), NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), "nf_model_set_isa"));
        assert_non_null(strstr(nf_last_error_message(), "not an nf_isa value"));
        assert_string_equal(nf_model_isa_name(m), "generic");
    }
    for (int isa = NF_ISA_AVX2; isa <= NF_ISA_AVX512; ++isa) {
        nf_status st = nf_model_set_isa(m, (nf_isa)isa);
        if (st == NF_OK) {
            assert_string_equal(nf_model_isa_name(m), isa == NF_ISA_AVX2 ? "avx2" : "avx512");
            assert_int_equal(nf_model_set_isa(m, NF_ISA_GENERIC), NF_OK);
            continue;
        }
        /* a CPU or build without the set: refused, saying what is missing */
        assert_int_equal(st, NF_ERROR_INVALID_ARGUMENT);
        assert_non_null(strstr(nf_last_error_message(), "nf_model_set_isa"));
        assert_non_null(strstr(nf_last_error_message(), "needs"));
        assert_string_equal(nf_model_isa_name(m), "generic");
    }
    nf_config cfg;
    assert_int_equal(nf_model_get_config(m, &cfg), NF_OK);
    assert_int_equal(cfg.isa, NF_ISA_GENERIC);
    train(m, 2, 5000u);
    train(reference, 2, 5000u);
    assert_same_bits(m, reference);
    nf_model_destroy(m);
    nf_model_destroy(reference);
}

/* Points hold context sums of the kernels that prepared them: a change of kernels makes them
 * stale, setting the set the model already runs does not. */
static void test_points_go_stale_when_the_kernels_change(void **state)
{
    (void)state;
    nf_model *m = make_model(NF_ISA_GENERIC);
    nf_context ctx = nft_context(0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.0f, 0.6f, 0.8f);
    nf_shading_point p;
    float u[2] = {0.25f, 0.75f}, dir[3], pdf;
    assert_int_equal(nf_point_prepare(m, &ctx, NULL, &p), NF_OK);
    assert_int_equal(nf_model_set_isa(m, NF_ISA_GENERIC), NF_OK);
    assert_int_equal(nf_point_sample(m, &p, 1, u, dir, &pdf), NF_OK);
    assert_int_equal(nf_model_set_isa(m, NF_ISA_AUTO), NF_OK);
    nf_status expected = strcmp(nf_model_isa_name(m), "generic") == 0 ? NF_OK : NF_ERROR_STALE;
    assert_int_equal(nf_point_sample(m, &p, 1, u, dir, &pdf), expected);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_switched_model_trains_like_a_created_one),
    cmocka_unit_test(test_loaded_model_resumes_like_the_original),
    cmocka_unit_test(test_refusals_leave_the_model_unchanged),
    cmocka_unit_test(test_points_go_stale_when_the_kernels_change),
)
