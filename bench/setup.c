/*
 * setup.c - what a preset's cases run on (see setup.h), prepared outside any timing.
 *
 * The model has randomized parameters (nf_model_get_params + uniform noise + nf_model_set_params) so
 * every spline is a real, non-identity spline; the cosine prior is the default. The inputs
 * are a fixed pseudo-random pool, the same in every run, so that runs compare.
 *
 * At start-up the sharded gradient that the multi-threaded training uses is checked against
 * the whole batch's, and the shading-point results against nf_sample / nf_pdf, which they
 * must equal bit for bit: a figure is only worth having for calls that compute the right
 * thing.
 */
#include "setup.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "gradient.h"
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

#define NFB_PARAM_NOISE 0.1f /* half-width of the uniform noise added to parameters */

/* ---- The inputs -------------------------------------------------------------------------- */

void bench_data_free(bench_data *d)
{
    free(d->ctx);
    free(d->u);
    free(d->dir);
    free(d->light_dir);
    free(d->weight);
    free(d->out_dir);
    free(d->out_pdf);
    free(d->out_pdf2);
    free(d->points);
    free(d->tables);
    free(d->walls);
    memset(d, 0, sizeof *d);
}

size_t bench_data_bytes(const bench_data *d)
{
    /* 14 floats an input: u 2, dir 3, light_dir 3, weight 1, out_dir 3, out_pdf 1, out_pdf2 1;
     * and a wall context */
    return d->n * (2 * sizeof(nf_context) + 14 * sizeof(float)) +
           NFB_POINT_RING * (sizeof(nf_shading_point) + sizeof(nf_direction_table));
}

int bench_data_alloc(bench_data *d, size_t n, const nf_config *cfg)
{
    memset(d, 0, sizeof *d);
    d->n = n;
    d->ctx = (nf_context *)malloc(n * sizeof *d->ctx);
    d->u = (float *)malloc(2 * n * sizeof(float));
    d->dir = (float *)malloc(3 * n * sizeof(float));
    d->light_dir = (float *)malloc(3 * n * sizeof(float));
    d->weight = (float *)malloc(n * sizeof(float));
    d->out_dir = (float *)malloc(3 * n * sizeof(float));
    d->out_pdf = (float *)malloc(n * sizeof(float));
    d->out_pdf2 = (float *)malloc(n * sizeof(float));
    /* 64-byte aligned, as point.h advises; aligned_alloc needs a multiple of 64 bytes. */
    d->points = (nf_shading_point *)aligned_alloc(
        64, (NFB_POINT_RING * sizeof *d->points + 63u) / 64u * 64u);
    d->tables = (nf_direction_table *)aligned_alloc(
        64, (NFB_POINT_RING * sizeof *d->tables + 63u) / 64u * 64u);
    d->walls = (nf_context *)malloc(n * sizeof *d->walls);
    if (!d->ctx || !d->u || !d->dir || !d->light_dir || !d->weight || !d->out_dir ||
        !d->out_pdf || !d->out_pdf2 || !d->points || !d->tables || !d->walls) {
        bench_data_free(d);
        return -1;
    }
    uint64_t rng = 0x5EEDF00Du;
    for (size_t i = 0; i < n; ++i) {
        nf_context *c = &d->ctx[i];
        for (int a = 0; a < 3; ++a) {
            float lo = cfg->bounds_min[a], hi = cfg->bounds_max[a];
            c->position[a] = lo + (hi - lo) * rng_float(&rng);
        }
        rng_unit_vector(&rng, c->normal);
        rng_unit_vector(&rng, c->wo);
        float cosine = c->normal[0] * c->wo[0] + c->normal[1] * c->wo[1] +
                       c->normal[2] * c->wo[2];
        if (cosine < 0.0f) /* wo on the normal's side, as at a real shading point */
            for (int a = 0; a < 3; ++a)
                c->wo[a] = -c->wo[a];
        d->u[2 * i] = rng_float(&rng);
        d->u[2 * i + 1] = rng_float(&rng);
        d->weight[i] = 0.05f + 2.0f * rng_float(&rng);
    }
    /* A stream of its own, so that the inputs above (and the figures of the batched ops) are
     * those of earlier versions of this program. */
    uint64_t rng_light = 0x11647D1Bu;
    for (size_t i = 0; i < n; ++i)
        rng_unit_vector(&rng_light, d->light_dir + 3 * i);
    /* The walls of a box, the bounds' faces: a renderer's surfaces, 6 x 16 x 16 cells of the
     * cache's default grid, each context on a face at a uniform point, its normal inward. */
    uint64_t rng_walls = 0x3A115u;
    for (size_t i = 0; i < n; ++i) {
        nf_context *c = &d->walls[i];
        memset(c, 0, sizeof *c);
        const int axis = (int)(rng_float(&rng_walls) * 3.0f) % 3;
        const int far = rng_float(&rng_walls) < 0.5f;
        for (int a = 0; a < 3; ++a) {
            float lo = cfg->bounds_min[a], hi = cfg->bounds_max[a];
            c->position[a] = a == axis ? (far ? hi : lo) : lo + (hi - lo) * rng_float(&rng_walls);
        }
        c->normal[axis] = c->wo[axis] = far ? -1.0f : 1.0f;
    }
    return 0;
}

