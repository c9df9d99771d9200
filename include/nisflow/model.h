/*
 * nisflow/model.h - the model: configuration, life cycle, sampling and density evaluation.
 *
 * A model is a normalizing flow over directions, conditioned on a shading context. It maps a
 * latent point drawn from a prior to a direction (nf_sample) and evaluates the density of any
 * direction (nf_pdf). All densities that cross this API are solid-angle densities (per
 * steradian), as in pbrt and Mitsuba. See docs/theory.md for the mathematics.
 *
 * Thread-safety: functions taking a `const nf_model *` may run concurrently on one model from
 * any number of threads, provided no thread modifies it at the same time (training, set
 * params, set isa, destroy). nf_sample and nf_pdf never allocate memory.
 */
#ifndef NISFLOW_MODEL_H
#define NISFLOW_MODEL_H

#include <stddef.h>
#include <stdint.h>

#include "version.h"
#include "status.h"

NF_EXTERN_C_BEGIN

/* Limits of the configuration, chosen so that all per-sample scratch fits on the stack. */
#define NF_MAX_COUPLING_LAYERS 16u
#define NF_MAX_SPLINE_BINS 64u
#define NF_MAX_HIDDEN_LAYERS 8u
#define NF_MAX_HIDDEN_WIDTH 128u
#define NF_MAX_ONEBLOB_BINS 64u
#define NF_MAX_SH_BANDS 6u

/* Ranges of the configuration's floats, checked by nf_model_create, nf_model_load /
 * nf_model_deserialize (as NF_ERROR_FORMAT) and nf_model_set_learning_rate, with a message naming
 * the field and its range. Every float field also refuses NaN, infinities and denormals. Each bound
 * keeps the arithmetic the value feeds away from underflow and overflow (the reasons:
 * docs/robustness.md, "Configuration ranges"). */
#define NF_PRIOR_EPSILON_MIN 1e-6f /* eps / (4 pi) >= 8e-8 per sr: a floor, not an underflow  */
#define NF_LEARNING_RATE_MIN 1e-9f /* below, a step is under half an ulp of any weight > 0.03 */
#define NF_LEARNING_RATE_MAX 1.0f  /* AdamW moves a weight by about lr per step               */
#define NF_BETA1_MAX 0.9999f       /* bias correction 1 - beta1^t >= 1e-4: step <= 1e4 lr      */
#define NF_BETA2_MAX 0.99999f      /* 1 - beta2^t >= 1e-5: 1 / sqrt of it <= 317              */
#define NF_ADAM_EPSILON_MIN 1e-12f /* m / eps stays small where v underflowed to 0            */
#define NF_ADAM_EPSILON_MAX 1.0f   /* beyond, AdamW is plain SGD with a tiny step              */
#define NF_WEIGHT_DECAY_MAX 100.0f /* with learning_rate * weight_decay < 1                   */

/* An opaque model. Create with nf_model_create, nf_model_clone or nf_model_load; destroy with
 * nf_model_destroy. */
typedef struct nf_model nf_model;

/* A shading context. `position` is in world units (normalized by the config's scene bounds
 * and clamped to them). `normal` is the shading normal and `wo` the direction towards the
 * previous vertex (pointing away from the surface). Both must be finite and non-zero (a
 * squared length above 1e-30); they are normalized by the library, so unit length is expected
 * but not required.
 *
 * A point in a participating medium (a volume vertex) has no surface: its normal is exactly
 * (0, 0, 0) (negative zeros too) and phase_g holds the medium's Henyey-Greenstein g there.
 * Every entry point takes such contexts, mixed freely with surface contexts in one batch.
 * The encodings see the position and wo as on surfaces and the normal's SH block as all
 * zeros, a value no unit normal produces, so one network tells media from surfaces; the
 * cosine prior is the phase function there (NF_PRIOR_COSINE). A normal that is not finite,
 * or non-zero but too short to normalize, is still refused. docs/integration.md, "Volume
 * vertices"; docs/theory.md section 2, "Media". */
