/*
 * internal.h - the model's memory layout and the interfaces between the library's modules.
 * Nothing here is installed; users see only include/nisflow/.
 *
 * The hot path (encodings, conditioners, splines, priors, the flow, shading points) is inline
 * code in src/kernels/, compiled once per instruction set by kernels/kernel.c; dispatch.c
 * picks the variant the CPU supports (docs/architecture.md draws the layers).
 *
 * Words: a pdf is per steradian (what crosses the API); a density is on the unit square.
 */
#ifndef NISFLOW_INTERNAL_H
#define NISFLOW_INTERNAL_H

#include <math.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "nisflow/nisflow.h"
#include "shading_point.h"

#define NF_PI 3.14159265358979323846f
#define NF_TWO_PI 6.28318530717958647692f
#define NF_HALF_PI 1.57079632679489661923f
#define NF_INV_FOUR_PI 0.0795774715459476679f
#define NF_TWO_PI_SQUARED 19.7392088021787172f
#define NF_SPLINE_MIN                                                                              \
    1e-3f /* m in docs/theory.md section 3: smallest bin width, height, derivative */
/* The conditioners' raw spline parameters are clamped to [-NF_RAW_LIMIT, NF_RAW_LIMIT] (NaN,
 * which an overflowing MLP can produce from extreme but finite weights, becomes the lower
 * bound). Widths and heights saturate long before (softmax differences beyond ~87 are
 * clamped by nf_fast_exp), and knot derivatives up to ~1e4 keep every spline slope within
 * [~1e-17, ~1e8] in float, so products over NF_MAX_COUPLING_LAYERS layers stay finite and
 * non-zero in double. Trained models stay orders of magnitude inside this bound. */
#define NF_RAW_LIMIT 1e4f

/* Per-lane helpers that the tile kernels call inside their loops over lanes must be inlined,
 * or the loops do not vectorize. GCC's heuristics alone are not enough: in libnisflow 0.1 they
 * left nf_to_square out of line in nf_sample's cosine-prior loop, 27% of the time of a batch
 * (docs/performance.md, "Measurements behind the kernels"). */
#if defined(__GNUC__) || defined(__clang__)
#define NF_ALWAYS_INLINE inline __attribute__((always_inline))
#else
#define NF_ALWAYS_INLINE inline
#endif

#define NF_MAX_RAW (3u * NF_MAX_SPLINE_BINS + 1u)
#define NF_MAX_SH (NF_MAX_SH_BANDS * NF_MAX_SH_BANDS)
#define NF_MAX_INPUT (4u * NF_MAX_ONEBLOB_BINS + 2u * NF_MAX_SH)
#define NF_MAX_ACTIVATIONS (NF_MAX_HIDDEN_LAYERS * NF_MAX_HIDDEN_WIDTH)

/* The kernels accumulate 16 outputs at a time (one AVX-512 register, two AVX2 ones), so the
 * packed weights pad every output dimension to a multiple of it. */
#define NF_CHUNK 16u
#define NF_PAD(n) (((n) + NF_CHUNK - 1u) / NF_CHUNK * NF_CHUNK)
#define NF_MAX_RAW_PADDED NF_PAD(NF_MAX_RAW)

/* ---- the model ------------------------------------------------------------------------ */

/* One linear layer inside a parameter array: W[in][stride] (input-major, columns >= out are
 * zero padding) followed by b[stride]. In the public layout stride = out. */
typedef struct nf_linear {
    size_t weight, bias;
    uint32_t in, out, stride;
} nf_linear;

typedef struct nf_kernels nf_kernels;

/* The constants of one AdamW step (docs/theory.md section 6), computed by nf_apply_gradient. */
typedef struct nf_adamw_step {
    float beta1, beta2, epsilon;
    float step_size;      /* learning_rate / (1 - beta1^t)     */
    float inv_sqrt_bias2; /* 1 / sqrt(1 - beta2^t)             */
    float decay;          /* 1 - learning_rate * weight_decay  */
} nf_adamw_step;

