/*
 * integrator.c - the path tracer (see integrator.h).
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
 *     scattered ray weighs p_mix against the light density (power heuristic).
 * The plain mixture (tracer.plain_mixture) is the other one-sample estimator: each technique
 * weighs its direction by its own density, and light-sampling MIS uses p_bsdf on both sides
 * (the weights still sum to one); the flow is then called only where it samples. Which
 * vertices are guided: non-delta ones up to guide_depth, not smooth rough conductors
 * (guide_min_roughness), and where a learned selection grid gives g = 0 none at all.
 */
#include "integrator.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "guide.h"
#include "selection.h"

#define MAX_RECORDED_VERTICES 256

void record_buffer_free(record_buffer *b)
{
    free(b->data);
    memset(b, 0, sizeof *b);
}

static train_record *record_push(record_buffer *b)
{
    if (b->count == b->capacity) {
        size_t cap = b->capacity ? 2 * b->capacity : 256;
        train_record *d = realloc(b->data, cap * sizeof *d);
        if (!d) {
            b->out_of_memory = 1;
            return NULL;
        }
        b->data = d;
        b->capacity = cap;
    }
    return &b->data[b->count++];
}

int record_buffer_append(record_buffer *dst, const record_buffer *src)
{
    if (dst->count + src->count > dst->capacity) {
        size_t cap = dst->capacity ? dst->capacity : 256;
        while (cap < dst->count + src->count)
            cap *= 2;
        train_record *d = realloc(dst->data, cap * sizeof *d);
        if (!d) {
            dst->out_of_memory = 1;
            return 0;
        }
        dst->data = d;
        dst->capacity = cap;
    }
    if (src->count)
        memcpy(dst->data + dst->count, src->data, src->count * sizeof *src->data);
    dst->count += src->count;
    return 1;
}

void path_stats_add(path_stats *a, const path_stats *b)
{
    a->paths += b->paths;
    a->rays += b->rays;
    a->guided_vertices += b->guided_vertices;
    a->nf_errors += b->nf_errors;
    a->camera_backfaces += b->camera_backfaces;
    a->invalid_rays += b->invalid_rays;
}

static float power_heuristic(float a, float b)
{
    float a2 = a * a, b2 = b * b;
    return a2 + b2 > 0.0f ? a2 / (a2 + b2) : 0.0f;
}

/* A ray origin pushed off the surface, to the side that `dir` leaves towards, so that the
 * ray does not hit the triangle it starts on. The offset grows with the coordinates'
 * magnitude because so does their rounding error. */
static vec3 offset_origin(vec3 p, vec3 ng, vec3 dir)
{
    float eps = 1e-5f * (1.0f + v3_max_abs(p));
    return v3_add(p, v3_scale(ng, v3_dot(dir, ng) > 0.0f ? eps : -eps));
}

/* What a recorded vertex keeps beside the library's nf_path_vertex (nisflow/path.h, which
 * does the backward walk): the material for the BSDF prior, and the mixture at the sampled
 * direction for the learned guiding probability. */
typedef struct vertex_extra {
    bsdf_point bp;
    float p_flow, p_bsdf, alpha;
    uint32_t cell;
} vertex_extra;

static void put_rgb(float out[3], rgb c)
{
    out[0] = c.r;
    out[1] = c.g;
    out[2] = c.b;
}

/* Appends the training samples of a recorded path (nf_path_training_samples does the walk:
 * next-event estimates, MIS weights, roulette). Returns 0 if the library refused the path. */
static int record_path(const tracer *t, nf_path_vertex *pv, const vertex_extra *ex, int nv,
                       record_buffer *records)
{
    nf_context ctx[MAX_RECORDED_VERTICES];
    float dir[3 * MAX_RECORDED_VERTICES], weight[MAX_RECORDED_VERTICES];
    size_t from[MAX_RECORDED_VERTICES], n = 0;
    if (t->mis_training) /* L_i counts the emission found with its MIS weight (options.h) */
        for (int j = 0; j < nv; ++j) {
            for (int c = 0; c < 3; ++c)
                pv[j].emitted[c] *= pv[j].emitted_mis;
            pv[j].emitted_mis = 1.0f;
        }
    if (nf_path_training_samples((size_t)nv, pv, (size_t)nv, ctx, dir, weight, from, &n) != NF_OK)
        return 0;
    for (size_t i = 0; i < n; ++i) {
        train_record *rec = record_push(records);
        if (!rec)
            return 1; /* out_of_memory is set: the caller reports it */
        const vertex_extra *x = &ex[from[i]];
        rec->ctx = ctx[i];
        memcpy(rec->dir, dir + 3 * i, sizeof rec->dir);
        rec->weight = weight[i];
        rec->bp = x->bp;
        rec->p_flow = x->p_flow;
        rec->p_bsdf = x->p_bsdf;
        rec->alpha = x->alpha;
        rec->cell = x->cell;
    }
    return 1;
}