typedef struct nf_context {
    float position[3];
    float normal[3];
    float wo[3];
    /* The Henyey-Greenstein asymmetry of the medium at a point in a participating medium:
     * finite, |phase_g| <= NF_PHASE_G_MAX. On surfaces it is never read (any value, so that
     * contexts filled before 0.5.0 stay valid); zero-initialise it. (Added in 0.5.0: a brace
     * initializer of the three members before it leaves it 0, and gcc's -Wextra asks for it by
     * name.) */
    float phase_g;
} nf_context;

/* The largest |phase_g| a context may carry: beyond it the phase function's peak is too
 * narrow for float directions. */
#define NF_PHASE_G_MAX 0.99f

/* The prior (latent density) of the flow. Values are explicit and never renumbered. */
typedef enum nf_prior_kind {
    NF_PRIOR_UNIFORM_DIRECTION = 0, /* 1/(4 pi) per steradian                                */
    NF_PRIOR_UNIFORM_ANGLE = 1,     /* uniform on the (theta, phi) square                     */
    NF_PRIOR_COSINE = 2,            /* max(0, n.w)/pi around the context's normal, eps-mixed;
                                       in a medium the Henyey-Greenstein phase function
                                       (1 - g^2) / (4 pi (1 + g^2 - 2 g w.d)^(3/2)) around
                                       d = -wo/|wo|, g = phase_g, eps-mixed alike (g = 0:
                                       uniform); docs/theory.md section 2, "Media"      */
    NF_PRIOR_CUSTOM = 3             /* user callbacks (for example a BSDF lobe), eps-mixed    */
} nf_prior_kind;
/* Transmission. The cosine prior covers only the hemisphere of the context's normal: its
 * eps-mixed uniform part (prior_epsilon of the mass, over the whole sphere) puts just eps / 2
 * below the surface, and a flow must learn to move mass there, which trains poorly. For glass,
 * thin translucent and other transmissive surfaces choose a prior that covers both
 * hemispheres: NF_PRIOR_UNIFORM_DIRECTION (simplest; NF_PRIOR_UNIFORM_ANGLE also covers the
 * sphere, denser towards the z poles), or NF_PRIOR_CUSTOM with a BSDF lobe whose density is
 * positive on both sides (reflection and transmission lobes mixed by their probabilities).
 * The prior is per model: a scene with opaque and transmissive materials can keep a model
 * per kind. docs/model-layer.md, section 5. */

/* How the flow treats the seam phi = 0 of its square (theta / pi, phi / 2 pi), docs/theory.md
 * section 4. Values are explicit and never renumbered. */
typedef enum nf_phi_map {
    /* The splines of phi / 2 pi are maps of [0, 1] onto itself, so phi = 0 is a fixed point of
     * every layer and the density there is the prior's times the end slopes: a lobe across the
     * seam is built from two pieces at opposite edges of the square. The only choice of model
     * format version 1. */
    NF_PHI_INTERVAL = 0,
    /* phi is a coordinate on the circle: each spline of phi / 2 pi has equal slopes at 0 and
     * 1, the last one is followed by a learned turn of the circle (its last conditioner
     * output, which NF_PHI_INTERVAL spends on the slope at 1), and the conditioners see phi
     * through a one-blob that wraps around. Mass moves across phi = 0, and the density is
     * continuous there. Same parameter count and kernels. (default) */
    NF_PHI_CIRCULAR = 1
} nf_phi_map;

/* A user prior in solid-angle terms (docs/theory.md section 2). The library mixes it with the
 * uniform direction density: q = (1 - eps) q_custom + eps / (4 pi), eps = nf_config.prior_epsilon.
 *
 * sample: maps (u0, u1) in [0,1)^2 deterministically to a direction `dir` (unit length, world
 *         space) and returns the solid-angle density of that direction, which must be finite
 *         and > 0. A sampler that cannot produce a direction (a BSDF lobe below the surface,
 *         say) must fall back to some valid direction of its own; the library refuses the
 *         batch with NF_ERROR_NUMERIC when it returns a density <= 0 or a non-finite value.
 * pdf:    the solid-angle density of `dir`, finite and >= 0. It must agree with what `sample`
 *         returns for the directions it draws: nf_sample reports the sample callback's value,
 *         nf_pdf and training the pdf callback's.
 * ctx:    the caller's own context, never a copy the library made: for nf_sample, nf_pdf,
 *         and nf_train_step it is &ctx[i] of the array the caller passed, for
 *         sample i (every batch size, every instruction set), and for nf_model_prior_pdf the
 *         pointer passed; normal and wo are as the caller gave them (not normalized).
 *         `ctx - base` is therefore the sample's index, through which a renderer can reach
 *         per-sample data such as the shading point's BSDF. Through a vertex object
 *         (vertex.h) it points to the object's copy of the vertex's context; per-vertex
 *         data travel there in the vertex's own callbacks' `user`.
 *         tests/correctness/test_prior_context.c checks every entry point.
 * user:   passed back unchanged; the library never dereferences or frees it.
 * Both callbacks are called from whichever threads call nf_sample / nf_pdf / training, and
 * must therefore be thread-safe themselves. They must not call back into the same model's
 * mutating functions. */
