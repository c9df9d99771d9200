/*
 * vertex.c - one vertex of a path (vertex.h): the segment to it, its plan, the flow's answers
 * at a shading point, and its finish.
 *
 * Depth follows Mitsuba's max_depth: a path of k segments ends at vertex k; the camera ray
 * is segment 1. Emission found at vertex k counts if k <= max_depth, so next-event
 * estimation at vertex k needs k + 1 <= max_depth and so does scattering from it.
 *
 * The estimator at a vertex with a non-delta part and guiding on:
 *   - the scattered direction comes from the flow with probability g (--guide-prob) and
 *     from the BSDF otherwise; whichever technique produced it, the direction's density is
 *     p_mix = g p_flow + (1 - g) p_bsdf, and the throughput is multiplied by f |cos| / p_mix
 *     (a one-sample balance-heuristic combination, unbiased as long as p_mix > 0 wherever
 *     f > 0, which the BSDF part guarantees);
 *   - a delta lobe chosen by the BSDF technique (the coating of a plastic) has probability
 *     (1 - g) times its own, so its weight is divided by (1 - g);
 *   - next-event estimation weighs the light sample against p_mix, and an emitter hit by the
 *     scattered ray weighs p_mix against the light density (power heuristic);
 *   - the library's path state (nisflow/policy.h, path_state.guide) decides the rest, as in
 *     docs/integration.md's recipe: g itself, lowered so that the path's boost stays within
 *     the cap and 0 deeper than the pass guides (nf_path_mixture_prob); Russian roulette on
 *     the larger of the throughput and the throughput divided by the boost
 *     (nf_path_survival); light-sampling MIS by p_mix only at the first vertices
 *     (nf_guide_light_mis_uses_flow), by p_bsdf on both sides deeper down, where the light
 *     sample then asks the flow nothing. The path records its scatters and contributions
 *     there too (nf_path_scatter, nf_path_survived, nf_path_add): the schedule's moments.
 * Which vertices are guided: non-delta ones, not rough conductors smoother than the policy's
 * min_roughness (their lobe is sharper than the flow learns). The ablation switches of
 * the tracer struct (integrator.h: guide_depth, light_mis_bsdf) restrict that further.
 *
 * A vertex runs in three steps: vertex_plan_next traces the segment to it and draws every
 * random number the vertex needs (light sample, roulette, technique, BSDF direction), stating
 * what it asks the flow; the questions are answered; vertex_finish weighs. trace_path answers
 * at a shading point right away; trace_paths answers the questions of many paths at once.
 */
#include "vertex.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "model_setup.h"

static float power_heuristic(float a, float b)
{
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0f ? a2 / (a2 + b2) : 0.0f;
}

static void put_rgb(float out[3], rgb c)
{
    out[0] = c.r;
    out[1] = c.g;
    out[2] = c.b;
}

/* The shading setup at a hit: material, frame and orientation. Returns 0 when the surface
 * cannot scatter towards wo (the back of a one-sided material). */
static int setup_shading(const scene *s, const hit *h, const surface *sf, vec3 wo, shading *sh)
{
    const bsdf *b = &s->bsdfs[s->shapes[h->shape].bsdf];
    vec3 ng = sf->ng, ns = sf->ns;
    float side = v3_dot(wo, ng);
    if (b->twosided && side < 0.0f) {
        ng = v3_neg(ng);
        ns = v3_neg(ns);
        side = -side;
    }
    if (!bsdf_transmits(b) && side <= 0.0f)
        return 0; /* one-sided materials are black from behind, as in Mitsuba */
    /* Interpolated normals can put wo below the shading surface although it is above the
     * geometry; fall back to the geometric normal there instead of returning black. */
    if (v3_dot(wo, ns) * side <= 0.0f)
        ns = ng;
    bsdf_point_init(&sh->bp, b, sf->u, sf->v);
    sh->ng = ng;
    sh->fr = frame_from_normal(ns);
    sh->wo_l = frame_to_local(&sh->fr, wo);
    return 1;
}

/* f |cos| for a world direction, zero when the shading and the geometric normal disagree
 * about which side wi is on (light leaking through interpolated normals). */
