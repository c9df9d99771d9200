/*
 * fuzz_scene_load.c - libFuzzer target for the example tracer's scene loader
 * (examples/tracer/scene_load.c, through its in-memory entry point scene_load_string): XML
 * parsing, <default> substitution, typed properties, transforms, materials, textures, meshes
 * and the Embree scene. Relative file names resolve against the Cornell box's directory
 * (NF_FUZZ_SCENE_DIR), so its small meshes load and a valid scene loads completely.
 *
 * Invariants: no crash, leak or sanitizer report; a refused scene comes with a message; a
 * loaded one has a camera, bounds and a film size that scene_set_resolution accepted, and
 * camera rays through the film that intersect or miss without trouble.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene.h"

#ifndef NF_FUZZ_SCENE_DIR
#define NF_FUZZ_SCENE_DIR "."
#endif

#define CHECK(cond, ...)                                                                       \
    do {                                                                                       \
        if (!(cond)) {                                                                         \
            fprintf(stderr, "fuzz check failed at %s:%d: %s\n  ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                                      \
            fprintf(stderr, "\n");                                                             \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

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
        /* A few camera rays: the corners and the centre of the film. */
        const float px[5] = {0.0f, (float)s.width, 0.0f, (float)s.width, 0.5f * (float)s.width};
        const float py[5] = {0.0f, 0.0f, (float)s.height, (float)s.height,
                             0.5f * (float)s.height};
        for (int k = 0; k < 5; ++k) {
            ray r = camera_ray(&s, px[k], py[k]);
            hit h;
            if (isfinite(r.o.x) && isfinite(r.d.x) && isfinite(r.o.y) && isfinite(r.d.y) &&
                isfinite(r.o.z) && isfinite(r.d.z))
                (void)scene_intersect(&s, &r, &h);
        }
        scene_free(&s);
    } else {
        CHECK(err.msg[0] != '\0', "a refused scene without a message");
    }
    free(xml);
    return 0;
}