typedef struct nf_prior_callbacks {
    float (*sample)(void *user, const nf_context *ctx, float u0, float u1, float dir[3]);
    float (*pdf)(void *user, const nf_context *ctx, const float dir[3]);
    void *user;
} nf_prior_callbacks;

/* An optional allocator. With both functions NULL the library uses malloc and free. A model's
 * memory is allocated when it is created, cloned or loaded; afterwards only nf_model_save
 * allocates (a temporary buffer the size of the file, freed before it returns), so an
 * allocator shared by models saved from several threads must be thread-safe. nf_model_load
 * reads through malloc whatever the allocator. `free` receives only pointers that `alloc`
 * returned, and never NULL. */
typedef struct nf_allocator {
    void *(*alloc)(void *user, size_t size);
    void (*free)(void *user, void *ptr);
    void *user;
} nf_allocator;

/* Model presets (docs/theory.md section 7). Values are explicit and never renumbered. */
typedef enum nf_preset {
    NF_PRESET_SMALL = 0, /* the paper's model: 2 coupling layers, 8 bins, 1 hidden layer of 16 */
    NF_PRESET_LARGE = 1  /* 4 coupling layers, 16 bins, 2 hidden layers of 16                  */
} nf_preset;

/* The instruction set of the sample / pdf / gradient kernels. The library ships one copy of
 * the kernels per set and picks the best the CPU supports (NF_ISA_AUTO); naming one is for
 * tests, benchmarks and reproducibility. AVX2 and AVX-512 give bit-identical results (both
 * fuse the conditioners' multiply-adds); the generic kernels round those twice and differ by
 * about 1e-6 relative. A render farm mixing CPUs with and without AVX2 that needs identical
 * results can name NF_ISA_GENERIC everywhere (nf_model_set_isa for loaded models). Values are
 * explicit and never renumbered. */
typedef enum nf_isa {
    NF_ISA_AUTO = 0,    /* the best available (default)                                   */
    NF_ISA_GENERIC = 1, /* portable C, the compiler's baseline for the target             */
    NF_ISA_AVX2 = 2,    /* x86-64 with AVX2 and FMA                                       */
    NF_ISA_AVX512 = 3   /* x86-64 with AVX-512 F/VL/DQ/BW                                 */
} nf_isa;