static rgb shading_eval(const shading *sh, vec3 wi, vec3 *wi_l)
{
    *wi_l = frame_to_local(&sh->fr, wi);
    if (v3_dot(wi, sh->ng) * wi_l->z <= 0.0f)
        return rgb_gray(0.0f);
    return bsdf_eval(&sh->bp, sh->wo_l, *wi_l);
}

/* The scattering function of a vertex for a world direction: f |cos| on surfaces, the phase
 * function in a medium. */
static rgb vertex_eval(const vertex_plan *vp, vec3 wi)
{
    if (vp->volume)
        return rgb_gray(phase_hg(vp->phase_g, v3_dot(vp->d, wi)));
    vec3 wi_l;
    return shading_eval(&vp->sh, wi, &wi_l);
}

/* The density with which the vertex's own technique (BSDF or phase sampling) gives wi. */
static float vertex_pdf(const vertex_plan *vp, vec3 wi)
{
    if (vp->volume)
        return phase_hg(vp->phase_g, v3_dot(vp->d, wi));
    return bsdf_pdf(&vp->sh.bp, vp->sh.wo_l, frame_to_local(&vp->sh.fr, wi));
}

/* Whether light-sampling MIS at a vertex `depth` segments deep weighs with the mixture's
 * density, which asks the flow (the policy's light_mis_depth; light_mis_bsdf: never). Both
 * sides of one vertex ask this with the same depth, so the two weights still sum to one. */
static int light_mis_uses_flow(const tracer *t, int depth)
{
    return !t->light_mis_bsdf && nf_guide_light_mis_uses_flow(&t->policy, (uint32_t)depth);
}

/* The medium a direction wi leaving the vertex travels in: a surface that bounds media
 * switches it when wi crosses to the other side than wo's. */
static int medium_towards(const scene *s, const vertex_plan *vp, const path_state *ps, vec3 wi)
{
    if (vp->volume || !s->shapes[vp->shape].media_boundary)
        return ps->medium;
    vec3 wo = v3_neg(vp->d);
    if (v3_dot(wi, vp->ng_geom) * v3_dot(wo, vp->ng_geom) >= 0.0f)
        return ps->medium; /* reflected: the medium stays */
    return scene_medium_after(s, vp->shape, vp->ng_geom, wi, ps->medium);
}

/* nee_plan in a scene with media: the light sample's transmittance through media and null
 * surfaces (scene_transmittance), the phase function at volume vertices. */
static int nee_plan_media(const tracer *t, vertex_plan *vp, const path_state *ps,
                          const light_sample *ls, rng *r, path_stats *st)
{
    const scene *s = t->s;
    rgb f = vertex_eval(vp, ls->wi);
    if (rgb_is_black(f) || rgb_is_black(ls->radiance))
        return 0;
    ray shadow;
    scene_shadow_ray(vp->p, vp->volume ? v3(0.0f, 0.0f, 0.0f) : vp->sh.ng, ls->wi, ls->dist,
                     &shadow);
    if (!scene_ray_valid(&shadow)) { /* never within the loader's world range */
        st->invalid_rays++;
        return 0;
    }
    rgb tr = scene_transmittance(s, &shadow, medium_towards(s, vp, ps, ls->wi), r, &st->rays);
    if (rgb_is_black(tr))
        return 0;
    vp->nee_value = rgb_mul(rgb_mul(f, tr), ls->radiance);
    vp->nee_light_pdf = ls->pdf;
    vp->nee_p_bsdf = vertex_pdf(vp, ls->wi);
    vp->q.light_wi = ls->wi;
    return 1;
}

/* One light sample towards an unoccluded light, weighed later against the scattering
 * density (vertex_finish). Returns 0 when it contributes nothing. */
static int nee_plan(const tracer *t, vertex_plan *vp, const path_state *ps, rng *r,
                    path_stats *st)
{
    const scene *s = t->s;
    light_sample ls;
    float u_pick = rng_next(r), u0 = rng_next(r), u1 = rng_next(r);
    if (!light_sample_from(s, vp->p, u_pick, u0, u1, &ls))
        return 0;
    if (s->has_media)
        return nee_plan_media(t, vp, ps, &ls, r, st);
    vec3 wi_l;
    rgb f = shading_eval(&vp->sh, ls.wi, &wi_l);
    if (rgb_is_black(f) || rgb_is_black(ls.radiance))
        return 0;
    ray shadow;
    scene_shadow_ray(vp->p, vp->sh.ng, ls.wi, ls.dist, &shadow);
    if (!scene_ray_valid(&shadow)) { /* never within the loader's world range */
        st->invalid_rays++;
        return 0;
    }
    st->rays++;
    if (scene_occluded(s, &shadow))
        return 0;
    vp->nee_value = rgb_mul(f, ls.radiance);
    vp->nee_light_pdf = ls.pdf;
    vp->nee_p_bsdf = bsdf_pdf(&vp->sh.bp, vp->sh.wo_l, wi_l);
    vp->q.light_wi = ls.wi;
    return 1;
}

