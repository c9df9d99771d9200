/*
 * test_limits.c - the world-space range (SCENE_WORLD_LIMIT, docs/scene-format.md "Limits") and
 * the rays Embree can take (scene_ray_valid).
 *
 * A scene outside the range is refused at load time with the file, the line, the element and
 * the value, one test per class: a huge camera origin (the reproducer of the issue: the
 * Cornell box seen from 4e18, which made Debian's Embree abort on its first camera ray), a
 * huge transform, a huge vertex, and non-finite values anywhere. A scene that reaches the
 * range's edge renders, guided and unguided, without forming a single invalid ray. Should a
 * ray be invalid all the same, it never reaches Embree: the integrator drops it (and counts
 * it), scene_intersect / scene_occluded refuse it (and assert in debug builds).
 */
#include <fcntl.h>
#include <math.h>
#include <setjmp.h>
#include <signal.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "integrator.h"
#include "model_setup.h"
#include "render.h"
#include "rng.h"
#include "scene.h"
#include "scene_errors.h"
#include "test_guided.h"

/* ---- Helpers ---------------------------------------------------------------------------- */

#define RANGE "outside the world-space range: coordinates must be finite and within +-1e+09"

/* A film of 8 x 8 and a camera at the origin looking down -z, unless `camera` replaces the
 * transform's content. */
static const char *with_camera(const char *camera, const char *rest)
{
    static char xml[8192];
    snprintf(xml, sizeof xml,
             "<scene version=\"3.0.0\">\n"
             "<sensor type=\"perspective\"><float name=\"fov\" value=\"40\"/>\n"
             "<transform name=\"to_world\">%s</transform>\n"
             "<film type=\"hdrfilm\"><integer name=\"width\" value=\"8\"/>"
             "<integer name=\"height\" value=\"8\"/></film></sensor>\n"
             "%s\n</scene>\n",
             camera, rest);
    return xml;
}

#define LOOK "<lookat origin=\"0, 0, 0\" target=\"0, 0, -1\" up=\"0, 1, 0\"/>"

/* ---- Rays ------------------------------------------------------------------------------- */

static ray make_ray(float ox, float oy, float oz, float dx, float dy, float dz, float tmax)
{
    ray r;
    r.o = v3(ox, oy, oz);
    r.d = v3(dx, dy, dz);
    r.tmax = tmax;
    return r;
}

static void test_ray_valid(void **state)
{
    (void)state;
    const float big = SCENE_RAY_LIMIT, too_big = 1.9e18f, inf = INFINITY, nan = NAN;
    assert_true(scene_ray_valid(&(ray){v3(0, 0, 0), v3(0, 0, 1), INFINITY}));
    assert_true(scene_ray_valid(&(ray){v3(big, -big, big), v3(-big, big, 0), 0.0f}));
    assert_true(scene_ray_valid(&(ray){v3(1, 2, 3), v3(0, 0, 0), 5.0f})); /* Embree's rule */
    ray bad[] = {
        make_ray(too_big, 0, 0, 0, 0, 1, inf), make_ray(0, -too_big, 0, 0, 0, 1, inf),
        make_ray(0, 0, 4e18f, 0, 0, 1, inf),   make_ray(nan, 0, 0, 0, 0, 1, inf),
        make_ray(0, inf, 0, 0, 0, 1, inf),     make_ray(0, 0, 0, -inf, 0, 1, inf),
        make_ray(0, 0, 0, 0, nan, 1, inf),     make_ray(0, 0, 0, 0, 0, too_big, inf),
        make_ray(0, 0, 0, 0, 0, 1, nan),       make_ray(0, 0, 0, 0, 0, 1, -1.0f),
        make_ray(0, 0, 0, 0, 0, 1, -inf),
    };
    for (size_t i = 0; i < sizeof bad / sizeof *bad; ++i)
        if (scene_ray_valid(&bad[i]))
            fail_msg("ray %zu is accepted", i);
}

/* A rectangle 2 units in front of the camera, lit by a constant environment. */
static void load_simple(scene *s)
{
    tr_error err;
    const char *xml = with_camera(
        LOOK, "<shape type=\"rectangle\"><transform name=\"to_world\"><translate z=\"-2\"/>"
              "</transform></shape>\n<emitter type=\"constant\"/>");
    if (!scene_load_string(xml, TRACER_TEST_TMP_DIR, s, &err))
        fail_msg("%s", err.msg);
}

