/*
 * selection.c - the learned guiding probability of selection.h.
 */
#include "selection.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Six normal bins (the dominant axis and its sign): the two sides of a wall see different
 * light. */
#define NORMAL_BINS 6

int selection_init(selection_grid *g, vec3 lo, vec3 hi, float initial)
{
    memset(g, 0, sizeof *g);
    g->cells = (size_t)SELECTION_RES * SELECTION_RES * SELECTION_RES * NORMAL_BINS;
    g->theta = malloc(3 * g->cells * sizeof *g->theta);
    g->moment_mix = calloc(3 * g->cells, sizeof *g->moment_mix);
    if (!g->theta || !g->moment_mix) {
        free(g->theta);
        free(g->moment_mix);
        return 0;
    }
    g->moment_bsdf = g->moment_mix + g->cells;
    g->count = g->moment_bsdf + g->cells;
    g->m = g->theta + g->cells;
    g->v = g->m + g->cells;
    float t0 = logf(initial / (1.0f - initial));
    for (size_t i = 0; i < g->cells; ++i) {
        g->theta[i] = t0;
        g->m[i] = g->v[i] = 0.0f;
    }
    g->lo = lo;
    vec3 d = v3_sub(hi, lo);
    g->scale = v3(SELECTION_RES / fmaxf(d.x, 1e-6f), SELECTION_RES / fmaxf(d.y, 1e-6f),
                  SELECTION_RES / fmaxf(d.z, 1e-6f));
    g->lr = 0.1f;
    g->min_prob = 0.05f;
    g->max_prob = 0.8f;
    g->off_below = 0.1f;
    g->cost = 1.0f;
    return 1;
}

void selection_free(selection_grid *g)
{
    free(g->theta);
    free(g->moment_mix);
    memset(g, 0, sizeof *g);
}

static int axis_cell(float x)
{
    int i = (int)x; /* x >= 0 after the clamp below; NaN gives 0 */
    return x > 0.0f ? (i < SELECTION_RES ? i : SELECTION_RES - 1) : 0;
}

size_t selection_cell(const selection_grid *g, vec3 p, vec3 n)
{
    int x = axis_cell((p.x - g->lo.x) * g->scale.x);
    int y = axis_cell((p.y - g->lo.y) * g->scale.y);
    int z = axis_cell((p.z - g->lo.z) * g->scale.z);
    float ax = fabsf(n.x), ay = fabsf(n.y), az = fabsf(n.z);
    int bin = ax >= ay && ax >= az ? (n.x < 0.0f) : ay >= az ? 2 + (n.y < 0.0f) : 4 + (n.z < 0.0f);
    return (((size_t)z * SELECTION_RES + (size_t)y) * SELECTION_RES + (size_t)x) * NORMAL_BINS +
           (size_t)bin;
}

float selection_prob(const selection_grid *g, size_t cell)
{
    float a = 1.0f / (1.0f + expf(-g->theta[cell]));
    a = fminf(fmaxf(a, g->min_prob), g->max_prob);
    return g->frozen && a < g->off_below ? 0.0f : a;
}

void selection_step(selection_grid *g, const selection_sample *s, size_t n, double *work)
{
    double *grad = work, *wsum = work + g->cells;
    memset(work, 0, 2 * g->cells * sizeof *work);
    for (size_t i = 0; i < n; ++i) {
        const selection_sample *x = &s[i];
        float p_mix = x->alpha * x->p_flow + (1.0f - x->alpha) * x->p_bsdf;
        if (!(p_mix > 0.0f) || !(x->weight > 0.0f) || x->cell >= g->cells)
            continue;
        grad[x->cell] -= (double)x->weight * (double)(x->p_flow - x->p_bsdf) / (double)p_mix;
        wsum[x->cell] += x->weight;
    }
    const float b1 = 0.9f, b2 = 0.999f;
    g->steps++;
    float c1 = 1.0f - powf(b1, (float)g->steps), c2 = 1.0f - powf(b2, (float)g->steps);
    for (size_t c = 0; c < g->cells; ++c) {
        if (wsum[c] <= 0.0)
            continue;
        float a = 1.0f / (1.0f + expf(-g->theta[c]));
        float d = (float)(grad[c] / wsum[c]) * a * (1.0f - a); /* chain rule through sigmoid */
        g->m[c] = b1 * g->m[c] + (1.0f - b1) * d;
        g->v[c] = b2 * g->v[c] + (1.0f - b2) * d * d;
        g->theta[c] -= g->lr * (g->m[c] / c1) / (sqrtf(g->v[c] / c2) + 1e-8f);
        /* Keep the logit where the clamp still lets it come back. */
        g->theta[c] = fminf(fmaxf(g->theta[c], -4.0f), 4.0f);
    }
}

void selection_observe(selection_grid *g, const selection_sample *s, size_t n)
{
    for (size_t c = 0; c < g->cells; ++c) {
        g->moment_mix[c] *= 0.5;
        g->moment_bsdf[c] *= 0.5;
        g->count[c] *= 0.5;
    }
    for (size_t i = 0; i < n; ++i) {
        const selection_sample *x = &s[i];
        if (x->cell >= g->cells || !(x->weight > 0.0f))
            continue;
        double w2 = (double)x->weight * (double)x->weight;
        double p_mix = (double)x->alpha * x->p_flow + (1.0 - (double)x->alpha) * x->p_bsdf;
        g->moment_mix[x->cell] += w2;
        /* Where BSDF sampling cannot reach a direction that carries light, it cannot do
         * without the flow: an infinite moment keeps the cell on. */
        g->moment_bsdf[x->cell] += x->p_bsdf > 0.0f ? w2 * p_mix / x->p_bsdf : INFINITY;
        g->count[x->cell] += 1.0;
    }
}

void selection_freeze(selection_grid *g)
{
    for (size_t c = 0; c < g->cells; ++c)
        if (g->count[c] >= 16.0 &&
            g->moment_mix[c] * (1.0 + (double)g->cost) >= g->moment_bsdf[c])
            g->theta[c] = -8.0f; /* below any clamp: off once frozen */
    g->frozen = 1;
}

double selection_off_share(const selection_grid *g)
{
    size_t visited = 0, off = 0;
    for (size_t c = 0; c < g->cells; ++c) {
        if (g->count[c] == 0.0)
            continue; /* never seen */
        visited++;
        off += selection_prob(g, c) == 0.0f;
    }
    return visited ? (double)off / (double)visited : 0.0;
}