/* Chooses the scattering technique: the flow with probability g, the BSDF otherwise (whose
 * direction is drawn now). Returns 0 when the path ends here. */
static int scatter_plan(vertex_plan *vp, rng *r)
{
    const float g = vp->g;
    float u_sel = rng_next(r), u_lobe = rng_next(r), u0 = rng_next(r), u1 = rng_next(r);
    vp->flow_chosen = g > 0.0f && u_sel < g;
    if (vp->flow_chosen) {
        vp->q.sample = 1;
        vp->q.u[0] = u0;
        vp->q.u[1] = u1;
        return 1;
    }
    if (vp->volume) {
        vp->q.wi = phase_hg_sample(vp->phase_g, vp->d, u0, u1, &vp->p_bsdf);
        vp->q.pdf = g > 0.0f;
        return vp->p_bsdf > 0.0f;
    }
    bsdf_sample bs;
    if (!bsdf_sample_dir(&vp->sh.bp, vp->sh.wo_l, u_lobe, u0, u1, &bs))
        return 0;
    vp->q.wi = frame_to_world(&vp->sh.fr, bs.wi);
    if (bs.delta) {
        if (v3_dot(vp->q.wi, vp->sh.ng) * bs.wi.z <= 0.0f)
            return 0; /* the shading normal sent the direction through the geometry */
        vp->delta = 1;
        /* The BSDF technique ran with probability 1 - g. */
        vp->delta_weight = rgb_scale(bs.weight, 1.0f / (1.0f - g));
        return 1;
    }
    vp->p_bsdf = bs.pdf;
    vp->q.pdf = g > 0.0f;
    return 1;
}

/* Adds a contribution c (throughput times radiance, RGB) that the technique of the vertex
 * `vertex_depth` deep found, with MIS weight w as the path weighs it and w_plain as plain
 * path tracing does (its scattered directions weighed by the BSDF's density), to what the
 * path says of each policy's second moment: a policy that guides the vertex weighs it as the
 * path does, one that does not as plain path tracing. */
static void moments_add(path_state *ps, int vertex_depth, rgb c, float w, float w_plain)
{
    if (!ps->guided) /* a plain path's moments are its square (path_moments) */
        return;
    float l = (c.r + c.g + c.b) / 3.0f;
    nf_path_add(&ps->guide, (uint32_t)vertex_depth, w * l, w_plain * l);
}

/* Adds radiance `value` found with MIS weight w (w_plain: plain path tracing's) after the
 * scattered direction of the vertex before this one, to the path's estimate and moments. */
static void path_add(path_state *ps, rgb value, float w, float w_plain)
{
    ps->L = rgb_add(ps->L, rgb_mul(ps->throughput, rgb_scale(value, w)));
    moments_add(ps, ps->depth - 1, rgb_mul(ps->throughput, value), w, w_plain);
}

/* What the path says of each policy's second moment (path_state.guide.moments): a guided
 * path's estimates, a plain path's squared luminance. */
void path_moments(const path_state *ps, float *out)
{
    float l = (ps->L.r + ps->L.g + ps->L.b) / 3.0f;
    for (int k = 0; k < PATH_MOMENTS; ++k)
        out[k] = ps->guided ? ps->guide.moments[k].moment : l * l;
}

/* The MIS weights of emission found after a scattered direction whose light-sampling density
 * is light_pdf: the path's (prev_pdf) and plain path tracing's (prev_p_bsdf). */
