/*
 * medium.c - homogeneous media (see medium.h).
 */
#include "medium.h"

#include <math.h>

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
