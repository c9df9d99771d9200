/*
 * nf_seam_study.c - how much the seam at phi = 0 costs the flow (docs/results.md, "The seam").
 *
 * The flow works on the square (theta / pi, phi / 2 pi), and its splines are monotone maps of
 * [0, 1] onto itself: a lobe that straddles phi = 0 must be built from two pieces at opposite
 * edges of the square. This program trains the small model on one shading point whose
 * integrand is a von Mises-Fisher lobe (concentration kappa) times the cosine to the normal,
 *
 *     f(w) = vMF(w; mu, kappa) max(0, n . w),
 *
 * once with the lobe centred on the seam (mu at phi = 0, the normal 0.2 rad beside it) and
 * once with the same configuration turned by pi about z (mu at phi = pi, far from the seam),
 * and reports the KL divergence from the normalized integrand to the model, by quadrature on
 * a grid of (cos theta, phi) cells, after each checkpoint of training. Training is online, as
 * in a guided renderer: each step draws a batch of directions, each from the flow with the
 * guide's default mixture probability (nf_guide_policy_init) and otherwise from a diffuse
 * BSDF's cosine lobe about the normal, weights each by f over the mixture's density and takes
 * one nf_train_step. `--training flow` draws every direction from the flow and weights it by
 * f / pdf: there a batch's weights have no bound, and a direction the flow makes too rare (a
 * lobe's tail) can carry 15 to 50 times the batch's mean weight and throw a run off for a
 * few dozen steps, in either placement (docs/results.md section 8).
 *
 * Output: a Markdown table, one row per prior, kappa and checkpoint, with the mean and
 * standard deviation over the seeds of both placements' KL and their ratio, and the medians
 * and theirs. Deterministic: the random numbers are the program's own.
 *
 * Usage: nf_seam_study [--steps A,B,C] [--seeds N] [--kappas K1,K2] [--phi-map MAP]
 *                      [--training mixture|flow] [--help]
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "pcg32.h"

#define BATCH 512          /* training samples per step, as nf_demo                      */
#define LEARNING_RATE 5e-3f
#define GRID_Z 512         /* quadrature cells in cos theta                             */
#define GRID_PHI 1024      /* and in phi: a kappa = 200 lobe (width ~0.07 rad) spans ~20 */
#define MAX_LIST 8

static const double PI = 3.14159265358979323846;

/* ---- the integrand --------------------------------------------------------------------------- */

typedef struct integrand {
    double mu[3], n[3], kappa, vmf_norm; /* vMF normalization kappa / (4 pi sinh kappa) */
} integrand;

static void from_angles(double theta, double phi, double w[3])
{
    w[0] = sin(theta) * cos(phi);
    w[1] = sin(theta) * sin(phi);
    w[2] = cos(theta);
}

/* The lobe at 60 degrees from +z and at phi = phi0, the normal at 45 degrees and phi0 + 0.2. */
static integrand make_integrand(double kappa, double phi0)
{
    integrand f;
    from_angles(PI / 3.0, phi0, f.mu);
    from_angles(PI / 4.0, phi0 + 0.2, f.n);
    f.kappa = kappa;
    /* kappa / (2 pi (1 - e^{-2 kappa})) times e^{kappa (mu.w - 1)}: no overflow. */
    f.vmf_norm = kappa / (2.0 * PI * (1.0 - exp(-2.0 * kappa)));
    return f;
}

/* A direction from the cosine lobe about the unit normal n (a diffuse BSDF's sampling). */
static void cosine_sample(const double n[3], double u0, double u1, double w[3])
{
    double s = n[2] >= 0.0 ? 1.0 : -1.0, a = -1.0 / (s + n[2]), c = n[0] * n[1] * a;
    double t[3] = {1.0 + s * n[0] * n[0] * a, s * c, -s * n[0]};
    double b[3] = {c, s + n[1] * n[1] * a, -n[1]};
    double r = sqrt(u0), x = r * cos(2.0 * PI * u1), y = r * sin(2.0 * PI * u1), z = sqrt(1.0 - u0);
    for (int k = 0; k < 3; ++k)
        w[k] = x * t[k] + y * b[k] + z * n[k];
}

