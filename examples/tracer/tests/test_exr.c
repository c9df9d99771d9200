/*
 * test_exr.c - image files and metrics: float RGB OpenEXR round trips bit for bit (odd
 * sizes, so that the last ZIP chunk is partial; extreme and special values; a chunk that zlib
 * cannot shrink, which must be stored raw), unreadable files are errors, PNG previews are
 * written, and MAPE / relMSE / downsampling compute what their definitions say.
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

#include "nf_test_main.h"
#include <openexr.h>
#if TRACER_TEST_ZLIB
#include <zlib.h>
#endif

#include "image.h"
#include "metrics.h"
#include "rng.h"

static void tmp_path(char *out, size_t size, const char *name)
{
    snprintf(out, size, "%s/%s", TRACER_TEST_TMP_DIR, name);
}

static void round_trip(int w, int h, uint64_t seed)
{
    image a, b;
    tr_error err;
    char path[1024];
    tmp_path(path, sizeof path, "round_trip.exr");
    assert_true(image_alloc(&a, w, h, &err));
    rng r = rng_seed(seed, RNG_TEST, 0, 0);
    size_t n = (size_t)w * (size_t)h * 3u;
    for (size_t i = 0; i < n; ++i) {
        /* Values over many magnitudes and both signs, so that no bit pattern is special. */
        float v = ldexpf(rng_next(&r), (int)(rng_next_u32(&r) % 80u) - 40);
        a.data[i] = (rng_next_u32(&r) & 1u) ? -v : v;
    }
    a.data[0] = 0.0f;
    a.data[1] = -0.0f;
    a.data[2] = 3.4028235e38f;
    if (n > 5) {
        a.data[3] = 1.0e-45f; /* the smallest denormal */
        a.data[4] = INFINITY;
        a.data[5] = -INFINITY;
    }
    if (!image_write_exr(&a, path, &err))
        fail_msg("%s", err.msg);
    if (!image_read_exr(path, &b, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(b.width, w);
    assert_int_equal(b.height, h);
    assert_memory_equal(a.data, b.data, n * sizeof(float)); /* bit-exact */
    image_free(&a);
    image_free(&b);
}

static void test_exr_round_trip_is_bit_exact(void **state)
{
    (void)state;
    round_trip(1, 1, 1);
    round_trip(37, 23, 2);   /* 23 lines: one full 16-line ZIP chunk and a partial one */
    round_trip(256, 129, 3);
    round_trip(5, 300, 4);
}

#if TRACER_TEST_ZLIB
/* What OpenEXR's ZIP compressor feeds zlib: the bytes split into even and odd halves, then
 * each byte replaced by its difference to the one before, plus 128. */
static void zip_predict(const uint8_t *raw, size_t n, uint8_t *out)
{
    for (size_t i = 0; i < n; ++i)
        out[(i & 1u) ? (n + 1) / 2 + i / 2 : i / 2] = raw[i];
    for (size_t i = n; i-- > 1;)
        out[i] = (uint8_t)(out[i] - out[i - 1] + 128);
}

/* A chunk whose zlib output is exactly as long as its raw bytes: a reader takes it for raw
 * bytes, so the writer must store it raw (OpenEXR 3.1 kept zlib's output and the chunk read
 * back as noise). The chunk is one line of 64 pixels, B, G and R planes of floats as OpenEXR
 * packs them; the candidates have 13 random low bits, where zlib's output straddles the raw
 * size (39 of 2,000 land on it with the zlib of Debian 12; 12 bits stay 53 bytes below it on
 * average, 14 bits above). */
static void test_exr_chunk_zlib_cannot_shrink_is_stored_raw(void **state)
{
    (void)state;
    enum { W = 64, FLOATS = 3 * W, BYTES = 4 * FLOATS };
    uint32_t bits[FLOATS];
    uint8_t predicted[BYTES], packed[BYTES + 64];
    int level = -1;
    exr_get_default_zip_compression_level(&level);
    rng r = rng_seed(7, RNG_TEST, 0, 0);
    int found = 0;
    const uint32_t mask = (1u << 13) - 1u;
    for (int trial = 0; trial < 100000 && !found; ++trial) {
        for (int i = 0; i < FLOATS; ++i)
            bits[i] = (rng_next_u32(&r) & mask) | (0x3f000000u & ~mask);
        zip_predict((const uint8_t *)bits, BYTES, predicted);
        uLongf size = sizeof packed;
        assert_int_equal(compress2(packed, &size, predicted, BYTES, level), Z_OK);
        found = size == BYTES;
    }
    assert_true(found); /* else the search needs other candidates for this zlib */
    image a, b;
    tr_error err;
    char path[1024];
    tmp_path(path, sizeof path, "zlib_cannot_shrink.exr");
    assert_true(image_alloc(&a, W, 1, &err));
    for (int x = 0; x < W; ++x) /* the planes in OpenEXR's channel order: B, G, R */
        for (int c = 0; c < 3; ++c)
            memcpy(&a.data[3 * x + 2 - c], &bits[c * W + x], sizeof(float));
    if (!image_write_exr(&a, path, &err))
        fail_msg("%s", err.msg);
    if (!image_read_exr(path, &b, &err))
        fail_msg("%s", err.msg);
    assert_memory_equal(a.data, b.data, sizeof bits); /* bit-exact */
    image_free(&a);
    image_free(&b);
}
#else
static void test_exr_chunk_zlib_cannot_shrink_is_stored_raw(void **state)
{
    (void)state;
    skip(); /* built without zlib (tests/CMakeLists.txt) */
}
#endif

static void test_exr_errors(void **state)
{
    (void)state;
    image img;
    tr_error err;
    char path[1024];
    assert_false(image_read_exr("/nonexistent/dir/x.exr", &img, &err));
    assert_non_null(strstr(err.msg, "/nonexistent/dir/x.exr"));
    assert_null(img.data);

    /* Not an EXR file. */
    tmp_path(path, sizeof path, "not_an.exr");
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    fputs("this is not an OpenEXR file", f);
    fclose(f);
    assert_false(image_read_exr(path, &img, &err));
    assert_non_null(strstr(err.msg, "not_an.exr"));

    /* A truncated EXR file. */
    image a;
    assert_true(image_alloc(&a, 64, 64, &err));
    for (size_t i = 0; i < 64u * 64u * 3u; ++i)
        a.data[i] = (float)i;
    tmp_path(path, sizeof path, "truncated.exr");
    assert_true(image_write_exr(&a, path, &err));
    image_free(&a);
    f = fopen(path, "rb+");
    assert_non_null(f);
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fclose(f);
    assert_int_equal(truncate(path, size / 2), 0);
    assert_false(image_read_exr(path, &img, &err));

    /* Writing into a directory that does not exist fails cleanly. */
    assert_true(image_alloc(&a, 4, 4, &err));
    assert_false(image_write_exr(&a, "/nonexistent/dir/y.exr", &err));
    assert_false(image_write_png(&a, "/nonexistent/dir/y.png", 0.0f, &err));
    image_free(&a);
}

static void test_png_preview(void **state)
{
    (void)state;
    image a, b;
    tr_error err;
    char path[1024];
    assert_true(image_alloc(&a, 3, 1, &err));
    a.data[0] = 1.0f;   /* white stays white */
    a.data[3] = 0.5f;   /* linear 0.5 is sRGB 188 */
    a.data[6] = NAN;    /* non-finite values become black rather than garbage */
    tmp_path(path, sizeof path, "preview.png");
    assert_true(image_write_png(&a, path, 0.0f, &err));
    /* Read it back raw (no sRGB decoding): 8-bit codes / 255. */
    if (!image_load_ldr(path, 0, &b, NULL, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(b.width, 3);
    assert_float_equal(b.data[0], 1.0f, 1e-6f);
    assert_float_equal(b.data[3] * 255.0f, 188.0f, 1e-3f);
    assert_float_equal(b.data[6], 0.0f, 0.0f);
    image_free(&a);
    image_free(&b);
}

static void test_metrics(void **state)
{
    (void)state;
    image ref, img, small;
    tr_error err;
    assert_true(image_alloc(&ref, 2, 2, &err));
    assert_true(image_alloc(&img, 2, 2, &err));
    for (int i = 0; i < 12; ++i) {
        ref.data[i] = 1.0f;
        img.data[i] = 1.0f;
    }
    assert_float_equal(image_mape(&ref, &img), 0.0, 0.0);
    assert_float_equal(image_relmse(&ref, &img), 0.0, 0.0);
    /* One channel off by 0.5 against a reference of 1: |dv| / (1 + 0.01) over 12 values. */
    img.data[5] = 1.5f;
    assert_float_equal(image_mape(&ref, &img), 0.5 / 1.01 / 12.0, 1e-9);
    assert_float_equal(image_relmse(&ref, &img), 0.25 / 1.01 / 12.0, 1e-9);
    /* A black reference pixel: the epsilon bounds the relative error. */
    ref.data[0] = 0.0f;
    img.data[0] = 0.01f;
    img.data[5] = 1.0f;
    assert_float_equal(image_mape(&ref, &img), 1.0 / 12.0, 1e-9);

    /* The tail: pixel 0 has relMSE 1e-4 / 0.01 = 0.01 (its other channels are exact); pixel 3
     * is off by 2 in one channel, 4 / 1.01. */
    double worst, body, e0 = 0.01, e3 = 4.0 / 1.01;
    img.data[9] = 3.0f;
    image_relmse_tail(&ref, &img, 1, &worst, &body);
    assert_float_equal(worst, e3 / (e0 + e3), 1e-9);
    assert_float_equal(body, e0 / 12.0, 1e-9);
    image_relmse_tail(&ref, &img, 2, &worst, &body);
    assert_float_equal(body, 0.0, 0.0);
    /* More pixels asked than carry an error, and ties: never more than k are left out. */
    img.data[6] = 3.0f; /* pixel 2 ties with pixel 3 */
    image_relmse_tail(&ref, &img, 1, &worst, &body);
    assert_float_equal(body, (e0 + e3) / 12.0, 1e-9);
    image_relmse_tail(&ref, &img, 3, &worst, &body);
    assert_float_equal(body, 0.0, 0.0);
    image_relmse_tail(&ref, &img, 4, &worst, &body);
    assert_float_equal(body, 0.0, 0.0);
    img.data[6] = img.data[9] = 1.0f;
    img.data[0] = 0.0f;
    image_relmse_tail(&ref, &img, 3, &worst, &body); /* an exact image */
    assert_float_equal(worst, 0.0, 0.0);
    assert_float_equal(body, 0.0, 0.0);
    img.data[4] = NAN; /* as relMSE, a NaN is not hidden */
    image_relmse_tail(&ref, &img, 3, &worst, &body);
    assert_true(isnan(worst) && isnan(body));
    img.data[4] = 1.0f;

    /* Downsampling averages blocks; sizes must be integer multiples. */
    for (int i = 0; i < 12; ++i)
        ref.data[i] = (float)i;
    assert_true(image_downsample(&ref, 1, 1, &small, &err));
    assert_float_equal(small.data[0], (0 + 3 + 6 + 9) / 4.0f, 1e-6f);
    assert_float_equal(small.data[2], (2 + 5 + 8 + 11) / 4.0f, 1e-6f);
    image_free(&small);
    assert_false(image_downsample(&ref, 3, 1, &small, &err));
    image_free(&ref);
    image_free(&img);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_exr_round_trip_is_bit_exact),
    cmocka_unit_test(test_exr_chunk_zlib_cannot_shrink_is_stored_raw),
    cmocka_unit_test(test_exr_errors),
    cmocka_unit_test(test_png_preview),
    cmocka_unit_test(test_metrics),
)
