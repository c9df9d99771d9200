/*
 * internal.h - the model's memory layout and the interfaces between the library's modules.
 * Nothing here is installed; users see only include/nisflow/.
 */
#ifndef NISFLOW_INTERNAL_H
#define NISFLOW_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "nisflow/nisflow.h"

#define NF_PI 3.14159265358979323846f
#define NF_TWO_PI 6.28318530717958647692f
#define NF_INV_FOUR_PI 0.0795774715459476679f
#define NF_SPLINE_MIN 1e-3f /* m in SPEC section 3: smallest bin width, height, derivative */

#define NF_MAX_RAW (3u * NF_MAX_SPLINE_BINS + 1u)
#define NF_MAX_SH (NF_MAX_SH_BANDS * NF_MAX_SH_BANDS)
#define NF_MAX_INPUT (4u * NF_MAX_ONEBLOB_BINS + 2u * NF_MAX_SH)
#define NF_MAX_ACTIVATIONS (NF_MAX_HIDDEN_LAYERS * NF_MAX_HIDDEN_WIDTH)

/* ---- the model ------------------------------------------------------------------------ */

struct nf_model {
    nf_config cfg;          /* validated; cfg.allocator resolved to real functions         */
    uint32_t input_dim;     /* conditioner input: 4 B + 2 S^2                               */
    uint32_t raw_dim;       /* conditioner output: 3 K + 1                                  */
    size_t layer_params;    /* parameters of one coupling layer's conditioner               */
    size_t param_count;     /* coupling_layers * layer_params                               */
    uint64_t step;          /* AdamW steps taken                                            */
    float *params;          /* param_count; layout documented in train.h                    */
    float *adam_m;          /* param_count, first moments                                   */
    float *adam_v;          /* param_count, second moments                                  */
    float *grad;            /* param_count, scratch of nf_train_step                        */
    float *staging;         /* 3 * param_count, scratch of nf_apply_gradient (p, m, v)      */
};

/* Offsets of one linear layer inside a coupling layer's parameter block. */
typedef struct nf_linear {
    size_t weight;  /* offset of W[in][out] (input-major) */
    size_t bias;    /* offset of b[out]                   */
    uint32_t in, out;
} nf_linear;

/* The j-th linear layer (0 = input layer, hidden_layers = output layer) of coupling layer
 * `layer`, with offsets from the start of the model's parameter array. */
nf_linear nf_model_linear(const nf_model *m, uint32_t layer, uint32_t j);

/* Size of a coupling layer's parameters for a config (assumed valid). */
size_t nf_layer_param_count(const nf_config *cfg);

/* Checks every field of a config; on failure records a message naming the field, prefixed
 * by `fn`, and returns NF_ERROR_INVALID_ARGUMENT. */
nf_status nf_config_validate(const nf_config *cfg, const char *fn);

/* Allocates a model for a validated config with zeroed parameters and optimizer state. */
nf_status nf_model_allocate(const nf_config *cfg, nf_model **out);

/* ---- errors ----------------------------------------------------------------------------- */

/* Records a printf-style message for nf_last_error_message and returns `status`. */
nf_status nf_fail(nf_status status, const char *fmt, ...)
#if defined(__GNUC__) || defined(__clang__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- validation of batch inputs (validate.c) --------------------------------------------- */

int nf_all_finite(const float *v, size_t n);
nf_status nf_validate_contexts(const char *fn, size_t n, const nf_context *ctx);
nf_status nf_validate_directions(const char *fn, const char *name, size_t n, const float *dir);
nf_status nf_validate_batch_size(const char *fn, size_t n);

/* ---- math helpers (square.c) --------------------------------------------------------------- */

/* fminf/fmaxf are libm calls unless -ffinite-math-only; these compile to minss/maxss. For NaN
 * they return the second argument, which callers never rely on (inputs are validated). */
static inline float nf_minf(float a, float b) { return a < b ? a : b; }
static inline float nf_maxf(float a, float b) { return a > b ? a : b; }
static inline float nf_clampf(float v, float lo, float hi) { return nf_minf(nf_maxf(v, lo), hi); }

/* sin(pi x) for x in [0,1], accurate near both ends. */
float nf_sin_pi(float x);

/* ---- the spline (spline.c) ------------------------------------------------------------------ */

/* The knots of one spline, computed from its raw parameters. */
typedef struct nf_spline {
    uint32_t bins;
    float x[NF_MAX_SPLINE_BINS + 1];  /* knot abscissae, x[0] = 0, x[K] = 1          */
    float y[NF_MAX_SPLINE_BINS + 1];  /* knot ordinates, y[0] = 0, y[K] = 1          */
    float sw[NF_MAX_SPLINE_BINS];     /* softmax of the raw widths (for gradients)    */
    float sh[NF_MAX_SPLINE_BINS];     /* softmax of the raw heights                   */
    const float *raw_d;               /* K+1 raw derivatives, borrowed: only the two
                                         of the bin in use are ever transformed       */
} nf_spline;

