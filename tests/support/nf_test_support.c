/*
 * nf_test_support.c - see nf_test_support.h.
 */
#include "nf_test_support.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "point_batch.h"
#include "direction_table.h"
#include "shading_point.h"

/* ---- PCG32 -------------------------------------------------------------------------------- */

void nft_rng_seed(nft_rng *r, uint64_t seed, uint64_t stream)
{
    r->state = 0u;
    r->inc = (stream << 1u) | 1u;
    (void)nft_rng_u32(r);
    r->state += seed;
    (void)nft_rng_u32(r);
}

uint32_t nft_rng_u32(nft_rng *r)
{
    uint64_t old = r->state;
    r->state = old * 6364136223846793005ULL + r->inc;
    uint32_t xorshifted = (uint32_t)(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = (uint32_t)(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((32u - rot) & 31u));
}

float nft_rng_float(nft_rng *r)
{
    return (float)(nft_rng_u32(r) >> 8) * (1.0f / 16777216.0f);
}

double nft_rng_double(nft_rng *r)
{
    uint64_t hi = nft_rng_u32(r);
    uint64_t lo = nft_rng_u32(r);
    return (double)(((hi << 32) | lo) >> 11) * (1.0 / 9007199254740992.0);
}

static void store_normalized(const double v[3], float out[3])
{
    double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int k = 0; k < 3; ++k)
        out[k] = (float)(v[k] / len);
}

void nft_random_unit_vector(nft_rng *r, float v[3])
{
    double z = 1.0 - 2.0 * nft_rng_double(r);
    double s = sqrt(fmax(0.0, 1.0 - z * z));
    double phi = 2.0 * NFT_PI * nft_rng_double(r);
    double d[3] = {s * cos(phi), s * sin(phi), z};
    store_normalized(d, v);
}

void nft_random_context(nft_rng *r, nf_context *ctx)
{
    for (int k = 0; k < 3; ++k)
        ctx->position[k] = nft_rng_float(r);
    nft_random_unit_vector(r, ctx->normal);
    nft_random_unit_vector(r, ctx->wo);
    float d = ctx->normal[0] * ctx->wo[0] + ctx->normal[1] * ctx->wo[1] +
              ctx->normal[2] * ctx->wo[2];
    if (d < 0.0f)
        for (int k = 0; k < 3; ++k)
            ctx->wo[k] = -ctx->wo[k];
}

void nft_random_queries(nft_rng *r, size_t n, nf_context *ctx, float *u)
{
    for (size_t i = 0; i < n; ++i) {
        nft_random_context(r, &ctx[i]);
        u[2 * i] = nft_rng_float(r);
        u[2 * i + 1] = nft_rng_float(r);
    }
}

void nft_random_batch(nft_rng *r, size_t n, nf_context *ctx, float *u, float *dir, float *weight,
                      float weight_min)
{
    for (size_t i = 0; i < n; ++i) {
        nft_random_context(r, &ctx[i]);
        if (u) {
            u[2 * i] = nft_rng_float(r);
            u[2 * i + 1] = nft_rng_float(r);
        }
        nft_random_unit_vector(r, dir + 3 * i);
        weight[i] = weight_min + nft_rng_float(r);
    }
}

void nft_random_u_dir(nft_rng *r, size_t n, float *u, float *dir)
{
    for (size_t i = 0; i < n; ++i) {
        u[2 * i] = nft_rng_float(r);
        u[2 * i + 1] = nft_rng_float(r);
        nft_random_unit_vector(r, dir + 3 * i);
    }
}

void nft_random_samples(nft_rng *r, size_t n, nf_context *ctx, float *dir, float *weight,
                        float weight_min)
{
    nft_random_batch(r, n, ctx, NULL, dir, weight, weight_min);
}

nf_context nft_context(float px, float py, float pz, float nx, float ny, float nz, float wx,
                       float wy, float wz)
{
    nf_context c;
    c.position[0] = px;
    c.position[1] = py;
    c.position[2] = pz;
    double n[3] = {nx, ny, nz};
    double w[3] = {wx, wy, wz};
    store_normalized(n, c.normal);
    store_normalized(w, c.wo);
    return c;
}

/* ---- vectors ------------------------------------------------------------------------------ */

double nft_dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void to_unit_double(const float v[3], double out[3])
{
    double len = nft_length3f(v);
    for (int k = 0; k < 3; ++k)
        out[k] = (double)v[k] / len;
}

void nft_direction_angles(const float dir[3], double *theta, double *phi)
{
    double x = dir[0], y = dir[1], z = dir[2];
    *theta = atan2(hypot(x, y), z);
    double p = atan2(y, x);
    if (p < 0.0)
        p += 2.0 * NFT_PI;
    if (p >= 2.0 * NFT_PI)
        p -= 2.0 * NFT_PI;
    *phi = p;
}