/* The shading setup at a hit: material, frame and orientation. Returns 0 when the surface
 * cannot scatter towards wo (the back of a one-sided material). */
typedef struct shading {
    bsdf_point bp;
    vec3 ng;      /* geometric normal; for reflective materials on wo's side           */
    frame fr;     /* shading frame                                                     */
    vec3 wo_l;    /* wo in the shading frame                                           */
} shading;

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

/* The flow's density of w at the vertex's prepared shading point. */
static int flow_pdf(const tracer *t, const nf_shading_point *sp, vec3 w, float *pdf,
                    path_stats *st)
{
    float d[3] = {w.x, w.y, w.z};
    if (nf_point_pdf(t->model, sp, 1, d, pdf) != NF_OK) {
        st->nf_errors++;
        return 0;
    }
    return 1;
}

/* The MIS-weighted next-event estimate at a vertex (without the path throughput): one light
 * sample, weighed against the density of the scattering technique, p_mix. g = 0: no flow. */
static rgb next_event(const tracer *t, const shading *sh, const surface *sf,
                      const nf_shading_point *sp, float g, rng *r, path_stats *st)
{
    const scene *s = t->s;
    rgb zero = rgb_gray(0.0f);
    light_sample ls;
    float u_pick = rng_next(r), u0 = rng_next(r), u1 = rng_next(r);
    if (!light_sample_from(s, sf->p, u_pick, u0, u1, &ls))
        return zero;
    vec3 wi_l;
    rgb f = shading_eval(sh, ls.wi, &wi_l);
    if (rgb_is_black(f) || rgb_is_black(ls.radiance))
        return zero;
    ray shadow;
    shadow.o = offset_origin(sf->p, sh->ng, ls.wi);
    shadow.d = ls.wi;
    shadow.tmax = isinf(ls.dist) ? INFINITY : ls.dist * (1.0f - 1e-4f);
    if (!scene_ray_valid(&shadow)) { /* never within the loader's world range */
        st->invalid_rays++;
        return zero;
    }
    st->rays++;
    if (scene_occluded(s, &shadow))
        return zero;
    float p_mix = bsdf_pdf(&sh->bp, sh->wo_l, wi_l);
    if (g > 0.0f) {
        float p_flow;
        if (!flow_pdf(t, sp, ls.wi, &p_flow, st))
            return zero;
        p_mix = g * p_flow + (1.0f - g) * p_mix;
    }
    float w = power_heuristic(ls.pdf, p_mix);
    return rgb_scale(rgb_mul(f, ls.radiance), w / ls.pdf);
}

/* A scattered direction and what the path needs to know about it. */
typedef struct scattered {
    vec3 wi;
    float p_flow, p_bsdf; /* the two techniques' densities of wi (non-delta)            */
    rgb weight;  /* f |cos| / p (delta lobes: the lobe's weight / its probability)       */
    float pdf;   /* the solid-angle density of wi for MIS; 0 after a delta lobe          */
    int delta;
} scattered;

/* The flow at a guided vertex. Balance mode prepares the shading point before next-event
 * estimation; plain mode prepares it only when the flow technique is chosen. */
typedef struct vertex_flow {
    float g;                        /* the vertex's guiding probability; 0: not guided      */
    int plain;                      /* plain one-sample mixture (tracer.plain_mixture)      */
    int prepared;
    nf_shading_point *sp;
    const nf_context *ctx;
    const nf_prior_callbacks *prior;
} vertex_flow;

static int flow_point(const tracer *t, vertex_flow *vf, path_stats *st)
{
    if (!vf->prepared) {
        if (nf_point_prepare(t->model, vf->ctx, vf->prior, vf->sp) != NF_OK) {
            st->nf_errors++;
            return 0;
        }
        vf->prepared = 1;
    }
    return 1;
}

/* Chooses the next direction. With g > 0 (a guided vertex), from the flow with probability
 * g and from the BSDF otherwise. Balance mode weighs either by the mixture density
 * p_mix = g p_flow + (1 - g) p_bsdf; plain mode weighs each by its own density (both
 * one-sample MIS estimators, docs/equal-time.md). With g = 0, from the BSDF alone. Returns 0
 * when the path ends here (failed sample, direction through the geometry, zero
 * contribution). */