/* scene_intersect (query 0) or scene_occluded (query 1) on an invalid ray, in a child process
 * whose stderr goes to a file: release builds must answer (a miss, occluded) without calling
 * Embree, whose own assertion would abort; debug builds must stop at our assertion. */
static void invalid_query_in_child(const scene *s, const ray *r, int query)
{
    char log[1024];
    snprintf(log, sizeof log, "%s/limits_child.log", TRACER_TEST_TMP_DIR);
    fflush(stdout);
    fflush(stderr);
    pid_t pid = fork();
    assert_true(pid >= 0);
    if (pid == 0) {
        int fd = open(log, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (fd < 0 || dup2(fd, 2) < 0)
            _exit(2);
        hit h;
        int answer = query == 0 ? scene_intersect(s, r, &h) : scene_occluded(s, r);
        _exit(answer == (query == 0 ? 0 : 1) ? 0 : 3);
    }
    int status = 0;
    assert_int_equal(waitpid(pid, &status, 0), pid);
#ifdef NDEBUG
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0)
        fail_msg("query %d on an invalid ray: %s %d", query,
                 WIFSIGNALED(status) ? "killed by signal" : "exit status",
                 WIFSIGNALED(status) ? WTERMSIG(status) : WEXITSTATUS(status));
#else
    assert_true(WIFSIGNALED(status) && WTERMSIG(status) == SIGABRT);
    char text[4096] = "";
    FILE *f = fopen(log, "rb");
    assert_non_null(f);
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = '\0';
    if (!strstr(text, "scene_ray_valid"))
        fail_msg("query %d aborted, but not at our assertion:\n%s", query, text);
#endif
}

static void test_invalid_ray_never_reaches_embree(void **state)
{
    (void)state;
    scene s;
    load_simple(&s);
    ray good = camera_ray(&s, 4.0f, 4.0f);
    hit h;
    assert_true(scene_ray_valid(&good));
    assert_true(scene_intersect(&s, &good, &h));
    assert_float_equal(h.t, 2.0f, 1e-5f);
    good.tmax = 1.0f;
    assert_false(scene_occluded(&s, &good));
    const ray bad[] = {make_ray(328.0f, 4e18f, 245.0f, 0, 0, -1, INFINITY),
                       make_ray(0, 0, 0, 0, NAN, -1, INFINITY), make_ray(0, 0, 0, 0, 0, -1, NAN)};
    for (size_t i = 0; i < sizeof bad / sizeof *bad; ++i)
        for (int query = 0; query < 2; ++query)
            invalid_query_in_child(&s, &bad[i], query);

    /* The integrator checks the rays it forms before it asks: a camera moved out of range
     * behind the loader's back ends every path at once, counted, in any build. */
    tracer t = {.s = &s};
    trace_scratch sc = {0};
    path_stats st = {0};
    rng r = rng_seed(5, RNG_TEST, 0, 0);
    s.cam.origin = v3(328.0f, 4e18f, 245.0f);
    for (int k = 0; k < 10; ++k) {
        rgb L = trace_path(&t, &r, 4.0f, 4.0f, NULL, &sc, &st);
        assert_true(rgb_is_black(L));
    }
    assert_int_equal(st.paths, 10);
    assert_int_equal(st.invalid_rays, 10);
    assert_int_equal(st.rays, 0);
    trace_scratch_free(&sc);
    scene_free(&s);
}

/* ---- Refused: a huge camera origin ------------------------------------------------------- */