static void emission_weights(const path_state *ps, float light_pdf, float *w, float *w_plain)
{
    *w = ps->prev_pdf > 0.0f ? power_heuristic(ps->prev_pdf, light_pdf) : 1.0f;
    *w_plain = ps->prev_p_bsdf == ps->prev_pdf ? *w
               : ps->prev_p_bsdf > 0.0f        ? power_heuristic(ps->prev_p_bsdf, light_pdf)
                                               : 1.0f;
}

/* The rest of a vertex's plan once its scattering function is set up (vertex_plan_next,
 * volume_plan): next-event estimation, roulette and the scattered direction's technique. */
static int plan_light_and_scatter(const tracer *t, path_state *ps, rng *r, path_stats *st,
                                  vertex_plan *vp, int smooth, int depth)
{
    const scene *s = t->s;
    /* Next-event estimation: balance mode weighs the light sample against p_mix, which
     * needs the flow's density of its direction. */
    if (smooth && s->has_lights && nee_plan(t, vp, ps, r, st)) {
        vp->nee = 1;
        vp->q.light = vp->g > 0.0f && light_mis_uses_flow(t, depth);
    }

    /* Russian roulette, before scattering, so that a vertex either scatters fully or not at
     * all (a recorded direction always gets its radiance). */
    vp->rr = 1.0f;
    if (depth >= s->rr_depth) {
        float q = nf_path_survival(&ps->guide, &t->policy, rgb_max(ps->throughput));
        if (!(rng_next(r) < q))
            return 1; /* scatters = 0: the light sample still counts */
        vp->rr = 1.0f / q;
        if (ps->guided)
            nf_path_survived(&ps->guide, &t->policy, (uint32_t)depth, rgb_max(ps->throughput), q);
    }
    vp->scatters = scatter_plan(vp, r);
    if (!vp->scatters)
        vp->q.sample = vp->q.pdf = 0;
    return 1;
}


/* Clears what a vertex's plan decides, field by field rather than a memset of the whole
 * plan, which cost plain path tracing 7% in Veach Ajar. */
static void vertex_plan_reset(vertex_plan *vp, int volume)
{
    vp->g = 0.0f;
    vp->nee = vp->scatters = vp->flow_chosen = vp->delta = 0;
    vp->p_bsdf = 0.0f;
    vp->q.light = vp->q.sample = vp->q.pdf = vp->q.failed = 0;
    vp->q.light_p_flow = vp->q.p_flow = 0.0f;
    vp->volume = volume;
}

/* Plans a vertex where free flight stopped in a medium of asymmetry phase_g, at p, the ray
 * travelling along d: its context has the normal (0, 0, 0) (a medium point, nisflow/model.h)
 * and the phase function's g; the phase function is its "BSDF", guided as surface vertices
 * are (docs/model-layer.md, section 5b). */
static int volume_plan(const tracer *t, path_state *ps, rng *r, path_stats *st, vec3 p, vec3 d,
                       float phase_g, vertex_plan *vp)
{
    const int max_depth = t->s->max_depth < 0 ? 1 << 30 : t->s->max_depth;
    const int depth = ps->depth;
    if (depth >= max_depth)
        return 0;
    vertex_plan_reset(vp, 1);
    vp->phase_g = phase_g;
    vp->d = d;
    vp->p = p;
    vp->shape = -1;
    nf_context *ctx = &vp->q.ctx;
    ctx->position[0] = vp->gp.position[0] = p.x;
    ctx->position[1] = vp->gp.position[1] = p.y;
    ctx->position[2] = vp->gp.position[2] = p.z;
    ctx->normal[0] = ctx->normal[1] = ctx->normal[2] = 0.0f;
    ctx->wo[0] = -d.x;
    ctx->wo[1] = -d.y;
    ctx->wo[2] = -d.z;
    /* The library takes |g| <= NF_PHASE_G_MAX; the loader allows (-1, 1). The flow's prior
     * then differs a little from the phase function, which the mixture's weights absorb. */
    ctx->phase_g = clampf(phase_g, -NF_PHASE_G_MAX, NF_PHASE_G_MAX);
    memset(&vp->gp.bp, 0, sizeof vp->gp.bp); /* no material: the phase function */
    memset(&vp->sh.bp, 0, sizeof vp->sh.bp);
    const float g = t->model ? t->policy.mixture_prob : 0.0f;
    if (g > 0.0f) {
        vp->g = nf_path_mixture_prob(&ps->guide, &t->policy, (uint32_t)depth,
                                     (uint32_t)t->guide_depth);
        st->guided_vertices += vp->g > 0.0f;
    }
    return plan_light_and_scatter(t, ps, r, st, vp, 1, depth);
}

