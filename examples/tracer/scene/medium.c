/*
 * medium.c - homogeneous and heterogeneous media (see medium.h).
 */
#include "medium.h"

#include <math.h>
#include <stdlib.h>

float phase_hg(float g, float cos_theta)
{
    float d = 1.0f + g * g - 2.0f * g * cos_theta;
    return (1.0f - g * g) / (4.0f * PI_F * d * sqrtf(d));
}

vec3 phase_hg_sample(float g, vec3 d, float u0, float u1, float *pdf)
{
    float c; /* cosine to d: inverse CDF of HG (Pharr et al., PBRT 3rd ed. 15.2.3) */
    if (fabsf(g) < 1e-3f) {
        c = 1.0f - 2.0f * u0;
    } else {
        float s = (1.0f - g * g) / (1.0f - g + 2.0f * g * u0);
        c = (1.0f + g * g - s * s) / (2.0f * g);
    }
    c = clampf(c, -1.0f, 1.0f);
    float sn = sqrtf(fmaxf(0.0f, 1.0f - c * c)), phi = 2.0f * PI_F * u1;
    frame f = frame_from_normal(d);
    vec3 w = frame_to_world(&f, v3(sn * cosf(phi), sn * sinf(phi), c));
    *pdf = phase_hg(g, c);
    return w;
}

static float channel_transmittance(float sigma, float t)
{
    return sigma > 0.0f ? expf(-sigma * t) : 1.0f; /* 0 x inf would be NaN */
}

rgb medium_transmittance(const medium *m, float t)
{
    return rgb_make(channel_transmittance(m->sigma_t.r, t),
                    channel_transmittance(m->sigma_t.g, t),
                    channel_transmittance(m->sigma_t.b, t));
}

int medium_sample_distance(const medium *m, rgb beta, float tmax, float u_channel, float u,
                           float *t, rgb *weight)
{
    const float sig[3] = {m->sigma_t.r, m->sigma_t.g, m->sigma_t.b};
    float pc[3] = {fmaxf(beta.r, 0.0f), fmaxf(beta.g, 0.0f), fmaxf(beta.b, 0.0f)};
    float sum = pc[0] + pc[1] + pc[2];
    if (!(sum > 0.0f) || !isfinite(sum)) {
        pc[0] = pc[1] = pc[2] = 1.0f;
        sum = 3.0f;
    }
    for (int c = 0; c < 3; ++c)
        pc[c] /= sum;
    int c = u_channel < pc[0] ? 0 : u_channel < pc[0] + pc[1] ? 1 : 2;
    if (pc[c] == 0.0f) /* u_channel at a boundary of rounding: any channel that can be drawn */
        c = pc[2] > 0.0f ? 2 : pc[1] > 0.0f ? 1 : 0;
    float dist = sig[c] > 0.0f ? -logf(1.0f - u) / sig[c] : INFINITY;
    if (dist < tmax) {
        rgb tr = medium_transmittance(m, dist);
        float p = pc[0] * sig[0] * tr.r + pc[1] * sig[1] * tr.g + pc[2] * sig[2] * tr.b;
        *t = dist;
        *weight = rgb_scale(rgb_mul(rgb_mul(m->sigma_t, m->albedo), tr), 1.0f / p);
        return 1;
    }
    rgb tr = medium_transmittance(m, tmax);
    float p = pc[0] * tr.r + pc[1] * tr.g + pc[2] * tr.b;
    *t = tmax;
    *weight = p > 0.0f ? rgb_scale(tr, 1.0f / p) : rgb_gray(0.0f);
    return 0;
}

/* ---- Heterogeneous media ------------------------------------------------------------------- */

void medium_free(medium *m)
{
    if (m->density)
        volume_grid_free(&m->density->grid);
    if (m->albedo_grid)
        volume_grid_free(&m->albedo_grid->grid);
    free(m->density);
    free(m->albedo_grid);
    m->density = m->albedo_grid = NULL;
}

static vec3 grid_point(const placed_grid *pg, vec3 p)
{
    const float(*a)[4] = pg->to_local;
    return v3(a[0][0] * p.x + a[0][1] * p.y + a[0][2] * p.z + a[0][3],
              a[1][0] * p.x + a[1][1] * p.y + a[1][2] * p.z + a[1][3],
              a[2][0] * p.x + a[2][1] * p.y + a[2][2] * p.z + a[2][3]);
}