static double cosine_pdf(const double n[3], const double w[3])
{
    double c = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
    return c > 0.0 ? c / PI : 0.0;
}

static double integrand_eval(const integrand *f, const double w[3])
{
    double c = f->n[0] * w[0] + f->n[1] * w[1] + f->n[2] * w[2];
    if (c <= 0.0)
        return 0.0;
    double m = f->mu[0] * w[0] + f->mu[1] * w[1] + f->mu[2] * w[2];
    return f->vmf_norm * exp(f->kappa * (m - 1.0)) * c;
}

/* ---- quadrature ------------------------------------------------------------------------------ */

/* The grid's cell centres (equal solid angle 4 pi / (GRID_Z GRID_PHI) each), the normalized
 * integrand there, and room for the model's densities. */
typedef struct grid {
    float *dir;     /* 3 per cell */
    double *target; /* normalized: sums to 1 over the sphere with the cell's solid angle */
    float *pdf;
    nf_context *ctx;
    size_t cells;
    double cell_sr;
} grid;

static int grid_make(grid *g, const integrand *f, const nf_context *ctx)
{
    g->cells = (size_t)GRID_Z * GRID_PHI;
    g->cell_sr = 4.0 * PI / (double)g->cells;
    g->dir = malloc(3 * g->cells * sizeof *g->dir);
    g->target = malloc(g->cells * sizeof *g->target);
    g->pdf = malloc(g->cells * sizeof *g->pdf);
    g->ctx = malloc(g->cells * sizeof *g->ctx);
    if (!g->dir || !g->target || !g->pdf || !g->ctx)
        return 0;
    double sum = 0.0;
    for (size_t i = 0; i < GRID_Z; ++i)
        for (size_t j = 0; j < GRID_PHI; ++j) {
            size_t k = i * GRID_PHI + j;
            double z = -1.0 + 2.0 * ((double)i + 0.5) / GRID_Z, r = sqrt(1.0 - z * z);
            double phi = 2.0 * PI * ((double)j + 0.5) / GRID_PHI;
            double w[3] = {r * cos(phi), r * sin(phi), z};
            for (int a = 0; a < 3; ++a)
                g->dir[3 * k + (size_t)a] = (float)w[a];
            g->target[k] = integrand_eval(f, w);
            sum += g->target[k] * g->cell_sr;
            g->ctx[k] = *ctx;
        }
    for (size_t k = 0; k < g->cells; ++k)
        g->target[k] /= sum;
    return 1;
}

static void grid_free(grid *g)
{
    free(g->dir);
    free(g->target);
    free(g->pdf);
    free(g->ctx);
}

/* KL(target || model) in nats: the integral of p* log(p* / p) over the sphere. */
static int kl_divergence(const nf_model *m, grid *g, double *kl)
{
    if (nf_pdf(m, g->cells, g->ctx, g->dir, g->pdf) != NF_OK)
        return 0;
    double sum = 0.0;
    for (size_t k = 0; k < g->cells; ++k)
        if (g->target[k] > 0.0)
            sum += g->target[k] * log(g->target[k] / (double)g->pdf[k]) * g->cell_sr;
    *kl = sum;
    return 1;
}

/* ---- one training run ------------------------------------------------------------------------ */

typedef struct options {
    long steps[MAX_LIST];
    int nsteps, seeds;
    double kappas[MAX_LIST];
    int nkappas;
    nf_phi_map phi_map;
    float flow_prob; /* the share of training directions the flow draws (1: all) */
} options;