/* Traces the path's next segment and plans the vertex it finds: emission found there is
 * added (and handed to the previous record), then next-event estimation, roulette and the
 * choice of the scattered direction draw their random numbers, and the flow's questions are
 * set in vp->q. Returns 0 when the path ends before a vertex to plan. */
int vertex_plan_next(const tracer *t, path_state *ps, rng *r, path_stats *st,
                     nf_path_vertex *prev, vertex_plan *vp)
{
    const scene *s = t->s;
    const int max_depth = s->max_depth < 0 ? 1 << 30 : s->max_depth;
    ray ry = ps->ry;
    const int depth = ++ps->depth;
    hit h;
    int crossed = 0; /* null surfaces crossed since the previous vertex */
    int found;
    for (;;) {
        if (!scene_ray_valid(&ry)) { /* never within the loader's world range */
            st->invalid_rays++;
            return 0;
        }
        st->rays++;
        found = scene_intersect(s, &ry, &h);
        if (!s->has_media)
            break;
        if (ps->medium >= 0) {
            const medium *m = &s->media[ps->medium];
            float tm;
            rgb w;
            int scattered = medium_sample_flight(m, ps->throughput, ry.o, ry.d,
                                                 found ? h.t : INFINITY, r, &tm, &w);
            ps->throughput = rgb_mul(ps->throughput, w);
            if (rgb_is_black(ps->throughput) || !rgb_is_finite(ps->throughput))
                return 0;
            if (scattered)
                return volume_plan(t, ps, r, st, v3_add(ry.o, v3_scale(ry.d, tm)), ry.d, m->g,
                                   vp);
        }
        if (!found || !s->shapes[h.shape].null_surface)
            break;
        /* A null surface: the ray goes on, maybe into another medium, and no vertex is made. */
        surface nf;
        scene_surface(s, &h, &ry, &nf);
        ps->medium = scene_medium_after(s, h.shape, nf.ng, ry.d, ps->medium);
        crossed = 1;
        ry.o = scene_offset_origin(nf.p, nf.ng, ry.d);
        ry.tmax = INFINITY;
    }
    if (!found) {
        rgb le = env_eval(s, ry.d);
        if (!rgb_is_black(le)) {
            float w = 1.0f, w_plain = 1.0f;
            if (ps->prev_pdf > 0.0f || ps->prev_p_bsdf > 0.0f)
                emission_weights(ps, light_pdf_env(s, ry.d), &w, &w_plain);
            if (!(depth == 1 && s->hide_emitters))
                path_add(ps, le, w, w_plain);
            if (prev) {
                put_rgb(prev->emitted, le);
                prev->emitted_mis = w;
            }
        }
        return 0;
    }
    surface sf;
    scene_surface(s, &h, &ry, &sf);
    vec3 wo = v3_neg(ry.d);
    const shape *shp = &s->shapes[h.shape];

    if (shp->emissive && v3_dot(wo, sf.ng) > 0.0f) {
        float w = 1.0f, w_plain = 1.0f;
        if (ps->prev_pdf > 0.0f || ps->prev_p_bsdf > 0.0f) {
            /* The light sample's distance is from the vertex: across null surfaces, measure
             * it from the segment's start rather than add up lengths between offsets. */
            float dist = crossed ? v3_length(v3_sub(sf.p, ps->ry.o)) : h.t;
            emission_weights(ps, light_pdf_area(s, h.shape, h.prim, ry.d, dist, sf.ng), &w,
                             &w_plain);
        }
        if (!(depth == 1 && s->hide_emitters))
            path_add(ps, shp->radiance, w, w_plain);
        if (prev) {
            put_rgb(prev->emitted, shp->radiance);
            prev->emitted_mis = w;
        }
    }
    if (depth >= max_depth)
        return 0;

    vertex_plan_reset(vp, 0);
    if (s->has_media) {
        vp->d = ry.d;
        vp->shape = h.shape;
        vp->ng_geom = sf.ng;
    }
    if (!setup_shading(s, &h, &sf, wo, &vp->sh)) {
        st->camera_backfaces += depth == 1;
        return 0;
    }
    const bsdf *b = vp->sh.bp.b;
    const int smooth = bsdf_has_smooth_part(b);
    const float g = t->model ? t->policy.mixture_prob : 0.0f;
    /* Lobes sharper than the policy's min_roughness are left to the BSDF; the pass's depth
     * rule is nf_path_mixture_prob's. */
    const int guided = smooth && g > 0.0f &&
                       !((b->type == BSDF_ROUGHCONDUCTOR || b->type == BSDF_ROUGHDIELECTRIC) &&
                         b->alpha < t->policy.min_roughness);
    vp->p = sf.p;
    vec3 n = vp->sh.fr.n;
    nf_context *ctx = &vp->q.ctx;
    ctx->position[0] = vp->gp.position[0] = sf.p.x;
    ctx->position[1] = vp->gp.position[1] = sf.p.y;
    ctx->position[2] = vp->gp.position[2] = sf.p.z;
    ctx->normal[0] = n.x;
    ctx->normal[1] = n.y;
    ctx->normal[2] = n.z;
    ctx->wo[0] = wo.x;
    ctx->wo[1] = wo.y;
    ctx->wo[2] = wo.z;
    ctx->phase_g = 0.0f;
    vp->gp.bp = vp->sh.bp;
    if (guided) {
        vp->g = nf_path_mixture_prob(&ps->guide, &t->policy, (uint32_t)depth,
                                     (uint32_t)t->guide_depth);
        st->guided_vertices += vp->g > 0.0f;
    }

    return plan_light_and_scatter(t, ps, r, st, vp, smooth, depth);
}