/* The reproducer: the shipped Cornell box seen from (328, 4e18, 245). */
static void test_refused_camera_origin(void **state)
{
    (void)state;
    char path[1024];
    snprintf(path, sizeof path, "%s/cornell-box/scene.xml", TRACER_SCENES_DIR);
    FILE *f = fopen(path, "rb");
    assert_non_null(f);
    static char original[1 << 16], xml[1 << 16];
    size_t n = fread(original, 1, sizeof original - 1, f);
    fclose(f);
    original[n] = '\0';
    const char *start = strstr(original, "<lookat"), *end = start ? strstr(start, "/>") : NULL;
    assert_non_null(end);
    int line = 1;
    for (const char *p = original; p < start; ++p)
        line += *p == '\n';
    const char *values[] = {"4e18", "1e17", "2e9"};
    for (int i = 0; i < 3; ++i) {
        snprintf(xml, sizeof xml, "%.*s<lookat origin=\"328, %s, 245\" target=\"328, 10, 0\" "
                 "up=\"0, 0, 1\"/>%s", (int)(start - original), original, values[i], end + 2);
        scene s;
        tr_error err;
        char where[64], shown[64], tag[128];
        snprintf(where, sizeof where, "<string>:%d: ", line);
        snprintf(tag, sizeof tag, "<lookat origin=\"328, %s, 245\"", values[i]);
        snprintf(shown, sizeof shown, "the lookat origin is at (328, %g, 245)",
                 (double)strtof(values[i], NULL));
        char dir[1024];
        snprintf(dir, sizeof dir, "%s/cornell-box", TRACER_SCENES_DIR);
        if (scene_load_string(xml, dir, &s, &err)) {
            scene_free(&s);
            fail_msg("the Cornell box seen from y = %s loads", values[i]);
        }
        if (!strstr(err.msg, where) || !strstr(err.msg, tag) || !strstr(err.msg, shown) ||
            !strstr(err.msg, RANGE))
            fail_msg("unexpected message: %s", err.msg);
    }
    /* From a file, the message starts with its name. */
    snprintf(path, sizeof path, "%s/huge_camera.xml", TRACER_TEST_TMP_DIR);
    write_text(path, with_camera("<lookat origin=\"328, 4e18, 245\" target=\"328, 10, 0\" "
                                 "up=\"0, 0, 1\"/>", ""));
    scene s;
    tr_error err;
    assert_false(scene_load(path, &s, &err));
    assert_true(strncmp(err.msg, path, strlen(path)) == 0);
    assert_non_null(strstr(err.msg, ":3: <lookat origin=\"328, 4e18, 245\""));

    /* The target too, and the origin once the whole to_world is applied. */
    expect_error(with_camera("<lookat origin=\"0, 0, 0\" target=\"0, 0, -2e9\"/>", ""),
                 "<string>:3: <lookat", "the lookat target is at (0, 0, -2e+09), " RANGE, NULL);
    expect_error(with_camera(LOOK "<translate y=\"4e18\"/>", ""), "<string>:3: <translate",
                 "the transform maps the origin to (0, 4e+18, 0), " RANGE, NULL);
    /* A projective to_world divides the origin by w = 1e-12. */
    expect_error(with_camera("<matrix value=\"1 0 0 5 0 1 0 0 0 0 1 0 0 0 0 1e-12\"/>", ""),
                 "<string>:2: <sensor type=\"perspective\">",
                 "the camera origin is at (5e+12, 0, 0), " RANGE, NULL);
    /* Not out of range, but as degenerate: every camera ray would have the same direction. */
    expect_error(with_camera("<scale value=\"0\"/>", ""), "<string>:2: <sensor",
                 "to_world is not invertible", NULL);
}

/* ---- Refused: a huge transform ------------------------------------------------------------ */

