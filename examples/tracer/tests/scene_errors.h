/*
 * scene_errors.h - the tracer tests' check of a refused scene, their load of a shipped one
 * and their scratch files, shared by test_scene.c, test_limits.c and test_interiors.c:
 * include it after <cmocka.h>, <stdio.h> and "scene.h".
 */
#ifndef TRACER_TEST_SCENE_ERRORS_H
#define TRACER_TEST_SCENE_ERRORS_H

#include <stdarg.h>
#include <string.h>

/* The first fragment of `ap` (up to a NULL) that `msg` lacks, or NULL: the caller ends ap
 * before it fails, as a failure jumps out of the test. */
static const char *missing_fragment(const char *msg, va_list ap)
{
    for (const char *frag = va_arg(ap, const char *); frag; frag = va_arg(ap, const char *))
        if (!strstr(msg, frag))
            return frag;
    return NULL;
}

/* Loads `xml` (which must fail) and checks that the message contains every fragment given
 * after it, up to a NULL. */
static void expect_error(const char *xml, ...)
{
    scene s;
    tr_error err;
    if (scene_load_string(xml, TRACER_TEST_TMP_DIR, &s, &err)) {
        scene_free(&s);
        fail_msg("loaded a scene that must be refused:\n%s", xml);
    }
    va_list ap;
    va_start(ap, xml);
    const char *lacks = missing_fragment(err.msg, ap);
    va_end(ap);
    if (lacks)
        fail_msg("error message\n  %s\nlacks '%s'", err.msg, lacks);
}

/* Loads examples/scenes/<name>/scene.xml, failing the test with the loader's message. */
static inline void load_shipped(const char *name, scene *s)
{
    char path[1024];
    tr_error err;
    snprintf(path, sizeof path, "%s/%s/scene.xml", TRACER_SCENES_DIR, name);
    if (!scene_load(path, s, &err))
        fail_msg("%s", err.msg);
}

/* Writes `size` bytes, or a string, to a new file at `path`. */
static inline void write_file(const char *path, const void *data, size_t size)
{
    FILE *f = fopen(path, "wb");
    assert_non_null(f);
    assert_int_equal(fwrite(data, 1, size, f), size);
    fclose(f);
}

static inline void write_text(const char *path, const char *text)
{
    write_file(path, text, strlen(text));
}

#endif /* TRACER_TEST_SCENE_ERRORS_H */
