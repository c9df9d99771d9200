/*
 * nf_demo.c - learn to importance-sample an analytic target with libnisflow.
 *
 * The target plays the role of a renderer's integrand at one shading point: two
 * von Mises-Fisher lobes (a sharp one and a broad one, think "a light source and a bright
 * wall") times the cosine of the angle to the surface normal, zero below the surface.
 *
 * Training is online, as in a guided path tracer: every iteration draws a batch of directions,
 * each from the current model with the guide's default probability (nf_guide_policy_init) and
 * otherwise from a diffuse BSDF's cosine lobe about the normal, weights each by target(w) over
 * the mixture's density, and takes one nf_train_step. The mixture bounds every weight; drawn
 * from the model alone, a direction the model has made too rare can outweigh its whole batch
 * (nisflow/train.h). Every 50 iterations the program reports, on a fixed held-out set of
 * directions,
 *
 *   KL        the Kullback-Leibler divergence from the normalized target to the model
 *             (nats; 0 when the model is exactly proportional to the target), and
 *   rel.var   the variance of the one-sample estimator target(w)/pdf(w), w ~ model,
 *             divided by the squared integral (0 for a perfect importance sampler).
 *
 * Only the public API is used. The output is deterministic: the program has its own
 * random-number generator with a fixed seed.
 *
 * Usage: nf_demo [--iterations N] [--prior uniform-direction|uniform-angle|cosine] [--help]
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#include "pcg32.h"

#define BATCH_SIZE 512      /* training samples per iteration                       */
#define HELD_OUT_SIZE 16384 /* directions of the fixed evaluation set                */
#define REPORT_EVERY 50     /* iterations between two reports                        */
#define LEARNING_RATE 5e-3f /* a little above the default: the demo trains briefly   */

static const float PI = 3.14159265358979f;

/* ---- Small vector helpers ------------------------------------------------------------------ */