static void test_refused_transform(void **state)
{
    (void)state;
    /* Each step is checked as it is applied; the message names the step. */
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">\n"
                                   "<scale value=\"2\"/><scale value=\"1e10\"/></transform></shape>"),
                 "<string>:6: <scale value=\"1e10\">",
                 "the transform maps the unit x vector to (2e+10, 0, 0), " RANGE, NULL);
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">\n"
                                   "<translate x=\"1\" z=\"-1e12\"/></transform></shape>"),
                 "<string>:6: <translate", "the transform maps the origin to (1, 0, -1e+12)",
                 NULL);
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">\n"
                                   "<matrix value=\"1 0 0 0 0 1 0 0 0 0 1 0 1e20 0 0 1\"/>"
                                   "</transform></shape>"),
                 "<string>:6: <matrix", "the transform's projective row is (1e+20, 0, 0, 1)",
                 NULL);
    /* Steps that stay in range one by one can leave it together. */
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">\n"
                                   "<scale value=\"1e5\"/>\n<scale value=\"1e5\"/>"
                                   "</transform></shape>"),
                 "<string>:7: <scale value=\"1e5\">",
                 "the transform maps the unit x vector to (1e+10, 0, 0)", NULL);
    /* Every transform: the environment's and a texture's. */
    expect_error(with_camera(LOOK, "<emitter type=\"envmap\"><string name=\"filename\" "
                                   "value=\"sky.exr\"/><transform name=\"to_world\">\n"
                                   "<rotate y=\"1\" angle=\"30\"/><scale y=\"-3e9\"/>"
                                   "</transform></emitter>"),
                 "<string>:6: <scale y=\"-3e9\">", "the transform maps the unit y vector to",
                 RANGE, NULL);
    expect_error(with_camera(LOOK, "<bsdf type=\"diffuse\"><texture name=\"reflectance\" "
                                   "type=\"checkerboard\"><transform name=\"to_uv\">\n"
                                   "<scale value=\"1e12\"/></transform></texture></bsdf>"),
                 "<string>:6: <scale value=\"1e12\">", RANGE, NULL);
    /* Within the range, a large transform is fine (see test_edge_of_the_range). */
    scene s;
    tr_error err;
    if (!scene_load_string(with_camera(LOOK, "<shape type=\"rectangle\"><transform "
                                             "name=\"to_world\"><scale value=\"1e9\"/>"
                                             "<translate z=\"-1e9\"/></transform></shape>"),
                           TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    assert_float_equal(s.bounds_min.x, -1e9f, 0.0f);
    scene_free(&s);
}

/* ---- Refused: a huge vertex ---------------------------------------------------------------- */

static void test_refused_vertex(void **state)
{
    (void)state;
    char obj[1024], ply[1024], rest[2048];
    snprintf(obj, sizeof obj, "%s/limits_huge.obj", TRACER_TEST_TMP_DIR);
    write_text(obj, "v 0 0 0\nv 1 0 0\nv 0 2e9 0\nf 1 2 3\n");
    snprintf(rest, sizeof rest, "<shape type=\"obj\">\n<string name=\"filename\" value=\"%s\"/>"
             "</shape>", obj);
    expect_error(with_camera(LOOK, rest), "<string>:5: <shape type=\"obj\">",
                 "vertex 2 of 3 (after to_world) is at (0, 2e+09, 0), " RANGE, NULL);
    /* In range in the file, out of range after to_world (whose entries are in range). */
    write_text(obj, "v 0 0 0\nv 1 0 0\nv 0 2 0\nf 1 2 3\n");
    snprintf(rest, sizeof rest, "<shape type=\"obj\">\n<string name=\"filename\" value=\"%s\"/>"
             "<transform name=\"to_world\"><scale value=\"6e8\"/><translate y=\"6e8\"/>"
             "</transform></shape>", obj);
    expect_error(with_camera(LOOK, rest), "<string>:5: <shape type=\"obj\">",
                 "vertex 2 of 3 (after to_world) is at (0, 1.8e+09, 0)", NULL);
    /* An ASCII PLY. */
    snprintf(ply, sizeof ply, "%s/limits_huge.ply", TRACER_TEST_TMP_DIR);
    write_text(ply, "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                    "property float y\nproperty float z\nelement face 1\n"
                    "property list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n-5e15 0 0\n0 1 0\n3 0 1 2\n");
    snprintf(rest, sizeof rest, "<shape type=\"ply\">\n<string name=\"filename\" value=\"%s\"/>"
             "</shape>", ply);
    expect_error(with_camera(LOOK, rest), "<string>:5: <shape type=\"ply\">",
                 "vertex 1 of 3 (after to_world) is at (-5e+15, 0, 0)", NULL);
    /* Built-in shapes: a sphere whose radius reaches past the range, an emissive cube (a
     * light) moved to its edge and a little beyond. */
    expect_error(with_camera(LOOK, "<shape type=\"sphere\"><float name=\"radius\" value=\"2e9\"/>"
                                   "</shape>"),
                 "<string>:5: <shape type=\"sphere\">", "(after to_world) is at", RANGE, NULL);
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">"
                                   "<scale value=\"100\"/><translate x=\"1e9\"/></transform>"
                                   "<emitter type=\"area\"><rgb name=\"radiance\" value=\"1\"/>"
                                   "</emitter></shape>"),
                 "<string>:5: <shape type=\"cube\">",
                 "vertex 0 of 24 (after to_world) is at (1000000128, -100, 100), " RANGE, NULL);
}

/* ---- Refused: non-finite values anywhere -------------------------------------------------- */