/* The model is not changed by the cases (training uses a clone), so the ring prepared once
 * per preset stays valid for all of them. */
int prepare_ring(const nf_model *m, bench_data *d)
{
    for (size_t i = 0; i < NFB_POINT_RING; ++i)
        if (report_status(nf_point_prepare(m, d->ctx + i, NULL, &d->points[i]),
                          "nf_point_prepare") != 0 ||
            report_status(nf_table_build(m, &d->points[i], &d->tables[i]), "nf_table_build") != 0)
            return -1;
    return 0;
}

/* ---- A custom prior for --prior custom: a cosine lobe through the callbacks -------------- */

static float custom_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    (void)user;
    float n[3] = {ctx->normal[0], ctx->normal[1], ctx->normal[2]};
    float len = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    n[0] /= len;
    n[1] /= len;
    n[2] /= len;
    /* Duff et al. 2017 orthonormal basis. */
    float sign = copysignf(1.0f, n[2]);
    float a = -1.0f / (sign + n[2]);
    float b = n[0] * n[1] * a;
    float t[3] = {1.0f + sign * n[0] * n[0] * a, sign * b, -sign * n[0]};
    float s[3] = {b, sign + n[1] * n[1] * a, -n[1]};
    float r = sqrtf(u0), phi = 2.0f * NFB_PI * u1;
    float z = sqrtf(fmaxf(1.0f - u0, 1e-6f));
    float x = r * cosf(phi), y = r * sinf(phi);
    for (int i = 0; i < 3; ++i)
        dir[i] = x * t[i] + y * s[i] + z * n[i];
    return z / NFB_PI;
}

