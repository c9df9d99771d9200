/*
 * test_hostile_files.c - nf_model_load and nf_model_save on paths that are not ordinary model
 * files (docs/robustness.md): a directory, an empty device, an endless one, a device that
 * refuses writes, a file of the right size full of zeros, a valid file with a foreign
 * version. Each is refused with the documented status (NF_ERROR_IO when the path cannot be
 * read or written, NF_ERROR_FORMAT when what was read is not a model), *out NULL, a message,
 * and nothing else touched. test_persistence.c covers truncated, bit-flipped, other-version
 * and invalid-content buffers; this file covers what only a path can be.
 */
#define _POSIX_C_SOURCE 200809L /* getpid, access */

#include <stdarg.h>
#include <stddef.h>
#include <setjmp.h>
#include <stdint.h>
#include <cmocka.h>

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <nisflow/nisflow.h>

#include "nf_test_support.h"

static void expect_load(const char *path, nf_status expect, const char *what)
{
    nf_model *out = (nf_model *)(uintptr_t)0x1; /* never dereferenced */
    nf_status st = nf_model_load(path, NULL, &out);
    if (st != expect || out != NULL)
        fail_msg("%s (%s): status %s, expected %s; out %s", what, path, nf_status_string(st),
                 nf_status_string(expect), out ? "not NULL" : "NULL");
    assert_true(nf_last_error_message()[0] != '\0');
}

static void test_load_directory(void **state)
{
    (void)state;
    /* fopen succeeds on a directory on Linux; reading it fails: an I/O error. */
    expect_load(".", NF_ERROR_IO, "a directory");
}

static void test_load_devices(void **state)
{
    (void)state;
    if (access("/dev/null", R_OK) != 0 || access("/dev/zero", R_OK) != 0) {
        print_message("  skipped: no /dev/null or /dev/zero\n");
        skip();
    }
    /* Empty: too short for a model. */
    expect_load("/dev/null", NF_ERROR_FORMAT, "an empty device");
    /* Endless: the reader stops at 256 MB ("larger than any model") instead of reading
     * forever or exhausting memory. */
    expect_load("/dev/zero", NF_ERROR_FORMAT, "an endless device");
    assert_non_null(strstr(nf_last_error_message(), "larger than any model"));
}

static void test_save_unwritable(void **state)
{
    nf_model *m = *state;
    nft_snapshot snap = nft_snapshot_of(m);
    /* A directory cannot be opened for writing. */
    assert_int_equal(nf_model_save(m, "."), NF_ERROR_IO);
    /* /dev/full accepts the open and refuses the data (ENOSPC): the short write is noticed
     * (fwrite or fclose fails) and reported, not ignored. */
    if (access("/dev/full", W_OK) == 0) {
        assert_int_equal(nf_model_save(m, "/dev/full"), NF_ERROR_IO);
        assert_non_null(strstr(nf_last_error_message(), "could not write"));
    } else {
        print_message("  no /dev/full: the short-write case was not checked\n");
    }
    assert_true(nft_snapshot_equal(m, &snap));
    nft_snapshot_free(&snap);
}

/* Files of exactly the right size whose content is not a model: all zeros, all 0xFF, the
 * right magic then zeros (every header field invalid), and a valid file whose version field
 * was changed without fixing the checksum. */
static void test_load_wrong_content(void **state)
{
    (void)state;
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_UNIFORM_DIRECTION);
    size_t size = 0;
    assert_int_equal(nf_model_serialize(m, NULL, 0, &size), NF_OK);
    unsigned char *good = malloc(size), *buf = malloc(size);
    assert_true(good && buf);
    assert_int_equal(nf_model_serialize(m, good, size, &size), NF_OK);
    char path[128];
    snprintf(path, sizeof path, "nf_test_hostile_%ld.nfm", (long)getpid());
    for (int k = 0; k < 4; ++k) {
        switch (k) {
        case 0: memset(buf, 0, size); break;
        case 1: memset(buf, 0xFF, size); break;
        case 2:
            memset(buf, 0, size);
            memcpy(buf, good, 8);
            break;
        default:
            memcpy(buf, good, size);
            buf[8] = 9; /* version 9, stale checksum */
            break;
        }
        FILE *f = fopen(path, "wb");
        assert_non_null(f);
        assert_int_equal(fwrite(buf, 1, size, f), size);
        assert_int_equal(fclose(f), 0);
        char what[64];
        snprintf(what, sizeof what, "content %d", k);
        expect_load(path, NF_ERROR_FORMAT, what);
    }
    remove(path);
    free(good);
    free(buf);
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_load_directory),
    cmocka_unit_test(test_load_devices),
    NFT_WITH_MODEL(test_save_unwritable),
    cmocka_unit_test(test_load_wrong_content),
)