static int scatter(const tracer *t, const shading *sh, vertex_flow *vf, rng *r, path_stats *st,
                   scattered *out)
{
    const float g = vf->g;
    float u_sel = rng_next(r), u_lobe = rng_next(r), u0 = rng_next(r), u1 = rng_next(r);
    float p_flow = 0.0f, p_bsdf = 0.0f;
    int flow_chosen = g > 0.0f && u_sel < g;
    out->delta = 0;
    out->p_flow = out->p_bsdf = 0.0f;
    if (flow_chosen) {
        float u[2] = {u0, u1}, d[3];
        if (!flow_point(t, vf, st))
            return 0;
        if (nf_point_sample(t->model, vf->sp, 1, u, d, &p_flow) != NF_OK) {
            st->nf_errors++;
            return 0;
        }
        out->wi = v3(d[0], d[1], d[2]);
        p_bsdf = bsdf_pdf(&sh->bp, sh->wo_l, frame_to_local(&sh->fr, out->wi));
    } else {
        bsdf_sample bs;
        if (!bsdf_sample_dir(&sh->bp, sh->wo_l, u_lobe, u0, u1, &bs))
            return 0;
        out->wi = frame_to_world(&sh->fr, bs.wi);
        if (bs.delta) {
            if (v3_dot(out->wi, sh->ng) * bs.wi.z <= 0.0f)
                return 0; /* the shading normal sent the direction through the geometry */
            out->delta = 1;
            /* The BSDF technique ran with probability 1 - g. */
            out->weight = rgb_scale(bs.weight, 1.0f / (1.0f - g));
            out->pdf = 0.0f;
            return 1;
        }
        p_bsdf = bs.pdf;
        if (g > 0.0f && !vf->plain &&
            !(flow_point(t, vf, st) && flow_pdf(t, vf->sp, out->wi, &p_flow, st)))
            return 0;
    }
    vec3 wi_l;
    rgb f = shading_eval(sh, out->wi, &wi_l);
    out->p_flow = p_flow;
    out->p_bsdf = p_bsdf;
    float p_weight; /* the density the throughput divides by */
    if (vf->plain) {
        p_weight = flow_chosen ? p_flow : p_bsdf;
        out->pdf = p_bsdf; /* MIS against light sampling ignores the flow (next_event too) */
    } else {
        p_weight = out->pdf = g * p_flow + (1.0f - g) * p_bsdf;
    }
    if (!(p_weight > 0.0f) || rgb_is_black(f))
        return 0;
    out->weight = rgb_scale(f, 1.0f / p_weight);
    return 1;
}

