/*
 * fuzz_volume_grid.c - libFuzzer target for the example tracer's .vol reader
 * (scene/volume_grid.c, through its in-memory entry point volume_grid_parse) and the
 * heterogeneous medium's tracking on what it accepts.
 *
 * Invariants: no crash, leak or sanitizer report; a refused grid comes with a message that
 * names the file and leaves the grid empty; an accepted one
 *   - holds only finite values within the bounds asked for, its max among them;
 *   - answers lookups anywhere (outside the cube, NaN coordinates) within [min, max];
 *   - gives delta and ratio tracking through it a weight and a transmittance in [0, 1].
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_check.h"
#include "medium.h"
#include "rng.h"
#include "volume_grid.h"


int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* The size picks the bounds: an odd count of values is read as an albedo (in [0, 1]),
     * an even one as a density (>= 0). */
    const int albedo = (size >> 2) & 1;
    const float lo = 0.0f, hi = albedo ? 1.0f : 1e30f;
    volume_grid g;
    tr_error err;
    memset(&err, 0, sizeof err);
    if (!volume_grid_parse(data, size, "fuzz.vol", albedo ? "albedo" : "density", lo, hi, &g,
                           &err)) {
        CHECK(!strncmp(err.msg, "fuzz.vol: ", 10), "message '%s'", err.msg);
        CHECK(g.data == NULL && g.nx == 0, "a refused grid is not empty");
        return 0;
    }
    const size_t n = (size_t)g.nx * (size_t)g.ny * (size_t)g.nz * (size_t)g.channels;
    float mn = INFINITY, mx = -INFINITY;
    for (size_t i = 0; i < n; ++i) {
        CHECK(isfinite(g.data[i]) && g.data[i] >= lo && g.data[i] <= hi, "value %zu: %g", i,
              (double)g.data[i]);
        mn = fminf(mn, g.data[i]);
        mx = fmaxf(mx, g.data[i]);
    }
    CHECK(mx == g.max, "max %g, largest value %g", (double)g.max, (double)mx);
    rng r = rng_seed(1, RNG_TEST, 0, (uint64_t)size);
    const vec3 probes[4] = {v3(0.5f, 0.5f, 0.5f), v3(-1.0f, 2.0f, 0.3f),
                            v3(NAN, 0.1f, INFINITY), v3(0.999f, 0.001f, 0.75f)};
    for (int nearest = 0; nearest < 2; ++nearest) {
        g.nearest = nearest;
        for (int k = 0; k < 4; ++k) {
            vec3 u = k == 0 ? v3(rng_next(&r), rng_next(&r), rng_next(&r)) : probes[k];
            float v = volume_grid_eval1(&g, u);
            rgb c = volume_grid_eval_rgb(&g, u);
            /* Trilinear weights sum to 1 in float: allow rounding of a few ulps of max. */
            const float slack = 1e-6f * fmaxf(fabsf(mx), 1e-30f);
            CHECK(v >= mn - slack && v <= mx + slack, "lookup %g outside [%g, %g]", (double)v,
                  (double)mn, (double)mx);
            CHECK(rgb_is_finite(c), "rgb lookup not finite");
        }
    }
    g.nearest = 0;
    if (!albedo && g.channels == 1 && mx < 1e4f) { /* bounded work: majorant x length < 1e4 */
        placed_grid pg = {.grid = g};
        pg.to_local[0][0] = pg.to_local[1][1] = pg.to_local[2][2] = 1.0f;
        medium m = {.albedo = rgb_gray(0.5f), .density = &pg, .scale = 1.0f, .majorant = mx};
        for (int k = 0; k < 4; ++k) {
            vec3 o = v3(-0.5f, rng_next(&r), rng_next(&r));
            vec3 d = v3_normalize(v3(1.0f, rng_next(&r) - 0.5f, rng_next(&r) - 0.5f));
            rgb tr = medium_segment_transmittance(&m, o, d, 3.0f, &r);
            CHECK(tr.r >= 0.0f && tr.r <= 1.0f, "transmittance %g", (double)tr.r);
            float t;
            rgb w;
            int scattered = medium_sample_flight(&m, rgb_gray(1.0f), o, d, 3.0f, &r, &t, &w);
            CHECK(t >= 0.0f && t <= 3.0f && w.r >= 0.0f && w.r <= 1.0f,
                  "flight: %d at %g, weight %g", scattered, (double)t, (double)w.r);
        }
    }
    volume_grid_free(&g);
    return 0;
}
