/*
 * integrator.c - the path tracer's two loops over a path's vertices (integrator.h): one path
 * at a time, each vertex answered at its own shading point through the thread's vertex object
 * (trace_path), or a batch of paths
 * advancing together, each round's flow questions answered in one batched nf_sample and
 * nf_pdf (trace_paths). The vertex itself, and the estimator, are vertex.c's.
 */
#include "integrator.h"

#include <stdlib.h>

#include "vertex.h"

void path_stats_add(path_stats *a, const path_stats *b)
{
    a->paths += b->paths;
    a->rays += b->rays;
    a->guided_vertices += b->guided_vertices;
    a->nf_errors += b->nf_errors;
    a->camera_backfaces += b->camera_backfaces;
    a->invalid_rays += b->invalid_rays;
}

rgb trace_path(const tracer *t, rng *r, float px, float py, record_buffer *records,
               trace_scratch *sc, path_stats *st)
{
    return trace_path_moment(t, r, px, py, records, sc, st, NULL);
}

rgb trace_path_moment(const tracer *t, rng *r, float px, float py, record_buffer *records,
                      trace_scratch *sc, path_stats *st, float *moment)
{
    nf_path_vertex pv[MAX_RECORDED_VERTICES]; /* the library's record of the path */
    vertex_extra ex[MAX_RECORDED_VERTICES];
    path_recorder rec = {pv, ex, 0, MAX_RECORDED_VERTICES}, *pr = records ? &rec : NULL;
    path_state ps;
    path_start(t, px, py, &ps);
    st->paths++;
    for (;;) {
        /* The previous vertex's record receives what this ray finds. */
        nf_path_vertex *prev = recorder_last(pr), *v;
        vertex_extra *vx;
        vertex_plan vp;
        if (!vertex_plan_next(t, &ps, r, st, prev, &vp))
            break;
        recorder_open(pr, &v, &vx);
        answer_at_point(t, &sc->flow, &vp, st);
        if (!vertex_finish(t, &ps, &vp, v, vx))
            break;
    }
    if (pr)
        recorder_close(t, pr, film_pixel(t->s, px, py), records, st);
    if (moment)
        path_moments(&ps, moment);
    return ps.L;
}

/* The questions of n planned vertices, answered by one nf_sample call for the flow samples
 * and one nf_pdf call for every density (light samples' and BSDF directions'), which run
 * the library's 16-lane kernels. A refused batch (which valid contexts never cause) is asked
 * again one vertex at a time, so that only the vertex the library refuses fails. */
static void answer_batch(const tracer *t, vertex_plan *const *vps, size_t n, trace_scratch *sc,
                         path_stats *st)
{
    nf_context sctx[TRACE_BATCH], pctx[2 * TRACE_BATCH];
    float su[2 * TRACE_BATCH], sdir[3 * TRACE_BATCH], spdf[TRACE_BATCH];
    float pdir[6 * TRACE_BATCH], ppdf[2 * TRACE_BATCH];
    float *pout[2 * TRACE_BATCH];
    vertex_plan *sfrom[TRACE_BATCH];
    size_t ns = 0, np = 0;
    for (size_t i = 0; i < n; ++i) {
        flow_questions *q = &vps[i]->q;
        if (q->light) {
            pctx[np] = q->ctx;
            put_vec3(pdir + 3 * np, q->light_wi);
            pout[np++] = &q->light_p_flow;
        }
        if (q->sample) {
            sctx[ns] = q->ctx;
            su[2 * ns] = q->u[0];
            su[2 * ns + 1] = q->u[1];
            sfrom[ns++] = vps[i];
        } else if (q->pdf) {
            pctx[np] = q->ctx;
            put_vec3(pdir + 3 * np, q->wi);
            pout[np++] = &q->p_flow;
        }
    }
    if ((ns && nf_sample(t->model, ns, sctx, su, sdir, spdf) != NF_OK) ||
        (np && nf_pdf(t->model, np, pctx, pdir, ppdf) != NF_OK)) {
        for (size_t i = 0; i < n; ++i)
            answer_at_point(t, &sc->flow, vps[i], st);
        return;
    }
    for (size_t i = 0; i < ns; ++i) {
        sfrom[i]->q.wi = v3(sdir[3 * i], sdir[3 * i + 1], sdir[3 * i + 2]);
        sfrom[i]->q.p_flow = spdf[i];
    }
    for (size_t i = 0; i < np; ++i)
        *pout[i] = ppdf[i];
}

int trace_paths_pay(const tracer *t)
{
    /* Models with the BSDF prior answer at shading points: the batch calls would hand its
     * callbacks contexts they cannot find the material of (bsdf_prior.h). */
    return t->model && t->policy.mixture_prob > 0.0f && !t->bsdf_prior && !t->no_batching;
}