static float dot3(const float a[3], const float b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void normalize3(float v[3])
{
    float len = sqrtf(dot3(v, v));
    v[0] /= len;
    v[1] /= len;
    v[2] /= len;
}

/* ---- The target ---------------------------------------------------------------------------- */

/* A von Mises-Fisher lobe: the density kappa / (4 pi sinh kappa) exp(kappa axis.w), per
 * steradian, times a weight. */
typedef struct lobe {
    float axis[3];
    float kappa;
    float weight;
} lobe;

typedef struct target {
    float normal[3];
    lobe lobes[2];
} target;

static target make_target(void)
{
    target t = {
        .normal = {0.2f, -0.3f, 1.0f},
        .lobes = {
            {.axis = {0.5f, 0.4f, 0.75f}, .kappa = 40.0f, .weight = 0.7f},  /* sharp */
            {.axis = {-0.6f, -0.3f, 0.6f}, .kappa = 6.0f, .weight = 0.3f}, /* broad */
        },
    };
    normalize3(t.normal);
    normalize3(t.lobes[0].axis);
    normalize3(t.lobes[1].axis);
    return t;
}

static float vmf_density(const lobe *l, const float w[3])
{
    /* kappa / (4 pi sinh kappa) exp(kappa c) written so that it cannot overflow. */
    float k = l->kappa;
    return k / (2.0f * PI * (1.0f - expf(-2.0f * k))) * expf(k * (dot3(l->axis, w) - 1.0f));
}

/* The (unnormalized) integrand: the lobes times max(0, cos theta) around the normal. */
static float target_eval(const target *t, const float w[3])
{
    float cos_theta = dot3(t->normal, w);
    if (cos_theta <= 0.0f)
        return 0.0f;
    return cos_theta * (t->lobes[0].weight * vmf_density(&t->lobes[0], w) +
                        t->lobes[1].weight * vmf_density(&t->lobes[1], w));
}

/* ---- Evaluation on a held-out set ---------------------------------------------------------- */

/* A fixed set of directions drawn from a mixture g of the two lobes and the uniform sphere
 * density (so that both the lobes and the rest of the sphere are well covered), with their
 * target values f and mixture densities g. Integrals over the sphere are then estimated as
 * averages of integrand / g. */
typedef struct held_out {
    float dir[3 * HELD_OUT_SIZE];
    float f[HELD_OUT_SIZE];
    float g[HELD_OUT_SIZE];
    double integral; /* estimate of the integral of the target over the sphere */
} held_out;

static const float HELD_OUT_MIX[3] = {0.2f, 0.5f, 0.3f}; /* uniform, lobe 0, lobe 1 */

/* An orthonormal frame (t, b) around the unit vector n (Duff et al. 2017). */
static void orthonormal_basis(const float n[3], float t[3], float b[3])
{
    float sign = copysignf(1.0f, n[2]);
    float a = -1.0f / (sign + n[2]);
    float c = n[0] * n[1] * a;
    t[0] = 1.0f + sign * n[0] * n[0] * a;
    t[1] = sign * c;
    t[2] = -sign * n[0];
    b[0] = c;
    b[1] = sign + n[1] * n[1] * a;
    b[2] = -n[1];
}

/* A direction with cos_theta = z and azimuth phi around `axis`. */
static void around_axis(const float axis[3], float z, float phi, float w[3])
{
    float t[3], b[3];
    orthonormal_basis(axis, t, b);
    float r = sqrtf(fmaxf(0.0f, 1.0f - z * z));
    for (int k = 0; k < 3; ++k)
        w[k] = r * cosf(phi) * t[k] + r * sinf(phi) * b[k] + z * axis[k];
}

static void make_held_out(held_out *h, const target *t, pcg32 *rng)
{
    const float z_axis[3] = {0.0f, 0.0f, 1.0f};
    double sum = 0.0;
    for (int i = 0; i < HELD_OUT_SIZE; ++i) {
        float pick = pcg32_float(rng), u0 = pcg32_float(rng), u1 = pcg32_float(rng);
        float *w = &h->dir[3 * i];
        if (pick < HELD_OUT_MIX[0]) {
            around_axis(z_axis, 1.0f - 2.0f * u0, 2.0f * PI * u1, w); /* uniform sphere */
        } else {
            const lobe *l = &t->lobes[pick < HELD_OUT_MIX[0] + HELD_OUT_MIX[1] ? 0 : 1];
            /* Inverse CDF of cos_theta under a von Mises-Fisher lobe. */
            float z = 1.0f + logf(u0 + (1.0f - u0) * expf(-2.0f * l->kappa)) / l->kappa;
            around_axis(l->axis, fminf(1.0f, fmaxf(-1.0f, z)), 2.0f * PI * u1, w);
        }
        h->f[i] = target_eval(t, w);
        h->g[i] = HELD_OUT_MIX[0] / (4.0f * PI) + HELD_OUT_MIX[1] * vmf_density(&t->lobes[0], w) +
                  HELD_OUT_MIX[2] * vmf_density(&t->lobes[1], w);
        sum += h->f[i] / h->g[i];
    }
    h->integral = sum / HELD_OUT_SIZE;
}

typedef struct metrics {
    double kl;      /* KL(target || model) in nats                                  */
    double rel_var; /* Var[f/p] / (integral f)^2 for one sample drawn from the model */
} metrics;

/* Both metrics are integrals over the sphere of expressions in p* = f / (integral of f):
 *   KL      = integral of  p* log(p* / p)
 *   rel_var = integral of  p*^2 / p   - 1                                              */
static nf_status evaluate(const nf_model *model, const nf_context *ctx, const held_out *h,
                          metrics *out)
{
    static float pdf[HELD_OUT_SIZE];
    /* ctx holds BATCH_SIZE copies of the shading context: evaluate in chunks of that size. */
    for (int start = 0; start < HELD_OUT_SIZE; start += BATCH_SIZE) {
        nf_status s = nf_pdf(model, BATCH_SIZE, ctx, &h->dir[3 * start], &pdf[start]);
        if (s != NF_OK)
            return s;
    }
    double kl = 0.0, second_moment = 0.0;
    for (int i = 0; i < HELD_OUT_SIZE; ++i) {
        if (h->f[i] <= 0.0f)
            continue; /* p* = 0: no contribution */
        double p_target = h->f[i] / h->integral;
        double p_model = pdf[i];
        kl += p_target * log(p_target / p_model) / h->g[i];
        second_moment += p_target * p_target / p_model / h->g[i];
    }
    out->kl = kl / HELD_OUT_SIZE;
    out->rel_var = second_moment / HELD_OUT_SIZE - 1.0;
    return NF_OK;
}

/* ---- Command line ------------------------------------------------------------------------- */

typedef struct options {
    long iterations;
    nf_prior_kind prior;
    const char *prior_name;
} options;

static void usage(FILE *out)
{
    fprintf(out,
            "usage: nf_demo [--iterations N] [--prior NAME] [--help]\n"
            "\n"
            "Trains a small libnisflow model online to importance-sample an analytic target\n"
            "(two von Mises-Fisher lobes times a cosine) and reports its progress.\n"
            "\n"
            "  --iterations N   training iterations of %d samples (default 300)\n"
            "  --prior NAME     uniform-direction, uniform-angle or cosine (default cosine)\n"
            "  --help           print this help and exit\n",
            BATCH_SIZE);
}

/* Returns 0 to run, 1 to exit successfully (--help), -1 on a usage error. */
static int parse_options(int argc, char **argv, options *opt)
{
    opt->iterations = 300;
    opt->prior = NF_PRIOR_COSINE;
    opt->prior_name = "cosine";
    for (int i = 1; i < argc; ++i) {
        if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            usage(stdout);
            return 1;
        } else if (strcmp(argv[i], "--iterations") == 0 && i + 1 < argc) {
            char *end = NULL;
            opt->iterations = strtol(argv[++i], &end, 10);
            if (*argv[i] == '\0' || *end != '\0' || opt->iterations < 0 ||
                opt->iterations > 1000000) {
                fprintf(stderr, "nf_demo: --iterations needs an integer in 0..1000000\n");
                return -1;
            }
        } else if (strcmp(argv[i], "--prior") == 0 && i + 1 < argc) {
            opt->prior_name = argv[++i];
            if (strcmp(opt->prior_name, "uniform-direction") == 0) {
                opt->prior = NF_PRIOR_UNIFORM_DIRECTION;
            } else if (strcmp(opt->prior_name, "uniform-angle") == 0) {
                opt->prior = NF_PRIOR_UNIFORM_ANGLE;
            } else if (strcmp(opt->prior_name, "cosine") == 0) {
                opt->prior = NF_PRIOR_COSINE;
            } else {
                fprintf(stderr, "nf_demo: unknown prior '%s'\n", opt->prior_name);
                return -1;
            }
        } else {
            fprintf(stderr, "nf_demo: unknown or incomplete option '%s'\n", argv[i]);
            usage(stderr);
            return -1;
        }
    }
    return 0;
}