rgb trace_path(const tracer *t, rng *r, float px, float py, record_buffer *records,
               path_stats *st)
{
    const scene *s = t->s;
    const int max_depth = s->max_depth < 0 ? 1 << 30 : s->max_depth;
    const float g = t->model ? t->guide_prob : 0.0f;
    nf_path_vertex pv[MAX_RECORDED_VERTICES]; /* the library's record of the path */
    vertex_extra ex[MAX_RECORDED_VERTICES];
    int nv = 0; /* recorded vertices (only when training) */

    rgb L = rgb_gray(0.0f), throughput = rgb_gray(1.0f);
    ray ry = camera_ray(s, px, py);
    float prev_pdf = 0.0f; /* density of the last scattered direction (0: delta or camera) */
    st->paths++;

    for (int depth = 1;; ++depth) {
        hit h;
        if (!scene_ray_valid(&ry)) { /* never within the loader's world range */
            st->invalid_rays++;
            break;
        }
        st->rays++;
        /* The previous vertex's record receives what this ray finds. */
        nf_path_vertex *prev = records && nv > 0 && nv <= MAX_RECORDED_VERTICES ? &pv[nv - 1] : NULL;
        if (!scene_intersect(s, &ry, &h)) {
            rgb le = env_eval(s, ry.d);
            if (!rgb_is_black(le)) {
                float w = prev_pdf > 0.0f ? power_heuristic(prev_pdf, light_pdf_env(s, ry.d)) : 1.0f;
                if (!(depth == 1 && s->hide_emitters))
                    L = rgb_add(L, rgb_mul(throughput, rgb_scale(le, w)));
                if (prev) {
                    put_rgb(prev->emitted, le);
                    prev->emitted_mis = w;
                }
            }
            break;
        }
        surface sf;
        scene_surface(s, &h, &ry, &sf);
        vec3 wo = v3_neg(ry.d);
        const shape *shp = &s->shapes[h.shape];

        if (shp->emissive && v3_dot(wo, sf.ng) > 0.0f) {
            float w = 1.0f;
            if (prev_pdf > 0.0f)
                w = power_heuristic(prev_pdf, light_pdf_area(s, h.shape, h.prim, ry.d, h.t, sf.ng));
            if (!(depth == 1 && s->hide_emitters))
                L = rgb_add(L, rgb_mul(throughput, rgb_scale(shp->radiance, w)));
            if (prev) {
                put_rgb(prev->emitted, shp->radiance);
                prev->emitted_mis = w;
            }
        }
        if (depth >= max_depth)
            break;

        shading sh;
        if (!setup_shading(s, &h, &sf, wo, &sh)) {
            st->camera_backfaces += depth == 1;
            break;
        }
        const bsdf *b = sh.bp.b;
        const int smooth = bsdf_has_smooth_part(b);
        const int guided = smooth && g > 0.0f && (t->guide_depth == 0 || depth <= t->guide_depth) &&
                           !(b->type == BSDF_ROUGHCONDUCTOR && b->alpha < t->guide_min_roughness);

        nf_path_vertex *v = NULL;
        vertex_extra *vx = NULL;
        if (records && nv < MAX_RECORDED_VERTICES) {
            v = &pv[nv];
            vx = &ex[nv++];
            memset(v, 0, sizeof *v);
        } else if (records) {
            nv = MAX_RECORDED_VERTICES + 1; /* past the cap: stop recording this path */
        }

        nf_context ctx;
        guide_point gp;
        vec3 n = sh.fr.n;
        ctx.position[0] = gp.position[0] = sf.p.x;
        ctx.position[1] = gp.position[1] = sf.p.y;
        ctx.position[2] = gp.position[2] = sf.p.z;
        ctx.normal[0] = n.x;
        ctx.normal[1] = n.y;
        ctx.normal[2] = n.z;
        ctx.wo[0] = wo.x;
        ctx.wo[1] = wo.y;
        ctx.wo[2] = wo.z;
        gp.bp = sh.bp;

        /* A guided vertex prepares the flow's shading point once; the light sample's density
         * and the scattering below both use it (docs/integration.md). With the plain mixture
         * it is prepared only if the flow samples. The BSDF prior gets this vertex's material
         * through the point's own callbacks. */
        nf_shading_point sp;
        nf_prior_callbacks bsdf_prior = guide_point_callbacks(&gp);
        vertex_flow vf = {0.0f, t->plain_mixture, 0, &sp, &ctx, t->bsdf_prior ? &bsdf_prior : NULL};
        size_t cell = 0;
        if (guided) {
            vf.g = g;
            if (t->selection) { /* learned per cell; 0 there: not guided at all */
                cell = selection_cell(t->selection, sf.p, n);
                vf.g = selection_prob(t->selection, cell);
            }
            if (vf.g > 0.0f && !vf.plain && !flow_point(t, &vf, st))
                vf.g = 0.0f; /* the error is counted; the vertex goes unguided */
            st->guided_vertices += vf.g > 0.0f;
        }

        /* Next-event estimation. */
        if (smooth && s->has_lights) {
            rgb d = next_event(t, &sh, &sf, &sp, vf.plain ? 0.0f : vf.g, r, st);
            L = rgb_add(L, rgb_mul(throughput, d));
            if (v)
                put_rgb(v->direct, d);
        }

        /* Russian roulette, before scattering, so that a vertex either scatters fully or
         * not at all (a recorded direction always gets its radiance). */
        float rr = 1.0f;
        if (depth >= s->rr_depth) {
            float q = fminf(rgb_max(throughput), 0.95f);
            if (!(rng_next(r) < q))
                break;
            rr = 1.0f / q;
        }

        /* Scattering: flow or BSDF, weighted by the mixture density. */
        scattered sc;
        if (!scatter(t, &sh, &vf, r, st, &sc))
            break;
        if (!rgb_is_finite(sc.weight) || rgb_is_black(sc.weight))
            break;
        throughput = rgb_mul(throughput, rgb_scale(sc.weight, rr));
        if (v) {
            put_rgb(v->beta, rgb_scale(sc.weight, rr));
            if (vf.g > 0.0f && !sc.delta) { /* the flow can only learn non-delta directions */
                v->learn = 1;
                put_rgb(v->f_over_p, sc.weight);
                v->ctx = ctx;
                v->dir[0] = sc.wi.x;
                v->dir[1] = sc.wi.y;
                v->dir[2] = sc.wi.z;
                vx->bp = sh.bp;
                vx->p_flow = sc.p_flow;
                vx->p_bsdf = sc.p_bsdf;
                vx->alpha = vf.g;
                vx->cell = (uint32_t)cell;
            }
        }
        prev_pdf = sc.pdf;
        ry.o = offset_origin(sf.p, sh.ng, sc.wi);
        ry.d = sc.wi;
        ry.tmax = INFINITY;
    }

    /* Training: the library walks the path backwards (nisflow/path.h). */
    if (records && nv > 0 && nv <= MAX_RECORDED_VERTICES && !record_path(t, pv, ex, nv, records))
        st->nf_errors++;
    return L;
}