/* The recipe of docs/integration.md: the thread's vertex object (made on first use) moved to
 * the vertex, asked for the light sample's density and for the scattered direction or the
 * BSDF direction's density, both in one call. At a shading point: the tracer's cells would
 * blur light that changes within them (docs/studies/cost-of-a-direction.md). */
void answer_at_point(const tracer *t, nf_vertex **flow, vertex_plan *vp, path_stats *st)
{
    flow_questions *q = &vp->q;
    if (!flow_asks(q))
        return;
    if (!*flow) {
        nf_vertex_config cfg;
        nf_vertex_config_init(&cfg);
        cfg.tables = 0;
        if (nf_vertex_create(&cfg, flow) != NF_OK)
            *flow = NULL;
    }
    nf_prior_callbacks bsdf_prior = bsdf_prior_at_point(&vp->gp);
    int ok = *flow && nf_vertex_set(*flow, t->model, &q->ctx, t->bsdf_prior ? &bsdf_prior : NULL,
                                    NF_VERTEX_POINT) == NF_OK;
    /* Two questions go in one call, whose walks through the flow interleave. */
    float d[3], dirs[6], p[2];
    if (ok && q->sample) {
        if (q->light)
            put_vec3(dirs, q->light_wi);
        ok = nf_vertex_sample(*flow, q->u, d, &q->p_flow, q->light ? 1 : 0, dirs,
                              &q->light_p_flow) == NF_OK;
        q->wi = v3(d[0], d[1], d[2]);
    } else if (ok && (q->pdf || q->light)) {
        size_t n = 0;
        if (q->pdf)
            put_vec3(dirs + 3 * n++, q->wi);
        if (q->light)
            put_vec3(dirs + 3 * n++, q->light_wi);
        ok = nf_vertex_pdf(*flow, n, dirs, p) == NF_OK;
        q->p_flow = q->pdf ? p[0] : q->p_flow;
        q->light_p_flow = q->light ? p[n - 1] : q->light_p_flow;
    }
    if (!ok) {
        st->nf_errors++;
        q->failed = 1;
    }
}

/* Finishes a planned vertex with the flow's answers: the light sample's contribution with its
 * MIS weight, then the scattered direction's weight and the next ray. Returns 0 when the path
 * ends here. */