/* ---- Main ---------------------------------------------------------------------------------- */

/* Prints why a libnisflow call failed; returns 1 if it did. */
static int failed(nf_status s, const char *call)
{
    if (s == NF_OK)
        return 0;
    fprintf(stderr, "nf_demo: %s failed: %s: %s\n", call, nf_status_string(s),
            nf_last_error_message());
    return 1;
}

int main(int argc, char **argv)
{
    options opt;
    int parsed = parse_options(argc, argv, &opt);
    if (parsed != 0)
        return parsed > 0 ? EXIT_SUCCESS : 2;

    /* The paper's small model; everything else stays at its default. */
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.prior = opt.prior;
    cfg.learning_rate = LEARNING_RATE;

    nf_model *model = NULL;
    if (failed(nf_model_create(&cfg, &model), "nf_model_create"))
        return EXIT_FAILURE;

    /* One shading point. The API takes a context per sample, so fill a batch's worth. */
    target tgt = make_target();
    static nf_context ctx[BATCH_SIZE];
    for (int i = 0; i < BATCH_SIZE; ++i) {
        nf_context c = {
            .position = {0.5f, 0.5f, 0.5f},
            .normal = {tgt.normal[0], tgt.normal[1], tgt.normal[2]},
            .wo = {0.0f, 0.6f, 0.8f},
        };
        ctx[i] = c;
    }

    pcg32 rng = pcg32_seed(2024u, 1u);
    pcg32 held_out_rng = pcg32_seed(7u, 2u);
    static held_out h;
    make_held_out(&h, &tgt, &held_out_rng);

    printf("libnisflow %s demo: small model, %s prior, %ld iterations of %d samples\n",
           nf_version_string(), opt.prior_name, opt.iterations, BATCH_SIZE);
    printf("%9s  %12s  %10s  %10s\n", "iteration", "train loss", "KL (nats)", "rel.var");

    int status = EXIT_FAILURE;
    metrics before, now;
    if (failed(evaluate(model, ctx, &h, &before), "nf_pdf"))
        goto done;
    printf("%9d  %12s  %10.4f  %10.4f\n", 0, "-", before.kl, before.rel_var);
    now = before;

    static float u[2 * BATCH_SIZE], dir[3 * BATCH_SIZE], pdf[BATCH_SIZE], weight[BATCH_SIZE];
    static float bsdf_dir[3 * BATCH_SIZE], bsdf_pdf[BATCH_SIZE];
    static int bsdf_at[BATCH_SIZE];
    nf_guide_policy policy;
    nf_guide_policy_init(&policy);
    const float flow_prob = policy.mixture_prob;
    double loss_sum = 0.0;
    int loss_count = 0;
    for (long it = 1; it <= opt.iterations; ++it) {
        /* 1. Draw directions from the mixture: the model's, some replaced by the BSDF's
         *    (a cosine lobe about the normal), as a guided renderer samples. */
        for (int i = 0; i < 2 * BATCH_SIZE; ++i)
            u[i] = pcg32_float(&rng);
        if (failed(nf_sample(model, BATCH_SIZE, ctx, u, dir, pdf), "nf_sample"))
            goto done;
        int nbsdf = 0;
        for (int i = 0; i < BATCH_SIZE; ++i)
            if (pcg32_float(&rng) >= flow_prob) {
                float u0 = pcg32_float(&rng), u1 = pcg32_float(&rng);
                around_axis(tgt.normal, sqrtf(1.0f - u0), 2.0f * PI * u1, &dir[3 * i]);
                memcpy(&bsdf_dir[3 * nbsdf], &dir[3 * i], 3 * sizeof(float));
                bsdf_at[nbsdf++] = i;
            }
        /* 2. The model's density where the BSDF drew (nf_sample gave it for the rest), then
         *    each weight: target over the mixture's density, the mixture's one-sample weight. */
        if (nbsdf > 0 && failed(nf_pdf(model, (size_t)nbsdf, ctx, bsdf_dir, bsdf_pdf), "nf_pdf"))
            goto done;
        for (int k = 0; k < nbsdf; ++k)
            pdf[bsdf_at[k]] = bsdf_pdf[k];
        for (int i = 0; i < BATCH_SIZE; ++i) {
            float bsdf = fmaxf(0.0f, dot3(tgt.normal, &dir[3 * i])) / PI;
            float mix = flow_prob * pdf[i] + (1.0f - flow_prob) * bsdf;
            weight[i] = mix > 0.0f ? target_eval(&tgt, &dir[3 * i]) / mix : 0.0f;
        }

        /* 3. One optimisation step on the weighted negative log-likelihood. */
        float loss = 0.0f;
        if (failed(nf_train_step(model, BATCH_SIZE, ctx, dir, weight, &loss), "nf_train_step"))
            goto done;
        loss_sum += loss;
        ++loss_count;

        if (it % REPORT_EVERY == 0 || it == opt.iterations) {
            if (failed(evaluate(model, ctx, &h, &now), "nf_pdf"))
                goto done;
            /* The loss is the mean over the iterations since the previous report. */
            printf("%9ld  %12.4f  %10.4f  %10.4f\n", it, loss_sum / loss_count, now.kl,
                   now.rel_var);
            loss_sum = 0.0;
            loss_count = 0;
        }
    }

    printf("\nbefore training: KL %.4f nats, relative variance %.4f\n", before.kl,
           before.rel_var);
    printf("after training:  KL %.4f nats, relative variance %.4f\n", now.kl, now.rel_var);
    if (now.rel_var > 0.0)
        printf("variance reduction over the untrained model (the prior): %.2fx\n",
               before.rel_var / now.rel_var);
    status = EXIT_SUCCESS;

done:
    nf_model_destroy(model);
    return status;
}