static void test_refused_non_finite(void **state)
{
    (void)state;
    /* In the XML: not numbers at all, or numbers that would not fit in a float. */
    expect_error(with_camera("<lookat origin=\"nan, 0, 0\" target=\"0, 0, -1\"/>", ""),
                 "<string>:3: <lookat", "'nan, 0, 0' is not a number", NULL);
    expect_error(with_camera("<lookat origin=\"0, 0, 0\" target=\"0, inf, -1\"/>", ""),
                 "<string>:3: <lookat", "'inf, -1' is not a number", NULL);
    expect_error(with_camera("<lookat origin=\"0, 1e39, 0\" target=\"0, 0, -1\"/>", ""),
                 "<string>:3: <lookat", "'1e39' is out of range (in origin=\"0, 1e39, 0\")",
                 NULL);
    expect_error(with_camera(LOOK, "<shape type=\"sphere\"><float name=\"radius\" value=\"-1e300\"/>"
                                   "</shape>"),
                 "<string>:5: <float name=\"radius\"", "'-1e300' is out of range", NULL);
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><emitter type=\"area\"><rgb "
                                   "name=\"radiance\" value=\"1, 1e40, 1\"/></emitter></shape>"),
                 "<string>:5: <rgb name=\"radiance\"", "'1e40' is out of range", NULL);
    expect_error(with_camera(LOOK, "<shape type=\"cube\"><transform name=\"to_world\">"
                                   "<rotate x=\"1\" angle=\"1e309\"/></transform></shape>"),
                 "<string>:5: <rotate", "is not a number", NULL);

    /* In mesh files: NaN and infinite positions (OBJ text, binary PLY). */
    char obj[1024], ply[1024], rest[2048];
    snprintf(obj, sizeof obj, "%s/limits_nan.obj", TRACER_TEST_TMP_DIR);
    const char *objs[] = {"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n",
                          "v 0 0 0\nv 1 0 0\nv 0 1 -inf\nf 1 2 3\n",
                          "v 0 0 0\nv 1 0 0\nv 0 1 1e39\nf 1 2 3\n"};
    /* 0 * NaN and 0 * inf are NaN: one such coordinate spreads through the transform. */
    const char *shown[] = {"vertex 1 of 3 (after to_world) is at (",
                           "vertex 2 of 3 (after to_world) is at (",
                           "vertex 2 of 3 (after to_world) is at ("};
    for (int i = 0; i < 3; ++i) {
        write_text(obj, objs[i]);
        snprintf(rest, sizeof rest, "<shape type=\"obj\">\n<string name=\"filename\" "
                 "value=\"%s\"/></shape>", obj);
        expect_error(with_camera(LOOK, rest), "<string>:5: <shape type=\"obj\">", shown[i],
                     RANGE, NULL);
    }
    snprintf(ply, sizeof ply, "%s/limits_nan.ply", TRACER_TEST_TMP_DIR);
    const char *header = "ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
                         "property float x\nproperty float y\nproperty float z\n"
                         "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
    unsigned char data[512];
    size_t len = strlen(header);
    memcpy(data, header, len);
    const float p[9] = {0, 0, 0, 1, 0, 0, 0, 1, NAN};
    for (int i = 0; i < 9; ++i) { /* little-endian floats */
        uint32_t u;
        memcpy(&u, &p[i], 4);
        for (int b = 0; b < 4; ++b)
            data[len++] = (unsigned char)(u >> (8 * b));
    }
    data[len++] = 3;
    for (uint32_t i = 0; i < 3; ++i)
        for (int b = 0; b < 4; ++b)
            data[len++] = (unsigned char)(i >> (8 * b));
    write_file(ply, data, len);
    snprintf(rest, sizeof rest, "<shape type=\"ply\">\n<string name=\"filename\" value=\"%s\"/>"
             "</shape>", ply);
    expect_error(with_camera(LOOK, rest), "<string>:5: <shape type=\"ply\">",
                 "vertex 2 of 3 (after to_world) is at (", RANGE, NULL);
}

/* ---- The edge of the range renders --------------------------------------------------------- */

/* Geometry out to +-1e9 on every axis, the camera and a light near the edge, a glass sphere
 * (delta paths), a constant environment (shadow rays to infinity). */