/* Takes a path to its next vertex that asks the flow something (returns 1, the questions in
 * vp->q, its record opened in *v, *vx) or to its end (returns 0); the vertices between, which
 * ask nothing, are finished on the way, so that a path that seldom asks runs as trace_path
 * runs it. pr: the path's record, or NULL. */
static int advance_to_question(const tracer *t, path_state *ps, rng *r, path_stats *st,
                               path_recorder *pr, vertex_plan *vp, nf_path_vertex **v,
                               vertex_extra **vx)
{
    for (;;) {
        if (!vertex_plan_next(t, ps, r, st, recorder_last(pr), vp))
            return 0;
        recorder_open(pr, v, vx);
        if (flow_asks(&vp->q))
            return 1;
        if (!vertex_finish(t, ps, vp, *v, *vx))
            return 0;
    }
}

static void scratch_free_records(trace_scratch *sc)
{
    free(sc->mem);
    sc->mem = NULL;
    sc->bytes = 0;
}

void trace_scratch_free(trace_scratch *sc)
{
    scratch_free_records(sc);
    nf_vertex_destroy(sc->flow);
    sc->flow = NULL;
}

/* The records of n paths in sc (grown if it is too small); NULL when out of memory. */
static path_recorder *recorders_in(const scene *s, size_t n, trace_scratch *sc)
{
    /* A path plans at most max_depth - 1 vertices (vertex_plan_next): a cap of max_depth
     * records every path trace_path records, and drops the same ones. */
    int cap = s->max_depth > 0 && s->max_depth < MAX_RECORDED_VERTICES ? s->max_depth
                                                                      : MAX_RECORDED_VERTICES;
    /* Largest alignment first: recorders, then the extras (a pointer inside), then the
     * library's vertices (floats). */
    size_t bytes = n * (sizeof(path_recorder) +
                        (size_t)cap * (sizeof(vertex_extra) + sizeof(nf_path_vertex)));
    if (sc->bytes < bytes) {
        scratch_free_records(sc);
        if (!(sc->mem = malloc(bytes)))
            return NULL;
        sc->bytes = bytes;
    }
    path_recorder *pr = sc->mem;
    vertex_extra *ex = (vertex_extra *)(pr + n);
    nf_path_vertex *pv = (nf_path_vertex *)(ex + n * (size_t)cap);
    for (size_t i = 0; i < n; ++i) {
        pr[i].pv = pv + i * (size_t)cap;
        pr[i].ex = ex + i * (size_t)cap;
        pr[i].nv = 0;
        pr[i].cap = cap;
    }
    return pr;
}

void trace_paths(const tracer *t, size_t n, rng *r, const float *px, const float *py, rgb *out,
                 float *moment, record_buffer *records, trace_scratch *scratch, path_stats *st)
{
    path_state ps[TRACE_BATCH];
    vertex_plan vp[TRACE_BATCH];
    vertex_plan *asking[TRACE_BATCH];
    nf_path_vertex *v[TRACE_BATCH];
    vertex_extra *vx[TRACE_BATCH];
    size_t live[TRACE_BATCH], nlive = 0;
    n = n < TRACE_BATCH ? n : TRACE_BATCH;
    path_recorder *pr = trace_paths_pay(t) && records ? recorders_in(t->s, n, scratch) : NULL;
    if (!trace_paths_pay(t) || (records && !pr)) { /* the same bits, one path at a time */
        for (size_t i = 0; i < n; ++i)
            out[i] =
                trace_path_moment(t, &r[i], px[i], py[i], records, scratch, st,
                                  moment ? &moment[PATH_MOMENTS * i] : NULL);
        return;
    }
    for (size_t i = 0; i < n; ++i) {
        path_start(t, px[i], py[i], &ps[i]);
        st->paths++;
        live[nlive++] = i;
    }
    /* Every round takes each live path to its next question, answers them all, and finishes
     * the vertices that asked. */
    while (nlive > 0) {
        size_t nask = 0;
        for (size_t k = 0; k < nlive; ++k) {
            size_t i = live[k];
            if (advance_to_question(t, &ps[i], &r[i], st, pr ? &pr[i] : NULL, &vp[i], &v[i],
                                    &vx[i])) {
                live[nask] = i;
                asking[nask++] = &vp[i];
            }
        }
        answer_batch(t, asking, nask, scratch, st);
        nlive = 0;
        for (size_t k = 0; k < nask; ++k) {
            size_t i = live[k];
            if (vertex_finish(t, &ps[i], &vp[i], v[i], vx[i]))
                live[nlive++] = i;
        }
    }
    for (size_t i = 0; i < n; ++i) {
        out[i] = ps[i].L;
        if (moment)
            path_moments(&ps[i], &moment[PATH_MOMENTS * i]);
        if (pr) /* in path order, as n calls of trace_path append them */
            recorder_close(t, &pr[i], film_pixel(t->s, px[i], py[i]), records, st);
    }
}