struct nf_model {
    nf_config cfg;       /* validated; cfg.allocator resolved to real functions         */
    uint32_t input_dim;  /* conditioner input: 4 B + 2 S^2                               */
    uint32_t raw_dim;    /* conditioner output: 3 K + 1                                  */
    size_t layer_params; /* parameters of one coupling layer's conditioner               */
    size_t param_count;  /* coupling_layers * layer_params                               */
    size_t packed_count; /* floats in `packed`                                           */
    uint64_t step;       /* AdamW steps taken                                            */
    uint64_t id;         /* unique among the models of this process (nf_model_allocate)  */
    /* Counts changes of the packed weights, twice per change: odd while one is being written
     * (nf_generation_begin .. nf_generation_end), even when they are stable. Shading points
     * record it; a point or a call that saw an odd value or another value than the model has
     * after it is stale, so that a call that overlapped a training step on another thread
     * is refused (NF_ERROR_STALE), never accepted with a mix of two models' weights. */
    atomic_uint_least64_t generation;
    const nf_kernels *kernels;
    /* [layer][j]: j = 0 input layer, j = hidden_layers output layer */
    nf_linear linear[NF_MAX_COUPLING_LAYERS][NF_MAX_HIDDEN_LAYERS + 1]; /* public layout */
    nf_linear packed_linear[NF_MAX_COUPLING_LAYERS][NF_MAX_HIDDEN_LAYERS + 1];
    /* params, adam_m and adam_v are one bank of 3 * param_count floats, staging the other;
     * nf_apply_gradient writes a step into staging and then exchanges the banks, so these
     * pointers change with every step (nothing may keep them). */
    float *params;  /* param_count; layout documented in train.h                    */
    float *packed;  /* the same weights, padded for the kernels; see nf_model_pack  */
    float *adam_m;  /* param_count, first moments                                   */
    float *adam_v;  /* param_count, second moments                                  */
    float *grad;    /* param_count, scratch of nf_train_step                        */
    float *staging; /* 3 * param_count, scratch of nf_apply_gradient (p, m, v)      */
};

/* The generation as a reader sees it before it reads the packed weights (acquire: the
 * weights it then reads are at least as new). */
static inline uint64_t nf_generation_read(const nf_model *m)
{
    return (uint64_t)atomic_load_explicit(&((nf_model *)m)->generation, memory_order_acquire);
}

/* Whether the weights may have changed since a reader saw generation `seen`: called after the
 * reads, it is 1 when `seen` was odd (a change was running) or a change began since. */
static inline int nf_generation_moved(const nf_model *m, uint64_t seen)
{
    atomic_thread_fence(memory_order_acquire);
    uint64_t now =
        (uint64_t)atomic_load_explicit(&((nf_model *)m)->generation, memory_order_relaxed);
    return (seen & 1u) != 0u || now != seen;
}

/* A writer's bracket around every change of the packed weights or the kernels. */
static inline void nf_generation_begin(nf_model *m)
{
    atomic_fetch_add_explicit(&m->generation, 1u, memory_order_relaxed);
    atomic_thread_fence(memory_order_seq_cst); /* the odd value before any weight is written */
}

static inline void nf_generation_end(nf_model *m)
{
    atomic_fetch_add_explicit(&m->generation, 1u, memory_order_release);
}

/* Size of a coupling layer's parameters for a config (assumed valid). */
size_t nf_layer_param_count(const nf_config *cfg);

/* Checks every field of a config; on failure records a message naming the field, prefixed
 * by `fn`, and returns NF_ERROR_INVALID_ARGUMENT. */
nf_status nf_config_validate(const nf_config *cfg, const char *fn);

/* Allocates a model for a validated config with zeroed parameters and optimizer state; `fn`
 * prefixes the message of a refusal (an unsupported cfg->isa, no memory). */
nf_status nf_model_allocate(const nf_config *cfg, const char *fn, nf_model **out);

/* malloc and free as an nf_allocator: what a zeroed allocator resolves to (model.c). */
nf_allocator nf_default_allocator(void);

/* Rebuilds the packed weights from params; every change of params must call it. */
void nf_model_pack(nf_model *m);

/* ---- errors ----------------------------------------------------------------------------- */

/* Records a printf-style message for nf_last_error_message and returns `status`. */
nf_status nf_fail(nf_status status, const char *fmt, ...)
#if defined(__GNUC__) || defined(__clang__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- validation of batch inputs (validate.c) --------------------------------------------- */

/* Validates n training samples (nisflow/train.h): the arrays non-NULL unless n = 0, finite
 * contexts and directions, weights finite and >= 0. *total (may be NULL) receives the
 * weights' sum and *positive (may be NULL) how many are > 0. */