double nft_sin_theta(const float dir[3])
{
    return hypot((double)dir[0], (double)dir[1]) / nft_length3f(dir);
}

double nft_length3f(const float v[3])
{
    double x = v[0], y = v[1], z = v[2];
    return sqrt(x * x + y * y + z * z);
}

void nft_frame(const double axis[3], double t[3], double b[3], double n[3])
{
    double len = sqrt(nft_dot3(axis, axis));
    for (int k = 0; k < 3; ++k)
        n[k] = axis[k] / len;
    /* Duff et al. 2017, in double. */
    double sign = n[2] >= 0.0 ? 1.0 : -1.0;
    double a = -1.0 / (sign + n[2]);
    double bb = n[0] * n[1] * a;
    t[0] = 1.0 + sign * n[0] * n[0] * a;
    t[1] = sign * bb;
    t[2] = -sign * n[0];
    b[0] = bb;
    b[1] = sign + n[1] * n[1] * a;
    b[2] = -n[1];
}

/* ---- the Phong prior ------------------------------------------------------------------------ */

static float nft_phong_exponent_value = NFT_PHONG_EXPONENT;

/* The lobe axis: the mirror direction of wo about the normal, in double; at a point in a
 * medium (zero normal) the propagation direction -wo, a forward-scattering lobe. */
static void phong_axis(const nf_context *ctx, double axis[3])
{
    double n[3], wo[3];
    to_unit_double(ctx->wo, wo);
    if (ctx->normal[0] == 0.0f && ctx->normal[1] == 0.0f && ctx->normal[2] == 0.0f) {
        for (int k = 0; k < 3; ++k)
            axis[k] = -wo[k];
        return;
    }
    to_unit_double(ctx->normal, n);
    double d = nft_dot3(n, wo);
    for (int k = 0; k < 3; ++k)
        axis[k] = 2.0 * d * n[k] - wo[k];
    double len = sqrt(nft_dot3(axis, axis));
    for (int k = 0; k < 3; ++k)
        axis[k] /= len;
}

double nft_phong_cosine(const nf_context *ctx, const float dir[3])
{
    double axis[3], w[3];
    phong_axis(ctx, axis);
    to_unit_double(dir, w);
    return nft_dot3(axis, w);
}

static double phong_density(double e, const nf_context *ctx, const float dir[3])
{
    double c = nft_phong_cosine(ctx, dir);
    if (!(c > 0.0))
        return 0.0;
    return (e + 1.0) / (2.0 * NFT_PI) * pow(c, e);
}

float nft_phong_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    double e = *(const float *)user;
    return (float)phong_density(e, ctx, dir);
}

float nft_phong_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3])
{
    double e = *(const float *)user;
    double axis[3], t[3], b[3], n[3];
    phong_axis(ctx, axis);
    nft_frame(axis, t, b, n);
    /* 1 - u0 lies in (0, 1] for u0 in [0, 1); the floor keeps the density clearly > 0 (the
     * library refuses a sampler density <= 0) at a cost of probability 1e-3^(e+1), nil. */
    double c = pow(fmin(fmax(1.0 - (double)u0, 0.0), 1.0), 1.0 / (e + 1.0));
    c = fmin(fmax(c, 1e-3), 1.0);
    double s = sqrt(fmax(0.0, 1.0 - c * c));
    double phi = 2.0 * NFT_PI * (double)u1;
    double w[3];
    for (int k = 0; k < 3; ++k)
        w[k] = s * cos(phi) * t[k] + s * sin(phi) * b[k] + c * n[k];
    store_normalized(w, dir);
    return nft_phong_pdf(user, ctx, dir);
}

nf_prior_callbacks nft_phong_callbacks(void)
{
    nf_prior_callbacks cb;
    cb.sample = nft_phong_sample;
    cb.pdf = nft_phong_pdf;
    cb.user = &nft_phong_exponent_value;
    return cb;
}

/* ---- models ----------------------------------------------------------------------------------- */

nf_phi_map nft_phi_map(void)
{
    const char *v = getenv("NF_TEST_PHI_MAP");
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    if (v && !strcmp(v, "interval"))
        return NF_PHI_INTERVAL;
    if (v && !strcmp(v, "circular"))
        return NF_PHI_CIRCULAR;
    return cfg.phi_map;
}

void nft_apply_phi_map(nf_config *cfg) { cfg->phi_map = nft_phi_map(); }

