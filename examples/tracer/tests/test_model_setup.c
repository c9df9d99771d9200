/*
 * test_model_setup.c - the tracer's checks on a loaded model: a model made for a scene matches it
 * (also after a save and load), a model made for another scene is reported with both boxes.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "model_setup.h"
#include "scene.h"

#include "mixed_scene.h"

/* The mixed scene moved 10 units along x: the same size, other places. */
static const char moved_xml[] =
    "<scene version=\"3.0.0\">\n"
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"55\"/>\n"
    "  <transform name=\"to_world\"><lookat origin=\"10, 0, 3\" target=\"10, 0, 0\" up=\"0, 1, 0\"/></transform>\n"
    "  <film type=\"hdrfilm\"><integer name=\"width\" value=\"8\"/><integer name=\"height\" value=\"8\"/></film>\n"
    "</sensor>\n"
    "<shape type=\"rectangle\"><transform name=\"to_world\"><translate x=\"10\" z=\"-1\"/></transform>"
    "<bsdf type=\"diffuse\"/></shape>\n"
    "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"0.3\"/><rotate x=\"1\" angle=\"90\"/><translate x=\"10\" y=\"1\"/></transform>"
    "<emitter type=\"area\"><rgb name=\"radiance\" value=\"8\"/></emitter></shape>\n"
    "</scene>\n";

static void test_bounds_match(void **state)
{
    (void)state;
    scene mixed, moved;
    tr_error err;
    if (!scene_load_string(MIXED_SCENE_XML, TRACER_TEST_TMP_DIR, &mixed, &err) ||
        !scene_load_string(moved_xml, TRACER_TEST_TMP_DIR, &moved, &err))
        fail_msg("%s", err.msg);
    model_settings gs = model_default_settings(MODEL_PRIOR_COSINE);
    nf_model *model = NULL, *loaded = NULL;
    if (!model_create_for_scene(&mixed, &gs, NULL, &model, &err))
        fail_msg("%s", err.msg);
    char msg[512] = "";
    assert_true(model_bounds_match(&mixed, model, msg, sizeof msg));
    assert_string_equal(msg, "");

    /* What --save-model and --load-model do. */
    char path[4096];
    snprintf(path, sizeof path, "%s/test_guide.nf", TRACER_TEST_TMP_DIR);
    assert_int_equal(nf_model_save(model, path), NF_OK);
    if (!model_load_file(path, NULL, &loaded, &err))
        fail_msg("%s", err.msg);
    assert_true(model_bounds_match(&mixed, loaded, msg, sizeof msg));

    assert_false(model_bounds_match(&moved, loaded, msg, sizeof msg));
    printf("  %s\n", msg);
    assert_non_null(strstr(msg, "another scene"));
    assert_non_null(strstr(msg, "position bounds"));
    nf_model_destroy(model);
    nf_model_destroy(loaded);
    remove(path);
    scene_free(&mixed);
    scene_free(&moved);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_bounds_match),
)