nf_status nf_validate_samples(const char *fn, size_t n, const nf_context *ctx, const float *dir,
                              const float *weight, double *total, size_t *positive);

/* Refuses the first NULL among up to four named pointers (a NULL name ends the list) with a
 * message that names it: "nf_sample: dir is NULL". NF_OK when none is NULL. */
nf_status nf_check_pointers(const char *fn, const char *name0, const void *p0, const char *name1,
                            const void *p1, const char *name2, const void *p2, const char *name3,
                            const void *p3);

int nf_all_finite(const float *v, size_t n);

/* nf_all_finite's test, inline for the kernels (which compile it per instruction set). A float
 * is NaN or Inf exactly when its exponent bits are all ones; OR-ing that test over the array
 * is associative, so the loop vectorizes, where a float sum of v[i] * 0 could not be reordered
 * and runs at one add latency per element. */
static inline int nf_floats_finite(const float *v, size_t n)
{
    uint32_t bad = 0;
    for (size_t i = 0; i < n; ++i) {
        uint32_t bits;
        memcpy(&bits, &v[i], sizeof bits);
        bad |= (uint32_t)((bits & 0x7f800000u) == 0x7f800000u);
    }
    return bad == 0;
}
nf_status nf_validate_contexts(const char *fn, size_t n, const nf_context *ctx);
nf_status nf_validate_directions(const char *fn, const char *name, size_t n, const float *dir);
nf_status nf_validate_batch_size(const char *fn, size_t n);

/* ---- small helpers ------------------------------------------------------------------------ */

/* fminf/fmaxf are libm calls unless -ffinite-math-only; these compile to minss/maxss. For NaN
 * they return the second argument, which callers never rely on (inputs are validated). */
static inline float nf_minf(float a, float b) { return a < b ? a : b; }
static inline float nf_maxf(float a, float b) { return a > b ? a : b; }
static inline float nf_clampf(float v, float lo, float hi) { return nf_minf(nf_maxf(v, lo), hi); }

/* v / |v| with one rounding per component. Double cannot overflow or underflow on the
 * squares of finite floats, and inputs are validated non-zero upstream. */
static inline void nf_normalize3(const float v[3], float out[3])
{
    double x = v[0], y = v[1], z = v[2];
    double inv = 1.0 / sqrt(x * x + y * y + z * z);
    out[0] = (float)(x * inv);
    out[1] = (float)(y * inv);
    out[2] = (float)(z * inv);
}

/* The non-zero bins of a one-blob encoding: up to 3 (bin, value, d value / dv). */
typedef struct nf_blob {
    uint32_t count;
    uint32_t bin[3];
    float value[3];
    float dvalue[3];
} nf_blob;

/* What a prior needs of a shading point: the context its callbacks receive, the callbacks,
 * the unit normal (the cosine prior on surfaces; zero in a medium), and at a point in a
 * medium the propagation direction and the phase function's g (the cosine prior's
 * Henyey-Greenstein branch, docs/theory.md section 2). On surfaces medium is 0 and axis and g
 * are zero, never the caller's phase_g. */
typedef struct nf_prior_point {
    const nf_context *user;
    const nf_prior_callbacks *prior;
    float normal[3];
    uint32_t medium; /* 1 at a point in a participating medium           */
    float axis[3];   /* in a medium: d = -wo / |wo|, where light travels  */
    float g;         /* in a medium: the Henyey-Greenstein asymmetry      */
} nf_prior_point;

/* A context whose normal is exactly (0, 0, 0) is a point in a participating medium
 * (nisflow/model.h). Negative zeros count as zero. */
static inline int nf_context_in_medium(const nf_context *c)
{
    return (c->normal[0] == 0.0f) & (c->normal[1] == 0.0f) & (c->normal[2] == 0.0f);
}

/* A validated, normalized shading context and everything the conditioners share. */
typedef struct nf_point {
    const nf_context *user;          /* the caller's context, passed on to custom prior callbacks */
    const nf_prior_callbacks *prior; /* the custom prior's callbacks for this context      */
    nf_context ctx;                  /* normal and wo normalized; position as given              */
    uint32_t rows[9];                /* input rows of the position one-blobs: 3 slots per axis   */
    float values[9];                 /* (nf_oneblob_slots; 0 where a slot is outside)            */
    uint32_t row_count;              /* 9                                                        */
    float sh[2 * NF_MAX_SH];         /* SH of normal, then of wo                                 */
} nf_point;

