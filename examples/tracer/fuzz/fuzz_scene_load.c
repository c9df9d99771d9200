/*
 * fuzz_scene_load.c - libFuzzer target for the example tracer's scene loader
 * (examples/tracer/scene_load.c, through its in-memory entry point scene_load_string): XML
 * parsing, <default> substitution, typed properties, transforms, materials, textures, meshes
 * and the Embree scene. Relative file names resolve against the Cornell box's directory
 * (NF_FUZZ_SCENE_DIR), so its small meshes load and a valid scene loads completely.
 *
 * Invariants: no crash, leak or sanitizer report; a refused scene comes with a message; a
 * loaded one
 *   - has a film size that scene_set_resolution accepted;
 *   - lies within the world-space range (SCENE_WORLD_LIMIT: camera origin, every vertex);
 *   - gives finite camera rays that Embree can take (scene_ray_valid) through the film's
 *     corners and centre, and they intersect or miss without trouble;
 *   - traces a few whole paths (next-event estimation and scattering, depth capped so that a
 *     closed box of white mirrors cannot loop for long) without forming a ray Embree cannot
 *     take (path_stats.invalid_rays stays 0).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_check.h"
#include "integrator.h"
#include "rng.h"
#include "scene.h"

#ifndef NF_FUZZ_SCENE_DIR
#define NF_FUZZ_SCENE_DIR "."
#endif


int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* The loader takes a NUL-terminated string; an embedded NUL just ends it early. */
    char *xml = (char *)malloc(size + 1);
    if (!xml)
        return 0;
    memcpy(xml, data, size);
    xml[size] = '\0';
    scene s;
    tr_error err;
    memset(&err, 0, sizeof err);
    if (scene_load_string(xml, NF_FUZZ_SCENE_DIR, &s, &err)) {
        CHECK(s.width > 0 && s.height > 0, "film %d x %d", s.width, s.height);
        const vec3 o = s.cam.origin;
        CHECK(v3_is_finite(o) && v3_max_abs(o) <= SCENE_WORLD_LIMIT,
              "camera origin (%g, %g, %g) outside the world-space range", o.x, o.y, o.z);
        for (int i = 0; i < s.nshapes; ++i)
            for (uint32_t v = 0; v < s.shapes[i].m.nverts; ++v) {
                const vec3 p = s.shapes[i].m.p[v];
                CHECK(v3_is_finite(p) && v3_max_abs(p) <= SCENE_WORLD_LIMIT,
                      "shape %d vertex %u at (%g, %g, %g) outside the world-space range", i,
                      (unsigned)v, p.x, p.y, p.z);
            }
        /* A few camera rays: the corners and the centre of the film. */
        const float px[5] = {0.0f, (float)s.width, 0.0f, (float)s.width, 0.5f * (float)s.width};
        const float py[5] = {0.0f, 0.0f, (float)s.height, (float)s.height,
                             0.5f * (float)s.height};
        for (int k = 0; k < 5; ++k) {
            ray r = camera_ray(&s, px[k], py[k]);
            CHECK(v3_is_finite(r.o) && v3_is_finite(r.d),
                  "camera ray %d: origin (%g, %g, %g), direction (%g, %g, %g)", k, r.o.x,
                  r.o.y, r.o.z, r.d.x, r.d.y, r.d.z);
            CHECK(scene_ray_valid(&r), "camera ray %d is invalid for Embree", k);
            hit h;
            if (scene_intersect(&s, &r, &h))
                CHECK(h.shape >= 0 && h.shape < s.nshapes && h.t >= 0.0f,
                      "camera ray %d: hit shape %d at t = %g", k, h.shape, h.t);
        }
        /* A few whole paths, unguided. */
        if (s.max_depth < 0 || s.max_depth > 8)
            s.max_depth = 8;
        tracer t = {.s = &s};
        trace_scratch sc = {0};
        path_stats st;
        memset(&st, 0, sizeof st);
        rng r = rng_seed(1, RNG_TEST, 0, (uint64_t)size);
        for (int k = 0; k < 4; ++k) {
            float fx = rng_next(&r) * (float)s.width;
            float fy = rng_next(&r) * (float)s.height;
            (void)trace_path(&t, &r, fx, fy, NULL, &sc, &st);
        }
        CHECK(st.paths == 4 && st.invalid_rays == 0,
              "%llu paths formed %llu rays that Embree cannot take",
              (unsigned long long)st.paths, (unsigned long long)st.invalid_rays);
        trace_scratch_free(&sc);
        scene_free(&s);
    } else {
        CHECK(err.msg[0] != '\0', "a refused scene without a message");
    }
    free(xml);
    return 0;
}