/* Trains a fresh model with `prior` on f at one context; kl[c] after options' step c. */
static int run(nf_prior_kind prior, const integrand *f, uint64_t seed, const options *o,
               double *kl)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.prior = prior;
    cfg.phi_map = o->phi_map;
    cfg.learning_rate = LEARNING_RATE;
    cfg.seed = seed;
    nf_model *m = NULL;
    if (nf_model_create(&cfg, &m) != NF_OK)
        return 0;
    nf_context c = {{0.5f, 0.5f, 0.5f},
                    {(float)f->n[0], (float)f->n[1], (float)f->n[2]},
                    {(float)f->n[0], (float)f->n[1], (float)f->n[2]},
                    0.0f};
    static nf_context ctx[BATCH];
    static float u[2 * BATCH], dir[3 * BATCH], pdf[BATCH], weight[BATCH];
    for (int i = 0; i < BATCH; ++i)
        ctx[i] = c;
    grid g;
    int ok = grid_make(&g, f, &c);
    pcg32 r = pcg32_seed(seed, 17u);
    long done = 0;
    for (int k = 0; ok && k < o->nsteps; ++k) {
        for (; ok && done < o->steps[k]; ++done) {
            for (int i = 0; i < 2 * BATCH; ++i)
                u[i] = pcg32_float(&r);
            ok = nf_sample(m, BATCH, ctx, u, dir, pdf) == NF_OK;
            /* The mixture: the BSDF's directions replace the flow's where the draw says so, and
             * every direction is weighted by f over the mixture's density at it. */
            int mixed = o->flow_prob < 1.0f;
            for (int i = 0; ok && mixed && i < BATCH; ++i)
                if (pcg32_float(&r) >= o->flow_prob) {
                    double w[3];
                    cosine_sample(f->n, pcg32_float(&r), pcg32_float(&r), w);
                    for (int a = 0; a < 3; ++a)
                        dir[3 * i + a] = (float)w[a];
                }
            ok = ok && (!mixed || nf_pdf(m, BATCH, ctx, dir, pdf) == NF_OK);
            for (int i = 0; ok && i < BATCH; ++i) {
                double w[3] = {dir[3 * i], dir[3 * i + 1], dir[3 * i + 2]};
                double p = mixed ? o->flow_prob * (double)pdf[i] +
                                       (1.0 - o->flow_prob) * cosine_pdf(f->n, w)
                                 : (double)pdf[i];
                weight[i] = (float)(integrand_eval(f, w) / p);
            }
            ok = ok && nf_train_step(m, BATCH, ctx, dir, weight, NULL) == NF_OK;
        }
        ok = ok && kl_divergence(m, &g, &kl[k]);
    }
    grid_free(&g);
    nf_model_destroy(m);
    return ok;
}

/* ---- the study ------------------------------------------------------------------------------- */

static int parse_list(const char *text, double *out, int *count)
{
    *count = 0;
    for (const char *p = text; *p && *count < MAX_LIST;) {
        char *end;
        double v = strtod(p, &end);
        if (end == p || !(v > 0.0))
            return 0;
        out[(*count)++] = v;
        p = *end == ',' ? end + 1 : end;
        if (*end && *end != ',')
            return 0;
    }
    return *count > 0;
}

static void usage(FILE *out)
{
    fprintf(out, "Usage: nf_seam_study [--steps A,B,C] [--seeds N] [--kappas K1,K2] "
                 "[--phi-map MAP]\n"
                 "  --steps    checkpoints, in training steps of %d samples (default "
                 "100,500,2000)\n"
                 "  --seeds    seeds per configuration (default 3)\n"
                 "  --kappas   vMF concentrations (default 20,200)\n"
                 "  --phi-map  circular (the library's default) or interval\n"
                 "  --training mixture (default: the guide's mixture of the flow and a\n"
                 "             diffuse BSDF) or flow (every direction from the flow)\n",
            BATCH);
}

static void mean_sd(const double *v, int n, double *mean, double *sd)
{
    double s = 0.0, q = 0.0;
    for (int i = 0; i < n; ++i)
        s += v[i];
    *mean = s / n;
    for (int i = 0; i < n; ++i)
        q += (v[i] - *mean) * (v[i] - *mean);
    *sd = n > 1 ? sqrt(q / (n - 1)) : 0.0;
}

/* The median: the means are set by the few seeds that stall, the medians by the typical run. */
static double median(const double *v, int n)
{
    double s[64];
    for (int i = 0; i < n; ++i) {
        int j = i;
        for (; j > 0 && s[j - 1] > v[i]; --j)
            s[j] = s[j - 1];
        s[j] = v[i];
    }
    return n % 2 ? s[n / 2] : 0.5 * (s[n / 2 - 1] + s[n / 2]);
}