/* ---- shading points (point.c, point.h) ---------------------------------------------- */

#define NF_POINT_MAGIC 0x4e465054u /* "NFPT" */
#define NF_TABLE_MAGIC 0x4e465442u /* "NFTB" */

/* The cell of x in [0, 1) on n cells, x outside clamped to the ends; NaN (a corrupted table)
 * lands in cell 0. The comparisons keep the float-to-integer conversion defined. */
static inline uint32_t nf_table_cell(float x, uint32_t n)
{
    if (!(x > 0.0f))
        return 0;
    float c = x * (float)n;
    return c < (float)(n - 1) ? (uint32_t)c : n - 1;
}

/* Whether point p may be used with m (its header intact, prepared on m, m's parameters not
 * changed since): NF_OK, or the status and message of fn's refusal; i names the point in the
 * message (SIZE_MAX: the only one). point.c; table.c asks it too. */
nf_status nf_point_usable(const char *fn, const nf_model *m, const nf_shading_point *p, size_t i);

/* st, or NF_ERROR_STALE when m's parameters moved since generation `seen` (a call that
 * overlapped a change on another thread read a mix of two models). */
nf_status nf_point_checked(const char *fn, const nf_model *m, uint64_t seen, nf_status st);

/* A hash of every field of a point before check_ (context, identity, prior callbacks, normal,
 * cache mode), so that a point whose header was overwritten (or never written) is refused
 * rather than read with a wrong normal, context or callback. A sum of the header's 64-bit
 * words times distinct odd constants: any change of a single word changes it, and the
 * multiplies are independent, so the check costs a few cycles of latency per call. On
 * 64-bit targets the header is 104 bytes without padding (asserted in point.c), read as 13
 * words; elsewhere field by field, since struct padding need not survive a copy. */
static inline uint32_t nf_point_hash(const nf_shading_point *p)
{
    uint64_t h = 0;
#if UINTPTR_MAX == UINT64_MAX
    enum { NF_POINT_HEADER_WORDS = offsetof(nf_shading_point, check_) / 8 };
    const unsigned char *bytes = (const unsigned char *)p;
    for (uint32_t i = 0; i < NF_POINT_HEADER_WORDS; ++i) {
        uint64_t w;
        memcpy(&w, bytes + 8 * i, sizeof w);
        h += w * (0x9e3779b97f4a7c15u + 2u * (uint64_t)i * 0x6a09e667f3bcc909u);
    }
#else
    uint32_t w[32], n = 0;
    memcpy(w, &p->context_, sizeof p->context_); /* 10 floats */
    n = (uint32_t)(sizeof p->context_ / sizeof w[0]);
    w[n++] = p->magic_;
    w[n++] = (uint32_t)p->model_id_;
    w[n++] = (uint32_t)(p->model_id_ >> 32);
    w[n++] = (uint32_t)p->generation_;
    w[n++] = (uint32_t)(p->generation_ >> 32);
    w[n++] = (uint32_t)(uintptr_t)p->prior_.sample;
    w[n++] = (uint32_t)(uintptr_t)p->prior_.pdf;
    w[n++] = (uint32_t)(uintptr_t)p->prior_.user;
    memcpy(w + n, p->frame_, sizeof p->frame_);
    n += 3;
    w[n++] = p->cached_;
    for (uint32_t i = 0; i < n; ++i)
        h += (uint64_t)w[i] * (0x9e3779b97f4a7c15u + 2u * (uint64_t)i * 0x6a09e667f3bcc909u);
#endif
    return (uint32_t)(h ^ (h >> 32));
}

/* Makes dst equal to src without allocating: parameters, optimizer state (moments, step
 * count) and the optimizer's settings (learning rate, weight decay). Both must share their
 * architecture, prior (with its epsilon), phi map and bounds (NF_ERROR_INVALID_ARGUMENT
 * otherwise, dst unchanged); dst keeps its own allocator, callbacks and instruction set.
 * Every point prepared on dst becomes stale. For resetting a model to a saved state, or
 * publishing one model's training into another that render threads sample between passes.
 * Not thread-safe for dst (no other call may use it meanwhile); src is only read. */
nf_status nf_model_copy(nf_model *dst, const nf_model *src);

#endif /* NISFLOW_INTERNAL_H */