const char *nft_phi_map_name(nf_phi_map map)
{
    return map == NF_PHI_INTERVAL ? "interval" : map == NF_PHI_CIRCULAR ? "circular" : "?";
}

nf_config nft_config(nf_preset preset, nf_prior_kind prior)
{
    nf_config cfg;
    memset(&cfg, 0, sizeof cfg);
    nf_config_init(&cfg, preset);
    nft_apply_phi_map(&cfg);
    cfg.prior = prior;
    if (prior == NF_PRIOR_CUSTOM)
        cfg.custom_prior = nft_phong_callbacks();
    return cfg;
}

float nft_prior_pdf(const nf_model *m, const nf_context *ctx, const float dir[3])
{
    float q = -1.0f;
    return nf_model_prior_pdf(m, ctx, dir, &q) == NF_OK ? q : -1.0f;
}

nf_guide_config nft_guide_config(size_t store_capacity, uint32_t step_samples,
                                 uint32_t steps_per_pass)
{
    nf_guide_config gc;
    nf_guide_config_init(&gc);
    gc.store_capacity = store_capacity;
    gc.step_samples = step_samples;
    gc.steps_per_pass = steps_per_pass;
    return gc;
}

void nft_config_largest(nf_config *cfg)
{
    cfg->coupling_layers = NF_MAX_COUPLING_LAYERS;
    cfg->spline_bins = NF_MAX_SPLINE_BINS;
    cfg->hidden_layers = NF_MAX_HIDDEN_LAYERS;
    cfg->hidden_width = NF_MAX_HIDDEN_WIDTH;
    cfg->oneblob_bins = NF_MAX_ONEBLOB_BINS;
    cfg->sh_bands = NF_MAX_SH_BANDS;
}

nf_model *nft_model_from(const nf_config *cfg)
{
    nf_model *m = NULL;
    /* Every caller needs the model: fail the running test here, with the library's reason,
     * rather than at each call site. */
    if (nf_model_create(cfg, &m) != NF_OK)
        fail_msg("nf_model_create: %s", nf_last_error_message());
    return m;
}

nf_model *nft_make_model(nf_preset preset, nf_prior_kind prior)
{
    nf_config cfg = nft_config(preset, prior);
    return nft_model_from(&cfg);
}

nf_model *nft_random_model(void)
{
    nf_model *m = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    if (nft_randomize_params(m, 0.5f, 11u) != NF_OK)
        fail_msg("nft_randomize_params: %s", nf_last_error_message());
    return m;
}

nf_direction_table nft_table_at(const nf_model *m, const nf_context *ctx)
{
    nf_shading_point p;
    nf_direction_table t;
    memset(&t, 0, sizeof t); /* cmocka's fail_msg is not declared noreturn */
    if (nf_point_prepare(m, ctx, NULL, &p) != NF_OK || nf_table_build(m, &p, &t) != NF_OK)
        fail_msg("nft_table_at: %s", nf_last_error_message());
    return t;
}

void nft_random_point(const nf_model *m, nft_rng *r, nf_context *ctx, nf_shading_point *p)
{
    nft_random_context(r, ctx);
    if (nf_point_prepare(m, ctx, NULL, p) != NF_OK)
        fail_msg("nft_random_point: %s", nf_last_error_message());
}

nf_table_cache_stats nft_cache_stats(const nf_table_cache *c)
{
    nf_table_cache_stats s;
    memset(&s, 0, sizeof s); /* cmocka's fail_msg is not declared noreturn */
    if (nf_table_cache_get_stats(c, &s) != NF_OK)
        fail_msg("nft_cache_stats: %s", nf_last_error_message());
    return s;
}

int nft_setup_model(void **state)
{
    *state = nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE);
    return 0;
}

int nft_teardown_model(void **state)
{
    nf_model_destroy(*state);
    *state = NULL;
    return 0;
}

nf_status nft_randomize_params(nf_model *m, float scale, uint64_t seed)
{
    size_t count = nf_model_param_count(m);
    float *p = malloc((count ? count : 1u) * sizeof *p);
    if (!p)
        return NF_ERROR_OUT_OF_MEMORY;
    nft_rng r;
    nft_rng_seed(&r, seed, 0x5eedu);
    for (size_t i = 0; i < count; ++i)
        p[i] = scale * (2.0f * nft_rng_float(&r) - 1.0f);
    nf_status st = nf_model_set_params(m, p);
    free(p);
    return st;
}