/* Everything needed to create a model. Fill it with nf_config_init, then change fields. */
typedef struct nf_config {
    uint32_t coupling_layers; /* L, 1..NF_MAX_COUPLING_LAYERS                                 */
    uint32_t spline_bins;     /* K, 2..NF_MAX_SPLINE_BINS                                     */
    uint32_t hidden_layers;   /* hidden layers per conditioner MLP, 1..NF_MAX_HIDDEN_LAYERS   */
    uint32_t hidden_width;    /* neurons per hidden layer, 1..NF_MAX_HIDDEN_WIDTH             */
    uint32_t oneblob_bins;    /* B, 2..NF_MAX_ONEBLOB_BINS (default 32)                       */
    uint32_t sh_bands;        /* S, 0..NF_MAX_SH_BANDS, S*S values per direction (default 4)  */
    nf_prior_kind prior;      /* default NF_PRIOR_COSINE                                      */
    float prior_epsilon;      /* defensive mixture weight for cosine/custom,
                                 [NF_PRIOR_EPSILON_MIN = 1e-6, 1] (default 0.01)             */
    nf_prior_callbacks custom_prior; /* required when prior == NF_PRIOR_CUSTOM                 */
    nf_phi_map phi_map;     /* the seam phi = 0: NF_PHI_INTERVAL or NF_PHI_CIRCULAR (default) */
    float bounds_min[3];    /* scene bounds for the position encoding, world units: finite,  */
    float bounds_max[3];    /* max - min in [FLT_MIN, FLT_MAX] on every axis (default the unit
                               cube)                                                          */
    float learning_rate;    /* AdamW, [1e-9, 1] (default 1e-3)                                */
    float beta1, beta2;     /* AdamW, beta1 in [0, 0.9999], beta2 in [0, 0.99999] (defaults 0.9,
                               0.999)                                                         */
    float adam_epsilon;     /* AdamW, [1e-12, 1] (default 1e-8)                               */
    float weight_decay;     /* AdamW decoupled decay, [0, 100] with learning_rate * weight_decay
                               < 1, so the decay factor stays positive (default 0.01)         */
    uint64_t seed;          /* seed of the weight initialisation (default 1)                */
    nf_allocator allocator; /* optional; not saved with the model                          */
    nf_isa isa;             /* kernels to use (default NF_ISA_AUTO); not saved: a loaded
                               model runs NF_ISA_AUTO until nf_model_set_isa             */
} nf_config;

/* Fills `cfg` with the preset's architecture and the defaults above. `cfg` NULL is ignored.
 * Thread-safe. */
NF_API void nf_config_init(nf_config *cfg, nf_preset preset);

/* Validates `cfg` and creates a model whose flow is the identity, so that its density equals
 * its prior's density. The hidden layers are initialised like PyTorch's nn.Linear from an RNG
 * seeded with cfg->seed; the last layer of every conditioner is zero. On success *out owns the
 * new model; on failure *out is NULL and the status says why (NF_ERROR_INVALID_ARGUMENT for a
 * bad config, NF_ERROR_OUT_OF_MEMORY). Thread-safe. */
NF_API nf_status nf_model_create(const nf_config *cfg, nf_model **out);

/* Frees everything the model owns, with the allocator it was created with. NULL is a no-op.
 * Not thread-safe with respect to other calls on the same model. */
NF_API void nf_model_destroy(nf_model *model);

/* A deep copy: configuration, parameters and optimizer state. *out is NULL on failure.
 * Thread-safe with respect to other const calls on `model`. */
NF_API nf_status nf_model_clone(const nf_model *model, nf_model **out);

/* Copies the model's configuration (including its allocator and custom prior callbacks) to
 * *out. Thread-safe. */
NF_API nf_status nf_model_get_config(const nf_model *model, nf_config *out);

/* Draws n directions. For sample i, u[2i], u[2i+1] are two numbers in [0,1) (values outside
 * are clamped), ctx[i] its shading context; dir[3i..3i+2] receives a unit vector and, if pdf
 * is not NULL, pdf[i] the solid-angle density of that direction, equal to what nf_pdf returns
 * for it: away from the poles (sin theta > 1e-2) the relative difference is below 1e-4 for
 * well-conditioned flows. pdf[i] belongs to the exact latent point, nf_pdf's value to the
 * inverse of the float direction; on sharp flows the float round trip drifts: on randomized
 * flows (tests/correctness/test_sampling.c) no sample differs by 1e-2; on trained sharp flows
 * (tests/correctness/test_sample_pdf_trained.c) rare samples differ by more than 1e-2 and
 * isolated ones by tens of percent, at the flat end of a spline where the float round trip
 * through the turn lands far off in latent space (docs/robustness.md has the measured
 * counts). One-sample MIS tolerates both. Densities are
 * clamped to [FLT_MIN, FLT_MAX], so that pdf and 1 / pdf are finite whatever the parameters
 * (docs/robustness.md). The map from u to dir is deterministic, and bit-identical however a
 * batch is split into calls (batches run in groups of 16 samples, calls of 1 or 2 samples per
 * sample, with the same arithmetic). n = 0 is a no-op (pointers may then be NULL). The whole
 * batch is validated before anything is written: on NF_ERROR_INVALID_ARGUMENT no output is
 * written. The one error that can arise mid-batch is NF_ERROR_NUMERIC from a custom prior
 * callback returning an invalid value; the outputs of earlier groups of 16 samples are then
 * written, those of the failing sample's group and later ones are not.
 * Thread-safe on a const model; never allocates; uses about 56 KiB of the caller's stack. A
 * call that overlaps a change of the model on another thread (a training step: misuse, see
 * guide.h for training while sampling) is refused with NF_ERROR_STALE, its outputs
 * unspecified, rather than answered with a mix of two models. */
