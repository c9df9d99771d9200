/*
 * test_load_messages.c - the messages of nf_model_load and nf_model_save (io.h): they name the
 * function the caller called and the path, and a file that cannot be opened gives the C
 * library's reason (strerror), so that a renderer's log says what went wrong where.
 */
#define _POSIX_C_SOURCE 200809L /* getpid */

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "nf_test_support.h"

static void assert_contains(const char *text, const char *part)
{
    if (!strstr(text, part))
        fail_msg("message \"%s\" lacks \"%s\"", text, part);
}

static void temp_path(char *buf, size_t cap, const char *name)
{
    snprintf(buf, cap, "%s/nf_msg_%ld_%s", NF_TEST_BINARY_DIR, (long)getpid(), name);
}

/* nf_model_load's message for `path`, which it must refuse with `expected` and no model. */
static const char *load_refused(const char *path, nf_status expected)
{
    nf_model *out = NULL;
    assert_int_equal(nf_model_load(path, NULL, &out), expected);
    assert_null(out);
    return nf_last_error_message();
}

static void test_missing_file(void **state)
{
    (void)state;
    char path[512];
    temp_path(path, sizeof path, "does_not_exist.nf");
    remove(path);
    const char *msg = load_refused(path, NF_ERROR_IO);
    assert_contains(msg, "nf_model_load");
    assert_contains(msg, "does_not_exist.nf");
    assert_contains(msg, strerror(ENOENT));
}

/* A file too short to be a model: the message names nf_model_load (the caller's function, not
 * the internal decoder) and the file. */
static void test_garbage_file(void **state)
{
    (void)state;
    char path[512];
    temp_path(path, sizeof path, "garbage.nf");
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite("hello world", 1, 11, f), 11);
    assert_int_equal(fclose(f), 0);
    const char *msg = load_refused(path, NF_ERROR_FORMAT);
    assert_contains(msg, "nf_model_load");
    assert_contains(msg, "garbage.nf");
    assert_contains(msg, "too short");
    assert_null(strstr(msg, "nf_model_deserialize"));
    remove(path);

    /* The same bytes through nf_model_deserialize name that function. */
    nf_model *out = NULL;
    assert_int_equal(nf_model_deserialize("hello world", 11, NULL, &out), NF_ERROR_FORMAT);
    assert_contains(nf_last_error_message(), "nf_model_deserialize");
}

/* A long path keeps its end (the file name) and leaves room for the reason. */
static void test_long_path(void **state)
{
    (void)state;
    char path[600];
    int len = snprintf(path, sizeof path, "%s/", NF_TEST_BINARY_DIR);
    while (len < 400) /* directories of 40 bytes: a name over 255 bytes gives ENAMETOOLONG */
    {
        path[len] = len % 41 == 0 ? '/' : 'd';
        ++len;
    }
    snprintf(path + len, sizeof path - (size_t)len, "/tail_name.nf");
    const char *msg = load_refused(path, NF_ERROR_IO);
    assert_contains(msg, "nf_model_load");
    assert_contains(msg, "tail_name.nf");
    assert_contains(msg, strerror(ENOENT));
}

static void test_save_into_missing_directory(void **state)
{
    (void)state;
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    nf_model *m = nft_model_from(&cfg);
    char path[512];
    temp_path(path, sizeof path, "no_such_dir/model.nf");
    assert_int_equal(nf_model_save(m, path), NF_ERROR_IO);
    const char *msg = nf_last_error_message();
    assert_contains(msg, "nf_model_save");
    assert_contains(msg, "model.nf");
    assert_contains(msg, strerror(ENOENT));
    nf_model_destroy(m);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_missing_file),
    cmocka_unit_test(test_garbage_file),
    cmocka_unit_test(test_long_path),
    cmocka_unit_test(test_save_into_missing_directory),
)
