/*
 * test_scene.c - the scene loader: the four shipped scenes load with the expected contents,
 * the format's features work ($defaults, refs, transforms, built-in shapes, PLY ASCII, OBJ),
 * and every kind of malformed input gives an error naming the file, the line and the
 * element.
 */
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "mesh.h"
#include "scene.h"
#include "scene_errors.h"

static uint64_t triangle_count(const scene *s)
{
    uint64_t n = 0;
    for (int i = 0; i < s->nshapes; ++i)
        n += s->shapes[i].m.ntris;
    return n;
}


/* ---- The shipped scenes ----------------------------------------------------------------- */

static void test_cornell_box(void **state)
{
    (void)state;
    scene s;
    load_shipped("cornell-box", &s);
    assert_int_equal(s.width, 1024);
    assert_int_equal(s.height, 1024);
    assert_int_equal(s.max_depth, 65);
    assert_int_equal(s.nshapes, 8);
    assert_int_equal(triangle_count(&s), 36);
    assert_int_equal(s.env.kind, ENV_NONE);
    assert_int_equal(s.nlights, 2); /* the light's two triangles */
    /* The light (the last shape) emits (17, 12, 4) downwards. */
    assert_true(s.shapes[7].emissive);
    assert_float_equal(s.shapes[7].radiance.r, 17.0f, 0.0f);
    /* The walls are two-sided diffuse. */
    assert_int_equal(s.bsdfs[s.shapes[0].bsdf].type, BSDF_DIFFUSE);
    assert_true(s.bsdfs[s.shapes[0].bsdf].twosided);
    scene_free(&s);
}

static void test_veach_ajar(void **state)
{
    (void)state;
    scene s;
    load_shipped("veach-ajar", &s);
    /* $resx / $resy / $max_depth come from <default>. */
    assert_int_equal(s.width, 1280);
    assert_int_equal(s.height, 720);
    assert_int_equal(s.max_depth, 13);
    assert_int_equal(s.nshapes, 22);
    assert_int_equal(s.fov_axis, 0);
    int bitmaps = 0, checkerboards = 0, dielectrics = 0, beckmann = 0;
    for (int i = 0; i < s.ntextures; ++i) {
        bitmaps += s.textures[i]->kind == TEX_BITMAP;
        checkerboards += s.textures[i]->kind == TEX_CHECKERBOARD;
    }
    for (int i = 0; i < s.nshapes; ++i) {
        const bsdf *b = &s.bsdfs[s.shapes[i].bsdf];
        dielectrics += b->type == BSDF_DIELECTRIC;
        beckmann += b->type == BSDF_ROUGHCONDUCTOR && b->distribution == MF_BECKMANN;
    }
    assert_int_equal(bitmaps, 3);
    assert_int_equal(checkerboards, 1);
    assert_int_equal(dielectrics, 2);
    assert_int_equal(beckmann, 1); /* the door handle */
    /* The painting (Mesh008.ply, shape 1): texture coordinates are flipped on load (v = 0 is
     * a bitmap's top row, and the file's v points up), so its top edge samples the top of
     * the image. */
    const mesh *painting = &s.shapes[1].m;
    assert_int_equal(painting->nverts, 4);
    for (uint32_t i = 0; i < 4; ++i)
        assert_true((painting->p[i].y > 2.0f) == (painting->uv[2 * i + 1] < 0.5f));
    /* The rectangle light and its 1000-unit radiance. */
    int lights = 0;
    for (int i = 0; i < s.nshapes; ++i)
        if (s.shapes[i].emissive) {
            ++lights;
            assert_float_equal(s.shapes[i].radiance.g, 1000.0f, 0.0f);
        }
    assert_int_equal(lights, 1);
    scene_free(&s);
}

static void test_veach_bidir(void **state)
{
    (void)state;
    scene s;
    load_shipped("veach-bidir", &s);
    assert_int_equal(s.width, 1024);
    assert_int_equal(s.max_depth, 7);
    assert_int_equal(s.nshapes, 14);
    int lights = 0;
    for (int i = 0; i < s.nshapes; ++i)
        lights += s.shapes[i].emissive;
    assert_int_equal(lights, 2);
    /* The OBJ glass egg has vertex normals; face_normals meshes have none. */
    int smooth = 0;
    for (int i = 0; i < s.nshapes; ++i)
        smooth += s.shapes[i].m.n != NULL;
    assert_true(smooth >= 1);
    scene_free(&s);
}

