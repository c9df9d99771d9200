/*
 * guide_policy.c - the path policy of nisflow/policy.h: how a guided path mixes the flow with
 * the BSDF, when Russian roulette lets it go on, and which vertices ask the flow for a light
 * sample's density, and the moments of other policies a path keeps for the schedule
 * (nf_plain_moment, nf_depth_moment). The rules and their measurements are in
 * docs/integration.md and docs/equal-time.md.
 */
#include <math.h>

#include "internal.h"
#include "policy_atoms.h"

void nf_guide_policy_init(nf_guide_policy *p)
{
    if (!p)
        return;
    p->mixture_prob = 0.7f;
    p->max_boost = 10.0f;
    p->max_survival = 0.95f;
    p->light_mis_depth = 2;
    p->min_roughness = 0.3f;
}

float nf_guide_mixture_prob(const nf_guide_policy *p, float boost)
{
    if (!p || !(p->mixture_prob > 0.0f))
        return 0.0f;
    float g = p->mixture_prob;
    if (!(p->max_boost > 0.0f))
        return g;
    /* A vertex multiplies the boost by at most 1 / (1 - g): keep boost / (1 - g) within the
     * cap. */
    float most = 1.0f - boost / p->max_boost;
    if (g <= most)
        return g;
    return most >= 0.05f ? most : 0.0f; /* NaN gives 0 */
}

float nf_guide_boost(float boost, float p_bsdf, float p_mix, float g_used)
{
    if (p_bsdf == 0.0f && p_mix == 0.0f) { /* a delta lobe, chosen with probability 1 - g */
        if (g_used > 0.0f && g_used < 1.0f)
            return boost / (1.0f - g_used);
        return boost;
    }
    if (!(p_bsdf > 0.0f) || !(p_mix > 0.0f) || !isfinite(p_bsdf) || !isfinite(p_mix))
        return boost;
    return boost * (p_bsdf / p_mix);
}

float nf_guide_roulette_survival(const nf_guide_policy *p, float throughput_max, float boost)
{
    /* A policy without a valid cap (zeroed, say) plays plain path tracing's 0.95. */
    float top = p && p->max_survival > 0.0f && p->max_survival <= 1.0f ? p->max_survival : 0.95f;
    float c = throughput_max;
    if (boost > 0.0f && isfinite(boost))
        c = fmaxf(c, throughput_max / boost);
    if (!(c >= 0.0f)) /* NaN or negative */
        return 0.0f;
    return fminf(c, top);
}

int nf_guide_light_mis_uses_flow(const nf_guide_policy *p, uint32_t depth)
{
    if (!p)
        return 0;
    return p->light_mis_depth == 0 || depth <= p->light_mis_depth;
}

/* ---- The moments a path keeps of plain path tracing and of shallower guiding ----------------- */

/* R below this is taken as this: a path plain path tracing would (almost) never trace
 * weighs in its second moment as one it traces once in 10^6. */
#define NF_PLAIN_RATIO_FLOOR 1e-6f

/* The steps, on R and the sums, that both moments share. */
static float nf_moment_roulette_ratio(float ratio, const nf_guide_policy *p, float throughput_max,
                                      float boost, float q_used)
{
    float r = fmaxf(ratio, NF_PLAIN_RATIO_FLOOR);
    float q_policy = nf_guide_roulette_survival(p, throughput_max / r, boost);
    /* q_policy = 0: the policy would never have gone on (R = 0, floored when used). */
    return q_policy > 0.0f ? r * (q_policy / q_used) : 0.0f;
}

static void nf_moment_add(float ratio, float *sum, float *moment, float c)
{
    float r = fmaxf(ratio, NF_PLAIN_RATIO_FLOOR);
    /* c_k^2 / R_k + 2 c_k sum_j c_j / R_j, then the sum takes c_k / R_k. */
    *moment += c * (c / r + 2.0f * *sum);
    *sum += c / r;
}

void nf_plain_moment_start(nf_plain_moment *m)
{
    if (!m)
        return;
    m->ratio = 1.0f;
    m->sum = 0.0f;
    m->moment = 0.0f;
}