nf_status nft_perturb_params(nf_model *m, double scale, int gaussian, uint64_t seed,
                             uint64_t stream)
{
    size_t count = nf_model_param_count(m);
    float *p = malloc((count ? count : 1u) * sizeof *p);
    if (!p)
        return NF_ERROR_OUT_OF_MEMORY;
    nf_status st = nf_model_get_params(m, p);
    nft_rng r;
    nft_rng_seed(&r, seed, stream);
    for (size_t i = 0; st == NF_OK && i < count; ++i) {
        if (gaussian) {
            double u1 = 1.0 - nft_rng_double(&r), u2 = nft_rng_double(&r);
            p[i] += (float)(scale * (sqrt(-2.0 * log(u1)) * cos(2.0 * NFT_PI * u2)));
        } else {
            p[i] += (float)scale * (2.0f * nft_rng_float(&r) - 1.0f);
        }
    }
    if (st == NF_OK)
        st = nf_model_set_params(m, p);
    free(p);
    return st;
}

const char *nft_prior_name(nf_prior_kind prior)
{
    switch (prior) {
    case NF_PRIOR_UNIFORM_DIRECTION: return "uniform_direction";
    case NF_PRIOR_UNIFORM_ANGLE: return "uniform_angle";
    case NF_PRIOR_COSINE: return "cosine";
    case NF_PRIOR_CUSTOM: return "custom";
    }
    return "unknown";
}

double nft_prior_density(nf_prior_kind prior, float eps, const nf_context *ctx,
                         const float dir[3])
{
    const double uniform = 1.0 / (4.0 * NFT_PI);
    double e = eps;
    switch (prior) {
    case NF_PRIOR_UNIFORM_DIRECTION:
        return uniform;
    case NF_PRIOR_UNIFORM_ANGLE: {
        double s = fmax(nft_sin_theta(dir), (double)NF_SIN_THETA_MIN);
        return 1.0 / (2.0 * NFT_PI * NFT_PI * s);
    }
    case NF_PRIOR_COSINE: {
        double n[3], w[3];
        to_unit_double(dir, w);
        if (ctx->normal[0] == 0.0f && ctx->normal[1] == 0.0f && ctx->normal[2] == 0.0f) {
            /* a point in a medium: Henyey-Greenstein around d = -wo (docs/theory.md 2.4) */
            double wo[3], g = ctx->phase_g;
            to_unit_double(ctx->wo, wo);
            double base = 1.0 + g * g + 2.0 * g * nft_dot3(wo, w); /* -2 g d.w, d = -wo */
            return (1.0 - e) * (1.0 - g * g) / (4.0 * NFT_PI * base * sqrt(base)) + e * uniform;
        }
        to_unit_double(ctx->normal, n);
        return (1.0 - e) * fmax(0.0, nft_dot3(n, w)) / NFT_PI + e * uniform;
    }
    case NF_PRIOR_CUSTOM:
        return (1.0 - e) * phong_density(NFT_PHONG_EXPONENT, ctx, dir) + e * uniform;
    }
    return NAN;
}

/* ---- callbacks over a model ---------------------------------------------------------------- */

int nft_model_fn_init(nft_model_fn *f, const nf_model *m, const nf_context *ctx)
{
    f->model = m;
    f->last = NF_OK;
    f->ctx = malloc(NFT_BATCH * sizeof *f->ctx);
    if (!f->ctx)
        return -1;
    for (size_t i = 0; i < NFT_BATCH; ++i)
        f->ctx[i] = *ctx;
    return 0;
}

void nft_model_fn_free(nft_model_fn *f)
{
    free(f->ctx);
    f->ctx = NULL;
}

int nft_model_pdf(void *user, size_t n, const float *dir, float *pdf)
{
    nft_model_fn *f = user;
    if (n > NFT_BATCH)
        return -1;
    f->last = nf_pdf(f->model, n, f->ctx, dir, pdf);
    return f->last == NF_OK ? 0 : -1;
}

int nft_model_sample(void *user, size_t n, const float *u, float *dir)
{
    nft_model_fn *f = user;
    if (n > NFT_BATCH)
        return -1;
    f->last = nf_sample(f->model, n, f->ctx, u, dir, NULL);
    return f->last == NF_OK ? 0 : -1;
}

/* ---- quadrature ---------------------------------------------------------------------------- */

/* The direction of grid angles (theta, phi) in the frame (NULL = world), as floats. */
static void grid_direction(double st, double ct, double phi, const double frame[3][3],
                           float out[3])
{
    double l[3] = {st * cos(phi), st * sin(phi), ct};
    if (!frame) {
        for (int k = 0; k < 3; ++k)
            out[k] = (float)l[k];
        return;
    }
    for (int k = 0; k < 3; ++k)
        out[k] = (float)(l[0] * frame[0][k] + l[1] * frame[1][k] + l[2] * frame[2][k]);
}

