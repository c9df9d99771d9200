/*
 * vertex.h - one vertex of a path, the integrator's step (vertex.c), between its two loops
 * (integrator.c: one path at a time, or many paths whose flow questions are batched): the
 * plan of a vertex with the questions it asks the flow, the answers at one shading point, and
 * the finish that weighs them. Internal to render/.
 */
#ifndef TRACER_VERTEX_H
#define TRACER_VERTEX_H

#include <nisflow/nisflow.h>

#include "bsdf.h"
#include "integrator.h"
#include "model_setup.h"
#include "path_record.h"

/* The shading setup at a hit: material, frame and orientation. */
typedef struct shading {
    bsdf_point bp;
    vec3 ng;      /* geometric normal; for reflective materials on wo's side           */
    frame fr;     /* shading frame                                                     */
    vec3 wo_l;    /* wo in the shading frame                                           */
} shading;

/* What a guided vertex asks the flow, once it has drawn all its random numbers: the density
 * of the light sample's direction (balance mode, unoccluded light sample), and either a
 * direction drawn for u or the density of the BSDF's direction. The answers come from a
 * shading point at once (trace_path, docs/integration.md) or from one batched nf_sample and
 * nf_pdf over many paths' vertices (trace_paths): the library gives the same bits either way. */
typedef struct flow_questions {
    nf_context ctx;
    int light;  /* asks light_p_flow = p_flow(light_wi) */
    int sample; /* asks wi and p_flow for u             */
    int pdf;    /* asks p_flow = p_flow(wi)             */
    float u[2];
    vec3 light_wi, wi;
    float light_p_flow, p_flow;
    int failed; /* the library refused (counted in nf_errors): the path ends here, without
                 * this vertex's light sample */
} flow_questions;

/* A vertex between drawing its random numbers and finishing. */
typedef struct vertex_plan {
    shading sh;
    vec3 p;
    /* A vertex in a medium (volume = 1) has no shading: the phase function with asymmetry
     * phase_g around the propagation direction d plays the BSDF's role (no cosine). */
    int volume;
    float phase_g;
    vec3 d;
    /* Surface vertices in scenes with media: the shape and its geometric normal, for the
     * medium a transmitted direction enters (scene_medium_after). */
    int shape;
    vec3 ng_geom;
    prior_point gp; /* the BSDF prior's material, read by the point's callbacks */
    float g;        /* the vertex's guiding probability; 0: not guided          */
    /* next-event estimation: an unoccluded light sample waiting for its MIS weight */
    int nee;
    rgb nee_value; /* f Le */
    float nee_light_pdf, nee_p_bsdf;
    /* scattering */
    int scatters; /* 0: the path ends here (roulette, failed sample) */
    float rr;
    int flow_chosen;
    int delta;
    rgb delta_weight;
    float p_bsdf;
    flow_questions q;
} vertex_plan;

/* Traces the path's next segment and plans the vertex it finds: emission found there is
 * added (and handed to the previous record, prev, which may be NULL), then next-event
 * estimation, roulette and the choice of the scattered direction draw their random numbers,
 * and the flow's questions are set in vp->q. Returns 0 when the path ends before a vertex to
 * plan. */
int vertex_plan_next(const tracer *t, path_state *ps, rng *r, path_stats *st,
                     nf_path_vertex *prev, vertex_plan *vp);

/* The recipe of docs/integration.md: the flow's questions answered at one shading point. */
void answer_at_point(const tracer *t, nf_vertex **flow, vertex_plan *vp, path_stats *st);

/* Finishes a planned vertex with the flow's answers: the light sample's contribution with its
 * MIS weight, then the scattered direction's weight and the next ray; v and vx, when not
 * NULL, receive its record. Returns 0 when the path ends here. */
int vertex_finish(const tracer *t, path_state *ps, const vertex_plan *vp, nf_path_vertex *v,
                  vertex_extra *vx);

/* The path's start through film position (px, py), and the pixel that position falls in. */
void path_start(const tracer *t, float px, float py, path_state *ps);
uint32_t film_pixel(const scene *s, float px, float py);

/* What the path says of each policy's second moment (path_state.moments). */
void path_moments(const path_state *ps, float *out);

static inline int flow_asks(const flow_questions *q) { return q->light || q->sample || q->pdf; }

static inline void put_vec3(float out[3], vec3 v)
{
    out[0] = v.x;
    out[1] = v.y;
    out[2] = v.z;
}

#endif /* TRACER_VERTEX_H */