void nf_plain_moment_scatter(nf_plain_moment *m, float p_bsdf, float p_mix, float g_used)
{
    if (m)
        m->ratio = nf_guide_boost(m->ratio, p_bsdf, p_mix, g_used);
}

void nf_plain_moment_roulette(nf_plain_moment *m, const nf_guide_policy *p, float throughput_max,
                              float q_used)
{
    if (m && q_used > 0.0f && isfinite(q_used))
        m->ratio = nf_moment_roulette_ratio(m->ratio, p, throughput_max, 1.0f, q_used);
}

void nf_plain_moment_add(nf_plain_moment *m, float c)
{
    if (m && c > 0.0f && isfinite(c))
        nf_moment_add(m->ratio, &m->sum, &m->moment, c);
}

void nf_depth_moment_start(nf_depth_moment *m, uint32_t depth)
{
    if (!m)
        return;
    m->ratio = m->boost = 1.0f;
    m->sum = m->moment = 0.0f;
    m->depth = depth;
}

void nf_depth_moment_scatter(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float p_bsdf,
                             float p_mix, float g_used)
{
    for (size_t k = 0; m && k < n; ++k) {
        /* Up to D the policy guided this vertex as the path did: only its boost moves. */
        if (vertex_depth <= m[k].depth)
            m[k].boost = nf_guide_boost(m[k].boost, p_bsdf, p_mix, g_used);
        else
            m[k].ratio = nf_guide_boost(m[k].ratio, p_bsdf, p_mix, g_used);
    }
}

void nf_depth_moment_roulette(nf_depth_moment *m, size_t n, const nf_guide_policy *p,
                              uint32_t vertex_depth, float throughput_max, float q_used)
{
    if (!m || !(q_used > 0.0f) || !isfinite(q_used))
        return;
    for (size_t k = 0; k < n; ++k)
        if (vertex_depth > m[k].depth)
            m[k].ratio =
                nf_moment_roulette_ratio(m[k].ratio, p, throughput_max, m[k].boost, q_used);
}

void nf_depth_moment_add(nf_depth_moment *m, size_t n, uint32_t vertex_depth, float c,
                         float c_plain)
{
    for (size_t k = 0; m && k < n; ++k) {
        float v = vertex_depth <= m[k].depth ? c : c_plain;
        if (v > 0.0f && isfinite(v))
            nf_moment_add(m[k].ratio, &m[k].sum, &m[k].moment, v);
    }
}

/* ---- The per-path state: the boost and the moments together ---------------------------------- */

void nf_path_start(nf_path_state *ps)
{
    if (!ps)
        return;
    ps->boost = 1.0f;
    for (uint32_t k = 0; k < NF_GUIDE_DEPTHS; ++k)
        nf_depth_moment_start(&ps->moments[k], k); /* 0: plain path tracing */
}

float nf_path_mixture_prob(const nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                           uint32_t pass_depth)
{
    if (!ps || (pass_depth != 0 && depth > pass_depth))
        return 0.0f;
    return nf_guide_mixture_prob(p, ps->boost);
}

float nf_path_survival(const nf_path_state *ps, const nf_guide_policy *p, float throughput_max)
{
    return ps ? nf_guide_roulette_survival(p, throughput_max, ps->boost) : 0.0f;
}

void nf_path_survived(nf_path_state *ps, const nf_guide_policy *p, uint32_t depth,
                      float throughput_max, float q_used)
{
    if (ps)
        nf_depth_moment_roulette(ps->moments, NF_GUIDE_DEPTHS, p, depth, throughput_max, q_used);
}

void nf_path_scatter(nf_path_state *ps, uint32_t depth, float p_bsdf, float p_mix, float g_used)
{
    if (!ps)
        return;
    nf_depth_moment_scatter(ps->moments, NF_GUIDE_DEPTHS, depth, p_bsdf, p_mix, g_used);
    ps->boost = nf_guide_boost(ps->boost, p_bsdf, p_mix, g_used);
}

void nf_path_add(nf_path_state *ps, uint32_t depth, float c, float c_plain)
{
    if (ps)
        nf_depth_moment_add(ps->moments, NF_GUIDE_DEPTHS, depth, c, c_plain);
}