static float custom_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    (void)user;
    const float *n = ctx->normal;
    float nn = sqrtf(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    float dd = sqrtf(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    float c = (n[0] * dir[0] + n[1] * dir[1] + n[2] * dir[2]) / (nn * dd);
    return c > 0.0f ? c / NFB_PI : 0.0f;
}

/* ---- The model --------------------------------------------------------------------------- */

/* Multiply-adds of the conditioner MLPs, times 2. Per coupling layer: input layer
 * in * H (in = 3 + 9 one-blob non-zeros + 2 S^2 SH values exploiting sparsity, or the dense
 * 4 B + 2 S^2), hidden layers H^2 each, output layer H (3K + 1). Biases, activations,
 * encodings and splines are not counted. *context is the share of *sparse that depends on
 * the context alone (the input rows of the position's one-blobs and the SH values), which
 * nf_point_prepare does once per point; the rest is done per direction. */
static void model_flops(const nf_config *cfg, double *sparse, double *dense, double *context)
{
    double h = cfg->hidden_width, s2 = (double)cfg->sh_bands * cfg->sh_bands;
    double blob_nz = cfg->oneblob_bins < 3 ? cfg->oneblob_bins : 3;
    double in_sparse = 4.0 * blob_nz + 2.0 * s2;
    double in_dense = 4.0 * cfg->oneblob_bins + 2.0 * s2;
    double rest = (cfg->hidden_layers - 1.0) * h * h + h * (3.0 * cfg->spline_bins + 1.0);
    *sparse = 2.0 * cfg->coupling_layers * (in_sparse * h + rest);
    *dense = 2.0 * cfg->coupling_layers * (in_dense * h + rest);
    *context = 2.0 * cfg->coupling_layers * (3.0 * blob_nz + 2.0 * s2) * h;
}

/* Training is counted as 3 forward passes (forward, and the backward pass's two products per
 * layer); the shading-point ops split the forward pass at the context's share. */
double flops_per_sample(const preset_info *pi, int op)
{
    double direction = pi->flops_sparse - pi->flops_context;
    switch (op) {
    case OP_TRAIN:
    case OP_GUIDE:
        return 3.0 * pi->flops_sparse;
    case OP_PREPARE:
        return pi->flops_context;
    case OP_POINT_SAMPLE:
    case OP_POINT_PDF:
        return direction;
    case OP_VERTEX:
    case OP_VERTEX_CALLS:
        return pi->flops_context + 2.0 * direction;
    case OP_TABLE_BUILD: /* a density per cell: the flow's arithmetic, the table's aside */
        return NF_TABLE_CELLS * direction;
    case OP_TABLE_VERTEX: /* no network */
    case OP_TABLE_FIND:
    case OP_CELL_VERTEX:
        return 0.0;
    default:
        return pi->flops_sparse;
    }
}

int report_status(nf_status st, const char *fn)
{
    if (st == NF_OK)
        return 0;
    fprintf(stderr, "nf_bench: %s failed: %s: %s\n", fn, nf_status_string(st),
            nf_last_error_message());
    return -1;
}

int make_model(int preset, const options *o, counting_allocator *ca, preset_info *info,
               nf_model **out)
{
    *out = NULL;
    nf_config cfg;
    nf_config_init(&cfg, preset == 0 ? NF_PRESET_SMALL : NF_PRESET_LARGE);
    cfg.prior = o->prior;
    cfg.phi_map = o->phi_map;
    cfg.isa = o->isa;
    if (o->prior == NF_PRIOR_CUSTOM) {
        cfg.custom_prior.sample = custom_sample;
        cfg.custom_prior.pdf = custom_pdf;
        cfg.custom_prior.user = NULL;
    }
    cfg.allocator.alloc = counting_alloc;
    cfg.allocator.free = counting_free;
    cfg.allocator.user = ca;
    size_t before = atomic_load(&ca->live);
    nf_model *m = NULL;
    if (report_status(nf_model_create(&cfg, &m), "nf_model_create") != 0)
        return -1;
    size_t p = nf_model_param_count(m);
    float *params = (float *)malloc(p * sizeof(float));
    if (!params) {
        fprintf(stderr, "nf_bench: out of memory\n");
        nf_model_destroy(m);
        return -1;
    }
    uint64_t rng = 0xC0FFEEu + (uint64_t)preset;
    int bad = report_status(nf_model_get_params(m, params), "nf_model_get_params");
    if (!bad) {
        for (size_t i = 0; i < p; ++i)
            params[i] += NFB_PARAM_NOISE * (2.0f * rng_float(&rng) - 1.0f);
        bad = report_status(nf_model_set_params(m, params), "nf_model_set_params");
    }
    free(params);
    if (bad) {
        nf_model_destroy(m);
        return -1;
    }
    info->name = PRESET_NAME[preset];
    info->params = p;
    info->model_bytes = atomic_load(&ca->live) - before;
    info->isa = nf_model_isa_name(m);
    info->cfg = cfg;
    model_flops(&cfg, &info->flops_sparse, &info->flops_dense, &info->flops_context);
    *out = m;
    return 0;
}

/* ---- Start-up checks --------------------------------------------------------------------- */

/* In real numbers the combination equals the whole batch's gradient exactly; in floats the
 * two differ by rounding, so the figure should be near float precision (main warns above
 * 1e-4). */
int check_sharding(const nf_model *m, const bench_data *d, size_t n, size_t p, double *rel)
{
    float *g = (float *)malloc(3 * p * sizeof(float));
    if (!g) {
        fprintf(stderr, "nf_bench: out of memory\n");
        return -1;
    }
    float *g1 = g + p, *g2 = g + 2 * p;
    size_t h = n / 2;
    double f1 = 0.0, f2 = 0.0;
    for (size_t i = 0; i < h; ++i)
        f1 += d->weight[i];
    for (size_t i = h; i < n; ++i)
        f2 += d->weight[i];
    int bad = report_status(nf_loss_gradient(m, n, d->ctx, d->dir, d->weight, NULL, g),
                            "nf_loss_gradient") ||
              report_status(nf_loss_gradient(m, h, d->ctx, d->dir, d->weight, NULL, g1),
                            "nf_loss_gradient") ||
              report_status(nf_loss_gradient(m, n - h, d->ctx + h, d->dir + 3 * h,
                                             d->weight + h, NULL, g2),
                            "nf_loss_gradient");
    if (!bad) {
        double num = 0.0, den = 0.0;
        for (size_t i = 0; i < p; ++i) {
            double c = (f1 * g1[i] + f2 * g2[i]) / (f1 + f2);
            num = fmax(num, fabs(c - g[i]));
            den = fmax(den, fabs((double)g[i]));
        }
        *rel = den > 0.0 ? num / den : num;
    }
    free(g);
    return bad ? -1 : 0;
}

/* Compared with memcmp, not ==, so that a difference in the last bit, or in a NaN, counts. */
int check_points(const nf_model *m, bench_data *d, size_t n, size_t *mismatches, double *worst)
{
    *mismatches = 0;
    *worst = 0.0;
    if (report_status(nf_pdf(m, n, d->ctx, d->light_dir, d->out_pdf2), "nf_pdf") != 0)
        return -1;
    _Alignas(64) nf_shading_point sp;
    for (size_t i = 0; i < n; ++i) {
        float dir[3], pdf, pdf2;
        if (report_status(nf_point_prepare(m, d->ctx + i, NULL, &sp), "nf_point_prepare") ||
            report_status(nf_point_sample(m, &sp, 1, d->u + 2 * i, dir, &pdf),
                          "nf_point_sample") ||
            report_status(nf_point_pdf(m, &sp, 1, d->light_dir + 3 * i, &pdf2),
                          "nf_point_pdf"))
            return -1;
        if (memcmp(dir, d->dir + 3 * i, sizeof dir) != 0 ||
            memcmp(&pdf, d->out_pdf + i, sizeof pdf) != 0 ||
            memcmp(&pdf2, d->out_pdf2 + i, sizeof pdf2) != 0)
            ++*mismatches;
        double a = fabs((double)pdf - d->out_pdf[i]) / d->out_pdf[i];
        double b = fabs((double)pdf2 - d->out_pdf2[i]) / d->out_pdf2[i];
        *worst = fmax(*worst, fmax(a, b));
    }
    return 0;
}