int vertex_finish(const tracer *t, path_state *ps, const vertex_plan *vp,
                  nf_path_vertex *v, vertex_extra *vx)
{
    const flow_questions *q = &vp->q;
    if (q->failed)
        return 0;
    const float g = vp->g;
    if (vp->nee) {
        float p_mix = vp->nee_p_bsdf;
        if (q->light)
            p_mix = g * q->light_p_flow + (1.0f - g) * p_mix;
        float w = power_heuristic(vp->nee_light_pdf, p_mix);
        rgb d = rgb_scale(vp->nee_value, w / vp->nee_light_pdf);
        ps->L = rgb_add(ps->L, rgb_mul(ps->throughput, d));
        if (ps->guided) {
            float w_plain = q->light ? power_heuristic(vp->nee_light_pdf, vp->nee_p_bsdf) : w;
            rgb c = rgb_scale(rgb_mul(ps->throughput, vp->nee_value), 1.0f / vp->nee_light_pdf);
            moments_add(ps, ps->depth, c, w, w_plain);
        }
        if (v)
            put_rgb(v->direct, d);
    }
    if (!vp->scatters)
        return 0;

    /* The scattered direction's weight: the mixture density p_mix = g p_flow + (1 - g) p_bsdf. */
    vec3 wi = q->wi;
    rgb weight;
    /* p_flow stays 0 where the flow was not asked (the plan zeroes it) */
    float pdf = 0.0f, p_flow = q->p_flow, p_bsdf = vp->p_bsdf;
    if (vp->delta) {
        weight = vp->delta_weight;
        if (g > 0.0f) { /* the BSDF technique ran with probability 1 - g */
    nf_path_scatter(&ps->guide, (uint32_t)ps->depth, 0.0f, 0.0f, g);
        }
    } else {
        if (vp->flow_chosen)
            p_bsdf = vertex_pdf(vp, wi);
        rgb f = vertex_eval(vp, wi);
        float p_weight = g * p_flow + (1.0f - g) * p_bsdf; /* what the throughput divides by */
        /* the density light MIS weighs with, as the light sample's side above */
        pdf = light_mis_uses_flow(t, ps->depth) ? p_weight : p_bsdf;
        if (!(p_weight > 0.0f) || rgb_is_black(f))
            return 0;
        weight = rgb_scale(f, 1.0f / p_weight);
        if (g > 0.0f) {
            nf_path_scatter(&ps->guide, (uint32_t)ps->depth, p_bsdf, p_weight, g);
        }
    }
    if (!rgb_is_finite(weight) || rgb_is_black(weight))
        return 0;
    ps->throughput = rgb_mul(ps->throughput, rgb_scale(weight, vp->rr));
    if (v) {
        put_rgb(v->beta, rgb_scale(weight, vp->rr));
        if (g > 0.0f && !vp->delta) { /* the flow can only learn non-delta directions */
            v->learn = 1;
            put_rgb(v->f_over_p, weight);
            v->ctx = q->ctx;
            put_vec3(v->dir, wi);
            vx->bp = vp->sh.bp; /* volume vertices: bp.b is NULL (the phase function) */
        }
    }
    ps->prev_pdf = pdf;
    ps->prev_p_bsdf = vp->delta ? 0.0f : p_bsdf;
    if (t->s->has_media) {
        ps->medium = medium_towards(t->s, vp, ps, wi);
        if (vp->volume) {
            ps->ry.o = vp->p;
            ps->ry.d = wi;
            ps->ry.tmax = INFINITY;
            return 1;
        }
    }
    ps->ry.o = scene_offset_origin(vp->p, vp->sh.ng, wi);
    ps->ry.d = wi;
    ps->ry.tmax = INFINITY;
    return 1;
}

/* The pixel a film position falls in, clamped to the film. */
uint32_t film_pixel(const scene *s, float px, float py)
{
    int x = (int)px, y = (int)py;
    x = x < 0 ? 0 : x >= s->width ? s->width - 1 : x;
    y = y < 0 ? 0 : y >= s->height ? s->height - 1 : y;
    return (uint32_t)y * (uint32_t)s->width + (uint32_t)x;
}

void path_start(const tracer *t, float px, float py, path_state *ps)
{
    const scene *s = t->s;
    ps->guided = t->model != NULL;
    ps->L = rgb_gray(0.0f);
    ps->throughput = rgb_gray(1.0f);
    ps->ry = camera_ray(s, px, py);
    ps->prev_pdf = 0.0f; /* density of the last scattered direction (0: delta or camera) */
    ps->prev_p_bsdf = 0.0f;
    ps->depth = 0;
    ps->medium = s->camera_medium;
    nf_path_start(&ps->guide);
}