static const char *const edge_xml =
    "<scene version=\"3.0.0\">\n"
    "<integrator type=\"path\"><integer name=\"max_depth\" value=\"8\"/></integrator>\n"
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"60\"/>\n"
    "  <transform name=\"to_world\"><lookat origin=\"9e8, 6e8, 1e9\" target=\"0, 0, 0\" up=\"0, 1, 0\"/></transform>\n"
    "  <film type=\"hdrfilm\"><integer name=\"width\" value=\"16\"/><integer name=\"height\" value=\"16\"/></film>\n"
    "</sensor>\n"
    "<bsdf type=\"twosided\" id=\"white\"><bsdf type=\"diffuse\"><rgb name=\"reflectance\" value=\"0.8\"/></bsdf></bsdf>\n"
    /* The floor, y = -1e9 (the range's edge), x and z over the whole range. */
    "<shape type=\"rectangle\"><transform name=\"to_world\"><rotate x=\"1\" angle=\"-90\"/>"
    "<scale value=\"1e9\"/><translate y=\"-1e9\"/></transform><ref id=\"white\"/></shape>\n"
    /* A wall at z = -1e9. */
    "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"1e9\"/>"
    "<translate z=\"-1e9\"/></transform><ref id=\"white\"/></shape>\n"
    /* A box in the far corner, a glass sphere, a rough metal sphere. */
    "<shape type=\"cube\"><transform name=\"to_world\"><scale value=\"2e8\"/>"
    "<translate value=\"-8e8, -8e8, -8e8\"/></transform><ref id=\"white\"/></shape>\n"
    "<shape type=\"sphere\"><point name=\"center\" value=\"2e8, -5e8, 0\"/>"
    "<float name=\"radius\" value=\"4e8\"/><bsdf type=\"dielectric\"/></shape>\n"
    "<shape type=\"sphere\"><point name=\"center\" value=\"-4e8, -6.5e8, 4e8\"/>"
    "<float name=\"radius\" value=\"3e8\"/><bsdf type=\"roughconductor\"/></shape>\n"
    /* A light facing down at y = 9e8. */
    "<shape type=\"rectangle\"><transform name=\"to_world\"><scale value=\"2e8\"/>"
    "<rotate x=\"1\" angle=\"90\"/><translate y=\"9e8\"/></transform>"
    "<emitter type=\"area\"><rgb name=\"radiance\" value=\"20\"/></emitter></shape>\n"
    "<emitter type=\"constant\"><rgb name=\"radiance\" value=\"0.2\"/></emitter>\n"
    "</scene>\n";

static void render_edge(int guided)
{
    scene s;
    tr_error err;
    if (!scene_load_string(edge_xml, TRACER_TEST_TMP_DIR, &s, &err))
        fail_msg("%s", err.msg);
    assert_float_equal(s.bounds_min.y, -1e9f, 0.0f);
    assert_float_equal(s.bounds_max.x, 1e9f, 0.0f);
    /* The camera sees the scene: its central ray hits something. */
    ray c = camera_ray(&s, 8.0f, 8.0f);
    hit h;
    assert_true(scene_ray_valid(&c));
    assert_true(scene_intersect(&s, &c, &h));

    tracer t = test_tracer(&s, guided, MODEL_PRIOR_COSINE, 0);
    image img;
    path_stats st;
    test_render(&t, 8, 17, &img, &st);
    assert_int_equal(st.invalid_rays, 0);
    assert_int_equal(st.nf_errors, 0);
    assert_true(st.rays > 2 * st.paths); /* paths bounce, and take light samples */
    if (guided)
        assert_true(st.guided_vertices > 0);
    double sum = 0.0;
    for (size_t i = 0; i < (size_t)img.width * (size_t)img.height * 3u; ++i) {
        assert_true(isfinite(img.data[i]));
        sum += img.data[i];
    }
    assert_true(sum > 0.0);
    image_free(&img);
    nf_model_destroy((nf_model *)t.model);
    scene_free(&s);
}

static void test_edge_of_the_range(void **state)
{
    (void)state;
    render_edge(0);
    render_edge(1);
    /* A hair beyond the edge is refused, and the message shows by how much. */
    expect_error(with_camera(LOOK, "<shape type=\"rectangle\"><transform name=\"to_world\">"
                                   "<scale value=\"1.0000001e9\"/></transform></shape>"),
                 "<string>:5: <scale", "the transform maps the unit x vector to (1000000100, 0, 0), "
                 RANGE, NULL);
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_ray_valid),
    cmocka_unit_test(test_invalid_ray_never_reaches_embree),
    cmocka_unit_test(test_refused_camera_origin),
    cmocka_unit_test(test_refused_transform),
    cmocka_unit_test(test_refused_vertex),
    cmocka_unit_test(test_refused_non_finite),
    cmocka_unit_test(test_edge_of_the_range),
)