NF_API nf_status nf_sample(const nf_model *m, size_t n, const nf_context *ctx, const float *u,
                           float *dir, float *pdf);

/* Evaluates the solid-angle density of n directions: pdf[i] = p(dir[3i..3i+2] | ctx[i]).
 * Directions must be finite and non-zero (a squared length above 1e-30); they are normalized
 * by the library, and any length gives the same density. Near the poles sin(theta) is
 * clamped to NF_SIN_THETA_MIN, and densities are clamped to [FLT_MIN, FLT_MAX] as in
 * nf_sample, so they stay finite and positive. n = 0 is a no-op. On
 * NF_ERROR_INVALID_ARGUMENT pdf is not written; NF_ERROR_NUMERIC (a custom prior callback
 * returned an invalid value) may come after earlier entries were written. Results are
 * bit-identical however a batch is split into calls, as for nf_sample.
 * Thread-safe on a const model; never allocates; uses about 56 KiB of the caller's stack.
 * Overlapping a change of the model: NF_ERROR_STALE, as nf_sample. */
NF_API nf_status nf_pdf(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                        float *pdf);

/* The solid-angle density of the model's prior (with its epsilon mixture) at `dir` into
 * *pdf: the density a fresh model has, clamped to [FLT_MIN, FLT_MAX] as nf_pdf's (with
 * prior_epsilon >= NF_PRIOR_EPSILON_MIN it is at least 1e-6 / (4 pi) for the cosine and custom
 * priors wherever the custom density is 0). ctx and dir follow nf_pdf's rules. Errors:
 * NF_ERROR_INVALID_ARGUMENT (NULL, a bad context or direction), NF_ERROR_NUMERIC (a custom
 * prior's pdf callback returned an invalid value); *pdf is then not written.
 * Thread-safe; never allocates. */
NF_API nf_status nf_model_prior_pdf(const nf_model *m, const nf_context *ctx, const float dir[3],
                                    float *pdf);

/* The name of the kernels the model runs ("generic", "avx2", "avx512"). Static string;
 * "" for NULL. Thread-safe. */
NF_API const char *nf_model_isa_name(const nf_model *m);

/* Switches the model to the kernels of `isa`, as if it had been created with nf_config.isa =
 * isa. This is how a loaded model (nf_model_load and nf_model_deserialize pick NF_ISA_AUTO,
 * since the file does not store the set) chooses its instruction set: a render farm that
 * mixes CPUs resumes a checkpoint to identical results by calling
 * nf_model_set_isa(m, NF_ISA_GENERIC) on every machine (or NF_ISA_AVX2 where all have it;
 * AVX2 and AVX-512 give the same bits). Parameters, optimizer state and step count are kept;
 * later samples, densities, gradients and steps are bit-identical to those of a model created
 * with that isa from the same state. nf_model_get_config reports the new isa; a clone keeps it.
 * Shading points prepared before a change of kernels become stale (NF_ERROR_STALE), since
 * their cached sums came from the old kernels; setting the isa the model already runs
 * changes nothing. Errors, which leave the model unchanged: NF_ERROR_INVALID_ARGUMENT for
 * NULL, a value that is not an nf_isa, or a set this CPU or build cannot run (the message
 * names what is missing, for example "AVX2 and FMA"). Not thread-safe: it modifies the model,
 * so no other call may use `m` meanwhile (like nf_train_step). Never allocates. */
NF_API nf_status nf_model_set_isa(nf_model *m, nf_isa isa);

/* The smallest value of sin(theta) the library divides by when it converts a density on the
 * (theta, phi) square to a solid-angle density. */
#define NF_SIN_THETA_MIN 1e-6f

NF_EXTERN_C_END

#endif /* NISFLOW_MODEL_H */