double nft_integrate_sphere(nft_pdf_fn pdf, void *user, uint32_t theta_res, uint32_t phi_res,
                            const double frame[3][3])
{
    const double dt = NFT_PI / theta_res, dp = 2.0 * NFT_PI / phi_res;
    float *dir = malloc(3u * NFT_BATCH * sizeof *dir);
    float *val = malloc(NFT_BATCH * sizeof *val);
    double total = 0.0;
    if (!dir || !val) {
        total = NAN;
        goto done;
    }
    for (uint32_t i = 0; i < theta_res; ++i) {
        double t = (i + 0.5) * dt, st = sin(t), ct = cos(t);
        double row = 0.0;
        for (uint32_t j0 = 0; j0 < phi_res; j0 += NFT_BATCH) {
            uint32_t count = phi_res - j0 < NFT_BATCH ? phi_res - j0 : NFT_BATCH;
            for (uint32_t j = 0; j < count; ++j)
                grid_direction(st, ct, (j0 + j + 0.5) * dp, frame, dir + 3u * j);
            if (pdf(user, count, dir, val) != 0) {
                total = NAN;
                goto done;
            }
            for (uint32_t j = 0; j < count; ++j) {
                if (!(val[j] >= 0.0f) || !isfinite(val[j])) {
                    total = NAN;
                    goto done;
                }
                row += val[j];
            }
        }
        total += row * st * dt * dp;
    }
done:
    free(dir);
    free(val);
    return total;
}

/* ---- chi-square ------------------------------------------------------------------------------ */

/* P(a, x) by its series, for x < a + 1. */
static double gamma_p_series(double a, double x)
{
    double ap = a, del = 1.0 / a, sum = del;
    for (int n = 0; n < 100000; ++n) {
        ap += 1.0;
        del *= x / ap;
        sum += del;
        if (fabs(del) < fabs(sum) * 1e-16)
            break;
    }
    return sum * exp(-x + a * log(x) - lgamma(a));
}

/* Q(a, x) by its continued fraction (modified Lentz), for x >= a + 1. */
static double gamma_q_fraction(double a, double x)
{
    const double tiny = 1e-300;
    double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
    for (int i = 1; i < 100000; ++i) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < tiny)
            d = tiny;
        c = b + an / c;
        if (fabs(c) < tiny)
            c = tiny;
        d = 1.0 / d;
        double del = d * c;
        h *= del;
        if (fabs(del - 1.0) < 1e-16)
            break;
    }
    return exp(-x + a * log(x) - lgamma(a)) * h;
}

double nft_gamma_q(double a, double x)
{
    if (!(a > 0.0) || !(x >= 0.0) || !isfinite(a))
        return NAN;
    if (x == 0.0)
        return 1.0;
    if (isinf(x))
        return 0.0;
    if (x < a + 1.0)
        return 1.0 - gamma_p_series(a, x);
    return gamma_q_fraction(a, x);
}

nft_chi2_params nft_chi2_defaults(const char *name)
{
    return (nft_chi2_params){.name = name, .theta_res = 16, .phi_res = 32, .subdiv = 8,
                             .sample_count = 100000, .seed = 1, .significance = 0.01,
                             .run_count = 1, .min_expected = 5.0, .integral_tolerance = 1e-2,
                             .dump_on_failure = 1};
}

typedef struct chi2_cell {
    double expected;
    double observed;
} chi2_cell;

static int compare_cells(const void *a, const void *b)
{
    double x = ((const chi2_cell *)a)->expected, y = ((const chi2_cell *)b)->expected;
    return (x > y) - (x < y);
}

static void dump_table(FILE *f, const char *title, const double *v, uint32_t rows,
                       uint32_t cols, int decimals)
{
    fprintf(f, "%s (rows: theta cells 0..%u, columns: phi cells 0..%u)\n", title, rows - 1u,
            cols - 1u);
    for (uint32_t i = 0; i < rows; ++i) {
        for (uint32_t j = 0; j < cols; ++j)
            fprintf(f, "%s%.*f", j ? " " : "", decimals, v[(size_t)i * cols + j]);
        fputc('\n', f);
    }
    fputc('\n', f);
}