static void test_statue(void **state)
{
    (void)state;
    scene s;
    load_shipped("statue", &s);
    assert_int_equal(s.width, 720);
    assert_int_equal(s.max_depth, 8);
    assert_int_equal(s.env.kind, ENV_CONSTANT);
    assert_true(triangle_count(&s) > 50000);
    /* The armadillo: roughplastic with GGX, smooth normals computed from the faces. */
    const shape *armadillo = &s.shapes[1];
    assert_int_equal(s.bsdfs[armadillo->bsdf].type, BSDF_ROUGHPLASTIC);
    assert_int_equal(s.bsdfs[armadillo->bsdf].distribution, MF_GGX);
    assert_non_null(armadillo->m.n);
    /* Two area lights (2 triangles each) and the environment. */
    assert_int_equal(s.nlights, 5);
    scene_free(&s);
}

/* ---- Features -------------------------------------------------------------------------------- */

#define SENSOR                                                                                \
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>"                        \
    "<film type=\"hdrfilm\"><integer name=\"width\" value=\"$w\"/>"                           \
    "<integer name=\"height\" value=\"8\"/></film></sensor>\n"

static void test_defaults_refs_and_transforms(void **state)
{
    (void)state;
    const char *xml =
        "<scene version=\"3.0.0\">\n"
        "<default name=\"w\" value=\"12\"/>\n"
        SENSOR
        "<bsdf type=\"diffuse\" id=\"white\"><rgb name=\"reflectance\" value=\"0.25, 0.5, 0.75\"/></bsdf>\n"
        "<shape type=\"rectangle\">\n"
        "  <transform name=\"to_world\"><scale value=\"2\"/><rotate x=\"1\" angle=\"90\"/>"
        "<translate x=\"1\" y=\"2\" z=\"3\"/></transform>\n"
        "  <ref id=\"white\"/>\n"
        "</shape>\n"
        "<shape type=\"cube\"><transform name=\"to_world\"><matrix value=\"1 0 0 10 0 1 0 0 0 0 1 0 0 0 0 1\"/></transform></shape>\n"
        "<shape type=\"sphere\"><point name=\"center\" value=\"0, 0, -5\"/><float name=\"radius\" value=\"0.5\"/></shape>\n"
        "</scene>\n";
    scene s;
    tr_error err;
    if (!scene_load_string(xml, ".", &s, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(s.width, 12);
    assert_int_equal(s.nshapes, 3);
    /* scale 2, then +90 degrees about x (y -> z), then translate: the rectangle spans
     * x in [-1, 3], y = 2, z in [1, 5], facing -y (rotating +z by 90 degrees about x). */
    const mesh *m = &s.shapes[0].m;
    for (uint32_t i = 0; i < m->nverts; ++i) {
        assert_float_equal(m->p[i].y, 2.0f, 1e-5f);
        assert_true(m->p[i].x > -1.0001f && m->p[i].x < 3.0001f);
        assert_true(m->p[i].z > 0.9999f && m->p[i].z < 5.0001f);
        assert_float_equal(m->n[i].y, -1.0f, 1e-5f);
    }
    /* The referenced material; shapes without one get Mitsuba's default diffuse 0.5. */
    assert_float_equal(s.bsdfs[s.shapes[0].bsdf].diffuse->value.g, 0.5f, 0.0f);
    assert_float_equal(s.bsdfs[s.shapes[1].bsdf].diffuse->value.g, 0.5f, 0.0f);
    /* The cube moved to x in [9, 11]. */
    assert_float_equal(s.bounds_max.x, 11.0f, 1e-5f);
    /* The sphere's vertices lie on it. */
    const mesh *sp = &s.shapes[2].m;
    for (uint32_t i = 0; i < sp->nverts; i += 97)
        assert_float_equal(v3_length(v3_sub(sp->p[i], v3(0.0f, 0.0f, -5.0f))), 0.5f, 1e-5f);
    scene_free(&s);
}

static void test_ply_ascii_and_obj(void **state)
{
    (void)state;
    char ply[1024], obj[1024];
    tr_error err;
    mesh m;
    snprintf(ply, sizeof ply, "%s/quad_ascii.ply", TRACER_TEST_TMP_DIR);
    write_text(ply, "ply\nformat ascii 1.0\ncomment a quad\nelement vertex 4\n"
                    "property float x\nproperty float y\nproperty float z\n"
                    "property float s\nproperty float t\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0 0 0\n1 0 0 1 0\n1 1 0 1 1\n0 1 0 0 1\n4 0 1 2 3\n");
    if (!mesh_load_ply(ply, &m, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(m.nverts, 4);
    assert_int_equal(m.ntris, 2); /* the quad became a fan of two triangles */
    assert_non_null(m.uv);
    assert_float_equal(m.uv[2 * 2 + 1], 1.0f, 0.0f);
    mesh_free(&m);

    snprintf(obj, sizeof obj, "%s/quad.obj", TRACER_TEST_TMP_DIR);
    write_text(obj, "# a quad\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n"
                    "vt 0 1\nvn 0 0 1\ng quad\nusemtl none\nf 1/1/1 2/2/1 3/3/1 4/4/1\n"
                    "f -4/-4/-1 -2/-2/-1 -1/-1/-1\n");
    if (!mesh_load_obj(obj, &m, &err))
        fail_msg("%s", err.msg);
    assert_int_equal(m.ntris, 3);
    assert_int_equal(m.nverts, 4); /* corners with equal v/vt/vn are shared */
    assert_non_null(m.n);
    mesh_free(&m);

    /* Out-of-range indices are errors, not crashes. */
    write_text(obj, "v 0 0 0\nv 1 0 0\nf 1 2 3\n");
    assert_false(mesh_load_obj(obj, &m, &err));
    assert_non_null(strstr(err.msg, "bad face index on line 3"));
    write_text(ply, "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                    "property float y\nproperty float z\nelement face 1\n"
                    "property list uchar int vertex_indices\nend_header\n");
    assert_false(mesh_load_ply(ply, &m, &err)); /* truncated data */
}

/* ---- Errors ------------------------------------------------------------------------------------ */

#define HEAD "<scene version=\"3.0.0\">\n<default name=\"w\" value=\"8\"/>\n" SENSOR

static void test_error_unknown_element(void **state)
{
    (void)state;
    expect_error(HEAD "<volume type=\"grid\"/>\n</scene>", "<string>:4:", "<volume",
                 "unknown or unsupported element", NULL);
    expect_error(HEAD "<shape type=\"cube\">\n  <phase type=\"hg\"/>\n</shape>\n</scene>",
                 "<string>:5:", "<phase", "unexpected element inside <shape type=\"cube\">", NULL);
    /* media are read (test_media.c), but a shape's must say which side it fills */
    expect_error(HEAD "<shape type=\"cube\">\n  <medium type=\"homogeneous\"/>\n</shape>\n</scene>",
                 "<string>:5:", "<medium", "needs name=\"interior\" or name=\"exterior\"", NULL);
    expect_error(HEAD "<bsdf type=\"hair\"/>\n</scene>", "<string>:4:", "unsupported BSDF type 'hair'",
                 NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\">\n<float name=\"roughness\" value=\"1\"/>\n</bsdf>\n</scene>",
                 "<string>:5:", "unsupported parameter 'roughness'", NULL);
    expect_error(HEAD "<emitter type=\"point\"/>\n</scene>", "<string>:4:", "unsupported emitter type",
                 NULL);
}

static void test_error_missing_attribute(void **state)
{
    (void)state;
    expect_error(HEAD "<shape>\n</shape>\n</scene>", "<string>:4:", "<shape>",
                 "missing attribute 'type'", NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\">\n<rgb value=\"1\"/>\n</bsdf>\n</scene>",
                 "<string>:5:", "<rgb value=\"1\">", "missing attribute 'name'", NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\">\n<rgb name=\"reflectance\"/>\n</bsdf>\n</scene>",
                 "<string>:5:", "missing attribute 'value'", NULL);
    expect_error(HEAD "<shape type=\"ply\"/>\n</scene>", "<string>:4:",
                 "missing parameter 'filename'", NULL);
}

static void test_error_bad_number(void **state)
{
    (void)state;
    expect_error("<scene version=\"3.0.0\">\n<sensor type=\"perspective\">\n"
                 "  <float name=\"fov\" value=\"wide\"/>\n</sensor>\n</scene>",
                 "<string>:3:", "<float name=\"fov\" value=\"wide\">", "'wide' is not a number",
                 NULL);
    expect_error(HEAD "<integrator type=\"path\"><integer name=\"max_depth\" value=\"6.5\"/></integrator>\n</scene>",
                 "<string>:4:", "'6.5' is not an integer", NULL);
    expect_error(HEAD "<integrator type=\"volpath\"><integer name=\"rr_depth\" value=\"0\"/></integrator>\n</scene>",
                 "<string>:4:", "rr_depth must be >= 1", NULL);
    expect_error(HEAD "<integrator type=\"volpathmis\"/>\n</scene>",
                 "<string>:4:", "unsupported integrator 'volpathmis' (path, volpath)", NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0.5, x, 0.5\"/></bsdf>\n</scene>",
                 "<string>:4:", "is not a number", NULL);
    expect_error(HEAD "<shape type=\"rectangle\"><transform name=\"to_world\">\n"
                 "<matrix value=\"1 0 0 0 1 0\"/></transform></shape>\n</scene>",
                 "<string>:5:", "a matrix needs 16 (or 9) numbers, not 6", NULL);
    expect_error(HEAD "<bsdf type=\"twosided\"><boolean name=\"x\" value=\"yes\"/></bsdf>\n</scene>",
                 "<string>:4:", NULL);
}

static void test_error_unknown_ref(void **state)
{
    (void)state;
    expect_error(HEAD "<shape type=\"cube\">\n<ref id=\"Marble\"/>\n</shape>\n</scene>",
                 "<string>:5:", "<ref id=\"Marble\">", "no object with id 'Marble'", NULL);
    /* A reference to an object of the wrong kind. */
    expect_error(HEAD "<shape type=\"cube\" id=\"box\"/>\n<shape type=\"cube\">\n<ref id=\"box\"/>\n"
                 "</shape>\n</scene>", "<string>:6:", "'box' (line 4) is not a bsdf", NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\" id=\"a\"/>\n<bsdf type=\"diffuse\" id=\"a\"/>\n</scene>",
                 "<string>:5:", "the id 'a' is used twice", NULL);
}

static void test_error_missing_file(void **state)
{
    (void)state;
    expect_error(HEAD "<shape type=\"ply\">\n<string name=\"filename\" value=\"nowhere.ply\"/>\n"
                 "</shape>\n</scene>", "<string>:4:", "<shape type=\"ply\">",
                 "cannot open", "nowhere.ply", NULL);
    expect_error(HEAD "<bsdf type=\"diffuse\"><texture name=\"reflectance\" type=\"bitmap\">\n"
                 "<string name=\"filename\" value=\"missing.jpg\"/></texture></bsdf>\n</scene>",
                 "<string>:4:", "<texture name=\"reflectance\" type=\"bitmap\">", "missing.jpg",
                 NULL);
    expect_error(HEAD "<emitter type=\"envmap\"><string name=\"filename\" value=\"sky.exr\"/></emitter>\n"
                 "</scene>", "<string>:4:", "sky.exr", "cannot open", NULL);
}

static void test_error_syntax_and_parameters(void **state)
{
    (void)state;
    expect_error("<scene version=\"3.0.0\">\n<shape type=\"cube\">\n</scene>", "<string>:3:",
                 "XML syntax error", NULL);
    expect_error(HEAD "<shape type=\"$shape\"/>\n</scene>", "<string>:4:",
                 "undefined parameter '$shape'", NULL);
    expect_error("<scene version=\"3.0.0\">\n<shape type=\"cube\"/>\n</scene>", "<string>:1:",
                 "the scene has no <sensor>", NULL);
    expect_error(HEAD "<bsdf type=\"roughconductor\"><string name=\"distribution\" value=\"phong\"/>"
                 "</bsdf>\n</scene>", "<string>:4:", "unknown distribution 'phong'", NULL);
    expect_error(HEAD "<shape type=\"cube\"><emitter type=\"area\"/></shape>\n</scene>",
                 "<string>:4:", "missing parameter 'radiance'", NULL);
    expect_error(HEAD "<shape type=\"cube\"><bsdf type=\"diffuse\"/><bsdf type=\"diffuse\"/></shape>\n"
                 "</scene>", "<string>:4:", "a shape takes one material", NULL);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_cornell_box),
    cmocka_unit_test(test_veach_ajar),
    cmocka_unit_test(test_veach_bidir),
    cmocka_unit_test(test_statue),
    cmocka_unit_test(test_defaults_refs_and_transforms),
    cmocka_unit_test(test_ply_ascii_and_obj),
    cmocka_unit_test(test_error_unknown_element),
    cmocka_unit_test(test_error_missing_attribute),
    cmocka_unit_test(test_error_bad_number),
    cmocka_unit_test(test_error_unknown_ref),
    cmocka_unit_test(test_error_missing_file),
    cmocka_unit_test(test_error_syntax_and_parameters),
)