/* Partial derivatives of y and log(dy/dx) at a point of bin k with respect to the bin's
 * local quantities. */
typedef struct nf_spline_partials {
    float dy_dx, dy_dxk, dy_dwk, dy_dyk, dy_dhk, dy_dd0, dy_dd1;
    float dl_dx, dl_dxk, dl_dwk, dl_dhk, dl_dd0, dl_dd1; /* l = log(dy/dx); dl/dyk = 0 */
    float dd0_draw, dd1_draw; /* d d_k / d raw_k and d d_{k+1} / d raw_{k+1} */
} nf_spline_partials;

/* `raw` must outlive `s`: the knot derivatives are computed from it on demand. */
void nf_spline_build(nf_spline *s, uint32_t bins, const float *raw);
uint32_t nf_spline_bin_of_x(const nf_spline *s, float x);
uint32_t nf_spline_bin_of_y(const nf_spline *s, float y);
/* y and log(dy/dx) at x in bin k. */
void nf_spline_eval(const nf_spline *s, uint32_t k, float x, float *y, float *log_dydx);
/* x in bin k with forward(x) = y. */
float nf_spline_solve(const nf_spline *s, uint32_t k, float y);
void nf_spline_partials_at(const nf_spline *s, uint32_t k, float x, nf_spline_partials *p);
/* Adds to raw_grad (3K+1) the gradient of  a*y + b*log(dy/dx)  (evaluated at x in bin k)
 * with respect to the raw parameters, given p from nf_spline_partials_at. */
void nf_spline_raw_backward(const nf_spline *s, uint32_t k, const nf_spline_partials *p,
                            float a, float b, float *raw_grad);

/* ---- encodings (encode.c) ------------------------------------------------------------------- */

/* The non-zero bins of a one-blob encoding: up to 3 (bin, value, d value / dv). */
typedef struct nf_blob {
    uint32_t count;
    uint32_t bin[3];
    float value[3];
    float dvalue[3];
} nf_blob;

void nf_oneblob_sparse(float v, uint32_t bins, nf_blob *out);
/* SH of a unit vector (no normalization). */
void nf_sh_unit(const float d[3], uint32_t bands, float *out);

/* ---- priors and shading-point features (prior.c, conditioner.c) --------------------------- */

/* A validated, normalized shading context and everything the conditioners share. */
typedef struct nf_point {
    nf_context ctx;            /* normal and wo normalized; position as given              */
    nf_blob position[3];       /* one-blob of each normalized position coordinate          */
    float sh[2 * NF_MAX_SH];   /* SH of normal, then of wo                                 */
} nf_point;

void nf_point_prepare(const nf_model *m, const nf_context *ctx, nf_point *pt);

/* Draws a latent point z on the square from the prior. Returns NF_ERROR_NUMERIC only for a
 * custom prior whose callback misbehaves. */
nf_status nf_prior_sample(const nf_model *m, const nf_point *pt, float u0, float u1, float z[2],
                          float *log_q);
/* log of the prior's density on the square at z, and (if grad != NULL) its gradient in z.
 * For custom priors NF_ERROR_NUMERIC if the callback returns a bad value. */
nf_status nf_prior_log_density(const nf_model *m, const nf_point *pt, const float z[2],
                               float *log_q, float grad[2]);

/* Conditioner MLP of coupling layer `layer`: raw spline parameters from the pass-through
 * coordinate v and the shading point. `act` receives the hidden activations
 * (hidden_layers * hidden_width) for a later backward pass. */
void nf_conditioner_forward(const nf_model *m, uint32_t layer, const nf_point *pt, float v,
                            float *act, float *raw);
/* Reverse mode: given the gradient of the loss w.r.t. raw (g_raw), adds parameter gradients
 * into grad (the whole model's gradient array) and returns d loss / d v. */
float nf_conditioner_backward(const nf_model *m, uint32_t layer, const nf_point *pt, float v,
                              const float *act, const float *g_raw, float *grad);

/* ---- the flow (flow.c) ---------------------------------------------------------------------- */

/* Forward map z -> s; returns log |det J_F(z)|. */
float nf_flow_forward(const nf_model *m, const nf_point *pt, const float z[2], float s[2]);
/* Inverse map s -> z; returns log |det J_{F^-1}(s)|. */
float nf_flow_inverse(const nf_model *m, const nf_point *pt, const float s[2], float z[2]);
/* log of the flow's density on the square at s; with grad != NULL, also adds
 * coef * d(log p_s)/d(params) into grad. */
nf_status nf_flow_log_density(const nf_model *m, const nf_point *pt, const float s[2],
                              float coef, float *grad, float *log_p);

#endif /* NISFLOW_INTERNAL_H */