/* Writes the tables to chi2_<name>.txt; returns the file name in `file` (or "" on error). */
static void dump_tables(const nft_chi2_params *p, const double *obs, const double *expv,
                        const char *why, char *file, size_t file_size)
{
    char clean[128];
    size_t k = 0;
    for (const char *c = p->name ? p->name : "unnamed"; *c && k + 1 < sizeof clean; ++c) {
        int ok = (*c >= 'a' && *c <= 'z') || (*c >= 'A' && *c <= 'Z') ||
                 (*c >= '0' && *c <= '9') || *c == '-' || *c == '_';
        clean[k++] = ok ? *c : '_';
    }
    clean[k] = '\0';
    snprintf(file, file_size, "chi2_%s.txt", clean);
    FILE *f = fopen(file, "w");
    if (!f) {
        file[0] = '\0';
        return;
    }
    fprintf(f, "chi-square test '%s' failed: %s\n", p->name ? p->name : "", why);
    fprintf(f, "samples %zu, seed %llu, grid %u x %u, %u x %u quadrature points per cell\n\n",
            p->sample_count, (unsigned long long)p->seed, p->theta_res, p->phi_res, p->subdiv,
            p->subdiv);
    dump_table(f, "observed", obs, p->theta_res, p->phi_res, 0);
    dump_table(f, "expected", expv, p->theta_res, p->phi_res, 2);
    fclose(f);
}

int nft_chi2_test(const nft_chi2_params *p, nft_sample_fn sample, nft_pdf_fn pdf, void *user,
                  nft_chi2_result *r)
{
    const uint32_t T = p->theta_res, P = p->phi_res, S = p->subdiv;
    const size_t cells = (size_t)T * P;
    const size_t N = p->sample_count;
    double *obs = calloc(cells, sizeof *obs);
    double *expv = calloc(cells, sizeof *expv);
    chi2_cell *sorted = calloc(cells, sizeof *sorted);
    float *u = malloc(2u * NFT_BATCH * sizeof *u);
    float *dir = malloc(3u * NFT_BATCH * sizeof *dir);
    float *val = malloc(NFT_BATCH * sizeof *val);
    char why[256] = "";

    memset(r, 0, sizeof *r);
    r->alpha = 1.0 - pow(1.0 - p->significance, 1.0 / (p->run_count ? p->run_count : 1u));
    if (!obs || !expv || !sorted || !u || !dir || !val || T == 0 || P == 0 || S == 0 ||
        P * S > NFT_BATCH) {
        snprintf(why, sizeof why, "bad parameters or out of memory");
        goto fail;
    }

    /* Histogram of N samples. */
    nft_rng rng;
    nft_rng_seed(&rng, p->seed, 0xc412u);
    for (size_t k0 = 0; k0 < N; k0 += NFT_BATCH) {
        size_t count = N - k0 < NFT_BATCH ? N - k0 : NFT_BATCH;
        for (size_t k = 0; k < 2u * count; ++k)
            u[k] = nft_rng_float(&rng);
        if (sample(user, count, u, dir) != 0) {
            snprintf(why, sizeof why, "the sampler failed at sample %zu", k0);
            goto fail;
        }
        for (size_t k = 0; k < count; ++k) {
            const float *w = dir + 3u * k;
            double len = nft_length3f(w);
            /* The API promises unit length within 1e-5; 1e-4 here keeps the harness generic. */
            if (!isfinite(len) || fabs(len - 1.0) > 1e-4) {
                snprintf(why, sizeof why,
                         "sample %zu (u = %.9g, %.9g) is not a unit vector: (%.9g, %.9g, %.9g)",
                         k0 + k, u[2u * k], u[2u * k + 1u], w[0], w[1], w[2]);
                goto fail;
            }
            double theta, phi;
            nft_direction_angles(w, &theta, &phi);
            long i = (long)(theta / NFT_PI * T), j = (long)(phi / (2.0 * NFT_PI) * P);
            i = i < 0 ? 0 : (i >= (long)T ? (long)T - 1 : i);
            j = j < 0 ? 0 : (j >= (long)P ? (long)P - 1 : j);
            obs[(size_t)i * P + (size_t)j] += 1.0;
        }
    }

    /* Expected counts: N times the integral of pdf over each cell, S x S midpoints. */
    const double dt = NFT_PI / ((double)T * S), dp = 2.0 * NFT_PI / ((double)P * S);
    for (uint32_t i = 0; i < T; ++i) {
        for (uint32_t a = 0; a < S; ++a) {
            double t = ((double)i * S + a + 0.5) * dt, st = sin(t), ct = cos(t);
            for (uint32_t j = 0; j < P * S; ++j)
                grid_direction(st, ct, (j + 0.5) * dp, NULL, dir + 3u * j);
            if (pdf(user, (size_t)P * S, dir, val) != 0) {
                snprintf(why, sizeof why, "the pdf failed");
                goto fail;
            }
            for (uint32_t j = 0; j < P * S; ++j) {
                if (!isfinite(val[j]) || !(val[j] >= 0.0f)) {
                    snprintf(why, sizeof why, "pdf = %g at (%.9g, %.9g, %.9g)", val[j],
                             dir[3u * j], dir[3u * j + 1u], dir[3u * j + 2u]);
                    goto fail;
                }
                expv[(size_t)i * P + j / S] += (double)N * val[j] * st * dt * dp;
            }
        }
    }
    double total = 0.0;
    for (size_t c = 0; c < cells; ++c)
        total += expv[c];
    r->pdf_integral = total / (double)N;
    if (!(fabs(r->pdf_integral - 1.0) <= p->integral_tolerance)) {
        snprintf(why, sizeof why, "the pdf integrates to %.6f, not 1 (tolerance %g)",
                 r->pdf_integral, p->integral_tolerance);
        goto fail;
    }

    /* Pearson's statistic with pooling of small cells (as pbrt-v4's Chi2Test). */
    for (size_t c = 0; c < cells; ++c) {
        sorted[c].expected = expv[c];
        sorted[c].observed = obs[c];
    }
    qsort(sorted, cells, sizeof *sorted, compare_cells);
    double chsq = 0.0, pooled_obs = 0.0, pooled_exp = 0.0;
    int dof = 0;
    size_t pooled_cells = 0;
    for (size_t c = 0; c < cells; ++c) {
        double e = sorted[c].expected, o = sorted[c].observed;
        if (e == 0.0) {
            if (o > (double)N * 1e-5) {
                snprintf(why, sizeof why, "%.0f samples in a cell with expected count 0", o);
                goto fail;
            }
        } else if (e < p->min_expected ||
                   (pooled_exp > 0.0 && pooled_exp < p->min_expected)) {
            pooled_obs += o;
            pooled_exp += e;
            ++pooled_cells;
        } else {
            chsq += (o - e) * (o - e) / e;
            ++dof;
        }
    }
    if (pooled_cells > 0) {
        chsq += (pooled_obs - pooled_exp) * (pooled_obs - pooled_exp) / pooled_exp;
        ++dof;
    }
    dof -= 1; /* the counts sum to N; no parameters are fitted */
    r->statistic = chsq;
    r->dof = dof;
    if (dof < 1) {
        snprintf(why, sizeof why, "too few cells (%d degrees of freedom)", dof);
        goto fail;
    }
    r->p_value = nft_gamma_q(0.5 * dof, 0.5 * chsq);
    if (!(r->p_value >= r->alpha)) {
        snprintf(why, sizeof why,
                 "statistic %.2f with %d degrees of freedom: p-value %.3g < %.3g "
                 "(significance %g, Sidak over %u runs)",
                 chsq, dof, r->p_value, r->alpha, p->significance, p->run_count);
        goto fail;
    }
    r->passed = 1;
    snprintf(r->message, sizeof r->message, "chi2 %s: statistic %.2f, dof %d, p-value %.3g",
             p->name ? p->name : "", chsq, dof, r->p_value);
    goto done;

fail:
    r->passed = 0;
    {
        char file[160] = "";
        if (p->dump_on_failure && obs && expv)
            dump_tables(p, obs, expv, why, file, sizeof file);
        snprintf(r->message, sizeof r->message, "chi2 %s failed: %s%s%s",
                 p->name ? p->name : "", why, file[0] ? "; tables in " : "", file);
    }
done:
    free(obs);
    free(expv);
    free(sorted);
    free(u);
    free(dir);
    free(val);
    return r->passed;
}