int main(int argc, char **argv)
{
    nf_config defaults;
    nf_config_init(&defaults, NF_PRESET_SMALL);
    nf_guide_policy policy;
    nf_guide_policy_init(&policy);
    options o = {{100, 500, 2000}, 3, 3, {20.0, 200.0}, 2, defaults.phi_map, policy.mixture_prob};
    for (int i = 1; i < argc; ++i) {
        double list[MAX_LIST];
        int n = 0;
        if (!strcmp(argv[i], "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(argv[i], "--steps") && i + 1 < argc && parse_list(argv[++i], list, &n)) {
            o.nsteps = n;
            for (int k = 0; k < n; ++k)
                o.steps[k] = (long)list[k];
            for (int k = 1; k < n; ++k)
                if (o.steps[k] <= o.steps[k - 1]) {
                    fprintf(stderr, "nf_seam_study: --steps must increase\n");
                    return 2;
                }
        } else if (!strcmp(argv[i], "--seeds") && i + 1 < argc &&
                   parse_list(argv[++i], list, &n) && n == 1 && list[0] <= 64) {
            o.seeds = (int)list[0];
        } else if (!strcmp(argv[i], "--kappas") && i + 1 < argc &&
                   parse_list(argv[++i], o.kappas, &o.nkappas)) {
        } else if (!strcmp(argv[i], "--phi-map") && i + 1 < argc &&
                   (!strcmp(argv[i + 1], "circular") || !strcmp(argv[i + 1], "interval"))) {
            o.phi_map = !strcmp(argv[++i], "circular") ? NF_PHI_CIRCULAR : NF_PHI_INTERVAL;
        } else if (!strcmp(argv[i], "--training") && i + 1 < argc &&
                   (!strcmp(argv[i + 1], "mixture") || !strcmp(argv[i + 1], "flow"))) {
            o.flow_prob = !strcmp(argv[++i], "flow") ? 1.0f : policy.mixture_prob;
        } else {
            fprintf(stderr, "nf_seam_study: bad option '%s'\n", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    static const nf_prior_kind priors[2] = {NF_PRIOR_UNIFORM_DIRECTION, NF_PRIOR_COSINE};
    static const char *prior_names[2] = {"uniform-direction", "cosine"};
    printf("| prior | kappa | steps | KL, lobe on the seam | KL, lobe at phi = pi | seam / pi | "
           "medians, seam / pi | seam / pi (medians) |\n");
    printf("|---|---|---|---|---|---|---|---|\n");
    for (int p = 0; p < 2; ++p)
        for (int k = 0; k < o.nkappas; ++k) {
            double kl[2][64][MAX_LIST];
            for (int place = 0; place < 2; ++place) {
                integrand f = make_integrand(o.kappas[k], place ? PI : 0.0);
                for (int s = 0; s < o.seeds; ++s)
                    if (!run(priors[p], &f, (uint64_t)s + 1u, &o, kl[place][s])) {
                        fprintf(stderr, "nf_seam_study: %s\n", nf_last_error_message());
                        return 1;
                    }
            }
            for (int c = 0; c < o.nsteps; ++c) {
                double v[2][64], mean[2], sd[2], med[2];
                for (int place = 0; place < 2; ++place) {
                    for (int s = 0; s < o.seeds; ++s)
                        v[place][s] = kl[place][s][c];
                    mean_sd(v[place], o.seeds, &mean[place], &sd[place]);
                    med[place] = median(v[place], o.seeds);
                }
                printf("| %s | %g | %ld | %.4f ± %.4f | %.4f ± %.4f | %.2f | %.4f / %.4f | %.2f |\n",
                       prior_names[p], o.kappas[k], o.steps[c], mean[0], sd[0], mean[1], sd[1],
                       mean[0] / mean[1], med[0], med[1], med[0] / med[1]);
            }
            fflush(stdout);
        }
    printf("\nKL(f || model) in nats by quadrature on %d x %d cells of (cos theta, phi); mean ± "
           "standard deviation, and median, over %d seeds; training online, %d samples per step, "
           "drawn %s; learning rate %g, the small model, phi map %s. libnisflow %s.\n",
           GRID_Z, GRID_PHI, o.seeds, BATCH,
           o.flow_prob < 1.0f ? "from the guide's mixture (the flow, else a diffuse BSDF)"
                              : "from the flow alone",
           (double)LEARNING_RATE, o.phi_map == NF_PHI_CIRCULAR ? "circular" : "interval",
           nf_version_string());
    return 0;
}