static vec3 grid_vector(const placed_grid *pg, vec3 v)
{
    const float(*a)[4] = pg->to_local;
    return v3(a[0][0] * v.x + a[0][1] * v.y + a[0][2] * v.z,
              a[1][0] * v.x + a[1][1] * v.y + a[1][2] * v.z,
              a[2][0] * v.x + a[2][1] * v.y + a[2][2] * v.z);
}

/* The part [*t0, *t1] of the segment [0, tmax] of o + t d inside the density's cube (an
 * affine map keeps t). Returns 0 when the segment misses it. */
static int clip_to_grid(const placed_grid *pg, vec3 o, vec3 d, float tmax, float *t0, float *t1)
{
    const vec3 lo = grid_point(pg, o), ld = grid_vector(pg, d);
    const float oc[3] = {lo.x, lo.y, lo.z}, dc[3] = {ld.x, ld.y, ld.z};
    float a = 0.0f, b = tmax;
    for (int k = 0; k < 3; ++k) {
        if (dc[k] == 0.0f) {
            if (!(oc[k] >= 0.0f && oc[k] <= 1.0f))
                return 0;
            continue;
        }
        float inv = 1.0f / dc[k], ta = -oc[k] * inv, tb = (1.0f - oc[k]) * inv;
        if (ta > tb) {
            float x = ta;
            ta = tb;
            tb = x;
        }
        a = fmaxf(a, ta);
        b = fminf(b, tb);
    }
    *t0 = a;
    *t1 = b;
    return a < b;
}

/* The extinction at a world point: scale x the density, never above the majorant (trilinear
 * rounding may pass the largest cell by an ulp). */
static float extinction_at(const medium *m, vec3 p)
{
    float s = m->scale * volume_grid_eval1(&m->density->grid, grid_point(m->density, p));
    return fminf(s, m->majorant);
}

static rgb albedo_at(const medium *m, vec3 p)
{
    if (!m->albedo_grid)
        return m->albedo;
    return volume_grid_eval_rgb(&m->albedo_grid->grid, grid_point(m->albedo_grid, p));
}

int medium_sample_flight(const medium *m, rgb beta, vec3 o, vec3 d, float tmax, rng *r,
                         float *t, rgb *weight)
{
    if (!m->density) {
        float u_channel = rng_next(r), u = rng_next(r);
        return medium_sample_distance(m, beta, tmax, u_channel, u, t, weight);
    }
    *t = tmax;
    *weight = rgb_gray(1.0f);
    float t0, t1;
    if (!(m->majorant > 0.0f) || !clip_to_grid(m->density, o, d, tmax, &t0, &t1))
        return 0;
    /* Delta tracking: tentative collisions at the majorant's rate, each real with
     * probability sigma_t / majorant; a real one scatters (the albedo weighs it, so absorption
     * needs no second number) and the path passes when none is real. */
    float x = t0;
    for (int i = 0; i < MEDIUM_MAX_COLLISIONS; ++i) {
        x -= logf(1.0f - rng_next(r)) / m->majorant;
        if (!(x < t1))
            return 0;
        vec3 p = v3_add(o, v3_scale(d, x));
        if (rng_next(r) * m->majorant < extinction_at(m, p)) {
            *t = x;
            *weight = albedo_at(m, p);
            return 1;
        }
    }
    *weight = rgb_gray(0.0f);
    return 0;
}

rgb medium_segment_transmittance(const medium *m, vec3 o, vec3 d, float len, rng *r)
{
    if (!m->density)
        return medium_transmittance(m, len);
    float t0, t1;
    if (!(m->majorant > 0.0f) || !clip_to_grid(m->density, o, d, len, &t0, &t1))
        return rgb_gray(1.0f);
    /* Ratio tracking: the product of the null-collision probabilities 1 - sigma_t / majorant
     * over tentative collisions at the majorant's rate. */
    float tr = 1.0f, x = t0;
    for (int i = 0; i < MEDIUM_MAX_COLLISIONS; ++i) {
        x -= logf(1.0f - rng_next(r)) / m->majorant;
        if (!(x < t1))
            return rgb_gray(tr);
        tr *= 1.0f - extinction_at(m, v3_add(o, v3_scale(d, x))) / m->majorant;
        if (tr < 0.1f) { /* roulette, so that thick media end early: survive with tr / 0.1 */
            if (!(rng_next(r) < 10.0f * tr))
                return rgb_gray(0.0f);
            tr = 0.1f;
        }
    }
    return rgb_gray(0.0f);
}