double nft_integrate_model(const nf_model *m, const nf_context *ctx, uint32_t theta_res,
                           uint32_t phi_res, const double frame[3][3])
{
    nft_model_fn f;
    if (nft_model_fn_init(&f, m, ctx) != 0)
        return NAN;
    double integral = nft_integrate_sphere(nft_model_pdf, &f, theta_res, phi_res, frame);
    nf_status last = f.last;
    nft_model_fn_free(&f);
    return last == NF_OK ? integral : NAN;
}

int nft_chi2_model(const nft_chi2_params *p, const nf_model *m, const nf_context *ctx,
                   nft_chi2_result *r)
{
    nft_model_fn f;
    memset(r, 0, sizeof *r);
    if (nft_model_fn_init(&f, m, ctx) != 0) {
        snprintf(r->message, sizeof r->message, "chi2 %s: out of memory", p->name ? p->name : "");
        return 0;
    }
    nft_chi2_test(p, nft_model_sample, nft_model_pdf, &f, r);
    nf_status last = f.last;
    nft_model_fn_free(&f);
    if (last != NF_OK) { /* the library's refusal, not the statistic, says what went wrong */
        r->passed = 0;
        snprintf(r->message, sizeof r->message, "chi2 %s: library call failed: %s (%s)",
                 p->name ? p->name : "", nf_status_string(last), nf_last_error_message());
    }
    return r->passed;
}

/* ---- model files ------------------------------------------------------------------------- */

uint32_t nft_crc32_ieee(const unsigned char *p, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) {
        crc ^= p[i];
        for (int b = 0; b < 8; ++b)
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

/* ---- snapshots ------------------------------------------------------------------------------- */

int nft_snapshot_take(const nf_model *m, nft_snapshot *s)
{
    memset(s, 0, sizeof *s);
    s->param_count = nf_model_param_count(m);
    s->params = malloc((s->param_count ? s->param_count : 1u) * sizeof *s->params);
    if (!s->params || nf_model_get_params(m, s->params) != NF_OK)
        return -1;
    if (nf_model_serialize(m, NULL, 0, &s->bytes_size) != NF_OK)
        return -1;
    s->bytes = malloc(s->bytes_size ? s->bytes_size : 1u);
    size_t written = 0;
    if (!s->bytes || nf_model_serialize(m, s->bytes, s->bytes_size, &written) != NF_OK ||
        written != s->bytes_size)
        return -1;
    s->steps = nf_model_step_count(m);
    return 0;
}

nft_snapshot nft_snapshot_of(const nf_model *m)
{
    nft_snapshot s;
    if (nft_snapshot_take(m, &s) != 0)
        fail_msg("nft_snapshot_of: the model's parameters or bytes could not be read: %s",
                 nf_last_error_message());
    return s;
}

int nft_snapshot_equal(const nf_model *m, const nft_snapshot *s)
{
    nft_snapshot now;
    int equal = nft_snapshot_take(m, &now) == 0 && now.param_count == s->param_count &&
                memcmp(now.params, s->params, s->param_count * sizeof *s->params) == 0 &&
                now.bytes_size == s->bytes_size &&
                memcmp(now.bytes, s->bytes, s->bytes_size) == 0 && now.steps == s->steps;
    nft_snapshot_free(&now);
    return equal;
}

void nft_snapshot_free(nft_snapshot *s)
{
    free(s->params);
    free(s->bytes);
    s->params = NULL;
    s->bytes = NULL;
}

static const float nft_sentinel = NFT_SENTINEL;

void nft_fill_sentinel(float *v, size_t n)
{
    for (size_t i = 0; i < n; ++i)
        v[i] = nft_sentinel;
}

int nft_untouched(const float *v, size_t n)
{
    for (size_t i = 0; i < n; ++i)
        if (memcmp(&v[i], &nft_sentinel, sizeof nft_sentinel) != 0)
            return 0;
    return 1;
}

nf_context nft_bad_context(const nf_context *good, int which, char *what, size_t size)
{
    nf_context c = *good;
    const float values[3] = {NAN, INFINITY, -INFINITY};
    const char *names[3] = {"position", "normal", "wo"};
    if (which < 27) {
        int field = which / 9, comp = (which / 3) % 3, v = which % 3;
        float *f = field == 0 ? c.position : field == 1 ? c.normal : c.wo;
        f[comp] = values[v];
        snprintf(what, size, "%s[%d] = %g", names[field], comp, (double)values[v]);
    } else {
        int k = which - 27;
        float *f = k % 2 == 0 ? c.normal : c.wo;
        const float v[3] = {0.0f, 1e-16f, 1e-38f};
        f[0] = f[1] = f[2] = v[k / 2];
        /* A zero normal is a point in a medium, bad only with a bad phase_g. */
        int medium = k == 0;
        if (medium)
            c.phase_g = NAN;
        snprintf(what, size, "%s of components %g%s", k % 2 == 0 ? "normal" : "wo",
                 (double)v[k / 2], medium ? " (a medium) with phase_g NaN" : "");
    }
    return c;
}

void nft_vmf_sample(nft_rng *r, const double mu[3], double kappa, float dir[3])
{
    double t[3], b[3], n[3];
    nft_frame(mu, t, b, n);
    double u = nft_rng_double(r);
    double c = 1.0 + log(u + (1.0 - u) * exp(-2.0 * kappa)) / kappa;
    c = fmin(fmax(c, -1.0), 1.0);
    double s = sqrt(fmax(0.0, 1.0 - c * c)), phi = 2.0 * NFT_PI * nft_rng_double(r);
    double w[3];
    for (int k = 0; k < 3; ++k)
        w[k] = s * cos(phi) * t[k] + s * sin(phi) * b[k] + c * n[k];
    double len = sqrt(nft_dot3(w, w));
    for (int k = 0; k < 3; ++k)
        dir[k] = (float)(w[k] / len);
}
