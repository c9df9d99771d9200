/*
 * nf_test_support.h - shared helpers of libnisflow's tests (not installed, not part of the API).
 *
 *   - PCG32 (O'Neill 2014): a small seeded RNG, so every test is reproducible.
 *   - models with a given prior, a custom "Phong lobe" prior, parameter randomization.
 *   - a deterministic quadrature of a solid-angle density over the sphere (midpoint rule on
 *     the (theta, phi) square with the analytic Jacobian sin(theta)), optionally in a rotated
 *     frame. Directions are computed here with the C library's double trig, independently of
 *     nf_square_to_direction, so the quadrature cross-checks the library's parameterization.
 *   - a chi-square goodness-of-fit harness in the style of pbrt-v4 and Mitsuba 3.
 *   - snapshots of a model (parameters + serialized bytes) to prove it was left unchanged.
 *
 * Everything uses the public API only.
 */
#ifndef NF_TEST_SUPPORT_H
#define NF_TEST_SUPPORT_H

#include <stddef.h>
#include <stdint.h>

#include <nisflow/nisflow.h>

#include "nf_test_main.h"
#include "blocks.h"
#include "direction_table.h"
#include "shading_point.h"

#define NFT_PI 3.14159265358979323846

/* The largest batch the quadrature and the chi-square harness pass to a callback. */
#define NFT_BATCH 4096u

/* ---- PCG32 -------------------------------------------------------------------------------- */

typedef struct nft_rng {
    uint64_t state;
    uint64_t inc;
} nft_rng;

void nft_rng_seed(nft_rng *r, uint64_t seed, uint64_t stream);
uint32_t nft_rng_u32(nft_rng *r);
/* Uniform in [0, 1): 24 random bits, so every value is exactly representable. */
float nft_rng_float(nft_rng *r);
/* Uniform in [0, 1) with 53 random bits. */
double nft_rng_double(nft_rng *r);
/* A uniformly distributed unit vector (float components, renormalized in double). */
void nft_random_unit_vector(nft_rng *r, float v[3]);
/* A random context: position uniform in the unit cube, random unit normal, and wo a random
 * unit vector in the hemisphere of the normal. */
void nft_random_context(nft_rng *r, nf_context *ctx);
/* n sampling queries: per query in turn, a random context and its two uniforms u[2i], u[2i+1]. */
void nft_random_queries(nft_rng *r, size_t n, nf_context *ctx, float *u);
/* n training samples: per sample in turn, a random context, a random unit direction
 * dir[3i..3i+2] and a weight weight_min + uniform [0, 1). */
void nft_random_samples(nft_rng *r, size_t n, nf_context *ctx, float *dir, float *weight,
                        float weight_min);
/* Both in one: per sample in turn, a random context, its two uniforms u[2i], u[2i+1], a random
 * unit direction and a weight weight_min + uniform [0, 1). */
void nft_random_batch(nft_rng *r, size_t n, nf_context *ctx, float *u, float *dir, float *weight,
                      float weight_min);
/* n pairs of uniforms u[2i], u[2i+1] and a random unit direction dir[3i..3i+2] each, in turn:
 * what a sample call and a pdf call at the same points take. */
void nft_random_u_dir(nft_rng *r, size_t n, float *u, float *dir);
/* A context from explicit vectors (normalized here in double). */
nf_context nft_context(float px, float py, float pz, float nx, float ny, float nz, float wx,
                       float wy, float wz);

/* ---- small vector helpers (double) ---------------------------------------------------------- */

double nft_dot3(const double a[3], const double b[3]);
/* theta = atan2(hypot(x, y), z), phi = atan2(y, x) wrapped to [0, 2 pi), of any vector. */
void nft_direction_angles(const float dir[3], double *theta, double *phi);
/* sin(theta) of a float direction (any positive length), computed in double. */
double nft_sin_theta(const float dir[3]);
/* The length of a float vector, in double. */
double nft_length3f(const float v[3]);
/* An orthonormal frame (t, b, n) with n = normalize(axis), computed in double. */
void nft_frame(const double axis[3], double t[3], double b[3], double n[3]);

/* A unit direction from the von Mises-Fisher lobe of concentration kappa > 0 around the unit
 * vector mu, by inversion: cos = 1 + log(u + (1 - u) e^(-2 kappa)) / kappa. */
void nft_vmf_sample(nft_rng *r, const double mu[3], double kappa, float dir[3]);

/* ---- models --------------------------------------------------------------------------------- */

/* The custom prior of the tests: a normalized Phong lobe in solid-angle terms around the
 * mirror direction of wo about the normal,  p(w) = (e + 1)/(2 pi) max(0, cos a)^e,  e the
 * exponent in *user (a const float). Sampled by inversion: cos a = (1 - u0)^(1/(e+1)),
 * azimuth 2 pi u1. Pure functions, so thread-safe. */
float nft_phong_sample(void *user, const nf_context *ctx, float u0, float u1, float dir[3]);
float nft_phong_pdf(void *user, const nf_context *ctx, const float dir[3]);
/* The cosine between dir and the Phong lobe's axis (the mirror of wo about the normal). */
double nft_phong_cosine(const nf_context *ctx, const float dir[3]);
/* The exponent the helpers below use for NF_PRIOR_CUSTOM. */
#define NFT_PHONG_EXPONENT 8.0f
/* Callbacks for the Phong prior with exponent NFT_PHONG_EXPONENT. */
nf_prior_callbacks nft_phong_callbacks(void);

/* The phi map under test: NF_PHI_INTERVAL when the environment variable NF_TEST_PHI_MAP is
 * "interval", NF_PHI_CIRCULAR when it is "circular", otherwise the library's default. CTest
 * runs the tests of the flow once per map (tests/CMakeLists.txt). */
nf_phi_map nft_phi_map(void);
/* Sets cfg->phi_map to nft_phi_map(). */
void nft_apply_phi_map(nf_config *cfg);
/* A short name of a phi map, for messages. */
const char *nft_phi_map_name(nf_phi_map map);

/* nf_config_init(preset) with `prior` and nft_phi_map(); for NF_PRIOR_CUSTOM the Phong
 * callbacks. */
nf_config nft_config(nf_preset preset, nf_prior_kind prior);
/* Creates a model from `cfg`; fails the running cmocka test with the library's message (never
 * returns NULL) when nf_model_create refuses. */
nf_model *nft_model_from(const nf_config *cfg);
/* nft_model_from(nft_config(preset, prior)). */
nf_model *nft_make_model(nf_preset preset, nf_prior_kind prior);
/* The small preset with the cosine prior, its parameters nft_randomize_params(m, 0.5, 11): a
 * flow far from its prior (the table tests'). Fails the test on a refusal. */
nf_model *nft_random_model(void);
/* The table (nisflow/table.h) of a point prepared at ctx. Fails the test with the library's
 * message on a refusal. */
nf_direction_table nft_table_at(const nf_model *m, const nf_context *ctx);
/* A surface context drawn from r (nft_random_context) and m's point prepared there. Fails the
 * test with the library's message on a refusal. */
void nft_random_point(const nf_model *m, nft_rng *r, nf_context *ctx, nf_shading_point *p);
/* Cache c's statistics (nf_table_cache_get_stats). Fails the test on a refusal. */
nf_table_cache_stats nft_cache_stats(const nf_table_cache *c);
/* cmocka fixtures: nft_setup_model puts nft_make_model(NF_PRESET_SMALL, NF_PRIOR_COSINE) in
 * *state, nft_teardown_model destroys it after the test, whatever the test did. A test
 * registered with NFT_WITH_MODEL(test) begins `nf_model *m = *state;` and does not destroy it. */
int nft_setup_model(void **state);
int nft_teardown_model(void **state);
#define NFT_WITH_MODEL(test) cmocka_unit_test_setup_teardown(test, nft_setup_model, nft_teardown_model)
/* Replaces every parameter by a uniform value in [-scale, scale] drawn from PCG32(seed), so
 * the flow is far from the identity. Returns the nf_model_set_params status. */
nf_status nft_randomize_params(nf_model *m, float scale, uint64_t seed);
/* Adds noise to each of m's parameters: scale x a standard normal variate (Box-Muller, in
 * double) when gaussian, else scale x a uniform one in [-1, 1) (in float), drawn in order
 * from the stream (seed, stream). NF_ERROR_OUT_OF_MEMORY, or nf_model_set_params's status. */
nf_status nft_perturb_params(nf_model *m, double scale, int gaussian, uint64_t seed,
                             uint64_t stream);
/* nf_model_prior_pdf's density, or -1 on any error (the message is kept). */
float nft_prior_pdf(const nf_model *m, const nf_context *ctx, const float dir[3]);
/* A short name of a prior, for messages. */
const char *nft_prior_name(nf_prior_kind prior);

/* Runs fn(arg) on a thread with a painted stack of stack_bytes (ours) and returns how many
 * bytes of it the thread touched. Fails the test when the thread cannot run. */
size_t nft_stack_used(void *(*fn)(void *), void *arg, size_t stack_bytes);

/* The analytic solid-angle density of docs/theory.md section 2 (with the eps mixture for cosine and
 * custom), in double, at a direction of any positive length; ctx vectors normalized here. */
double nft_prior_density(nf_prior_kind prior, float eps, const nf_context *ctx,
                         const float dir[3]);

/* ---- density and sampler callbacks ---------------------------------------------------------- */

/* Evaluates the solid-angle density of n <= NFT_BATCH directions. Returns 0 on success. */
typedef int (*nft_pdf_fn)(void *user, size_t n, const float *dir, float *pdf);
/* Maps n <= NFT_BATCH points u (2 floats each) to unit directions. Returns 0 on success. */
typedef int (*nft_sample_fn)(void *user, size_t n, const float *u, float *dir);

/* Adapts a model and one context to the callbacks above. */
typedef struct nft_model_fn {
    const nf_model *model;
    nf_context *ctx; /* NFT_BATCH copies of one context (owned) */
    nf_status last;  /* status of the last library call */
} nft_model_fn;

int nft_model_fn_init(nft_model_fn *f, const nf_model *m, const nf_context *ctx);
void nft_model_fn_free(nft_model_fn *f);
int nft_model_pdf(void *user, size_t n, const float *dir, float *pdf);
int nft_model_sample(void *user, size_t n, const float *u, float *dir);

/* ---- quadrature over the sphere ------------------------------------------------------------- */

/* Midpoint rule on a theta_res x phi_res grid of the (theta, phi) square: the integral of the
 * density over the sphere, sum of pdf(w) sin(theta) dtheta dphi, accumulated in double.
 * frame == NULL: w = (sin t cos p, sin t sin p, cos t). Otherwise the grid's pole lies along
 * frame[2]: w = sin t cos p frame[0] + sin t sin p frame[1] + cos t frame[2] (frame rows
 * orthonormal). Returns NAN if the callback fails or returns a non-finite or negative value. */
double nft_integrate_sphere(nft_pdf_fn pdf, void *user, uint32_t theta_res, uint32_t phi_res,
                            const double frame[3][3]);

/* nft_integrate_sphere of a model's nf_pdf at one context. NAN if a call failed (out of
 * memory, or the library refused: nf_last_error_message() on this thread says why), so that
 * any |I - 1| check fails. */
double nft_integrate_model(const nf_model *m, const nf_context *ctx, uint32_t theta_res,
                           uint32_t phi_res, const double frame[3][3]);

/* ---- chi-square goodness of fit -------------------------------------------------------------- */

/* Q(a, x) = Gamma(a, x) / Gamma(a), the regularized upper incomplete gamma function (series
 * for x < a + 1, Lentz continued fraction otherwise, as Numerical Recipes' gammq). */
double nft_gamma_q(double a, double x);

typedef struct nft_chi2_params {
    const char *name;           /* identifies the run; failure tables go to chi2_<name>.txt */
    uint32_t theta_res;         /* histogram cells in theta                                */
    uint32_t phi_res;           /* histogram cells in phi                                  */
    uint32_t subdiv;            /* midpoint quadrature points per cell side (expected)     */
    size_t sample_count;        /* N                                                       */
    uint64_t seed;              /* PCG32 seed of the u values                              */
    double significance;        /* overall significance level, e.g. 0.01                   */
    uint32_t run_count;         /* number of runs in the test (Sidak correction)           */
    double min_expected;        /* pool cells with fewer expected samples (5)              */
    double integral_tolerance;  /* |integral of pdf - 1| allowed                           */
    int dump_on_failure;        /* write the tables on failure                             */
} nft_chi2_params;

/* Defaults: 16 x 32 cells, 8 x 8 quadrature points per cell, 100000 samples, significance
 * 0.01, one run, pooling below 5, integral tolerance 1e-2, dump on failure. */
nft_chi2_params nft_chi2_defaults(const char *name);

typedef struct nft_chi2_result {
    int passed;
    double statistic;
    int dof;
    double p_value;
    double alpha;        /* Sidak-corrected threshold for p_value */
    double pdf_integral; /* sum of expected counts / N             */
    char message[512];   /* why it failed (and the dump file)      */
} nft_chi2_result;

/* Draws N directions from sample(u) with u from PCG32, histograms them on the (theta, phi)
 * grid, integrates pdf over each cell for the expected counts, pools cells with expected
 * counts below min_expected, and runs Pearson's chi-square test with a Sidak-corrected
 * level. Fails also on non-unit or non-finite samples, on samples in cells whose expected
 * count is 0, and on a pdf that does not integrate to 1. Returns r->passed. */
int nft_chi2_test(const nft_chi2_params *p, nft_sample_fn sample, nft_pdf_fn pdf, void *user,
                  nft_chi2_result *r);

/* nft_chi2_test of a model's nf_sample against its nf_pdf at one context. Returns r->passed;
 * a library call that failed fails the test, its status and message in r->message. */
int nft_chi2_model(const nft_chi2_params *p, const nf_model *m, const nf_context *ctx,
                   nft_chi2_result *r);

/* ---- model files ------------------------------------------------------------------------- */

/* CRC-32/IEEE as zlib computes it (reflected polynomial 0xEDB88320, initial value and final
 * XOR 0xFFFFFFFF), bit by bit: deliberately unlike the library's table-driven version, so
 * that a test that re-seals an edited model file checks the library's CRC. */
uint32_t nft_crc32_ieee(const unsigned char *p, size_t n);

/* ---- snapshots ---------------------------------------------------------------------------- */

typedef struct nft_snapshot {
    size_t param_count;
    float *params;
    size_t bytes_size;
    unsigned char *bytes; /* nf_model_serialize output */
    uint64_t steps;
} nft_snapshot;

/* Takes a snapshot; returns 0 on success. */
int nft_snapshot_take(const nf_model *m, nft_snapshot *s);
/* The snapshot of `m`; fails the running cmocka test when it cannot be taken. */
nft_snapshot nft_snapshot_of(const nf_model *m);
/* 1 if the model's parameters, serialized bytes and step count equal the snapshot's. */
int nft_snapshot_equal(const nf_model *m, const nft_snapshot *s);
void nft_snapshot_free(nft_snapshot *s);

/* 1 when built with AddressSanitizer, ThreadSanitizer or MemorySanitizer (GCC or clang):
 * tests of stack use and resource limits skip themselves there. */
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define NFT_UNDER_SANITIZER 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) ||                     \
    __has_feature(memory_sanitizer)
#define NFT_UNDER_SANITIZER 1
#endif
#endif
#ifndef NFT_UNDER_SANITIZER
#define NFT_UNDER_SANITIZER 0
#endif

/* 1 where the stack-use tests measure (nft_stack_used): optimized builds without sanitizers,
 * the builds the headers' stack figures are for (sanitizers grow every frame). */
#if !NFT_UNDER_SANITIZER && defined(NDEBUG) && defined(__OPTIMIZE__)
#define NFT_STACK_CHECK 1
#else
#define NFT_STACK_CHECK 0
#endif

/* nf_guide_config_init's defaults with a store of store_capacity samples and passes of
 * steps_per_pass steps of step_samples: the small guides of the tests. */
nf_guide_config nft_guide_config(size_t store_capacity, uint32_t step_samples,
                                 uint32_t steps_per_pass);

/* Sets every size field of cfg to its largest value (NF_MAX_*): the largest model. */
void nft_config_largest(nf_config *cfg);

/* Outputs that a refused call must leave alone: nft_fill_sentinel writes NFT_SENTINEL, a value
 * no call produces, and nft_untouched checks that every float still has its bits. */
#define NFT_SENTINEL 12345.0f
void nft_fill_sentinel(float *v, size_t n);
int nft_untouched(const float *v, size_t n);

/* The contexts nf_sample, nf_pdf and nf_point_prepare must refuse, made from a valid one:
 * `which` < NFT_BAD_CONTEXTS picks NaN, +Inf or -Inf in each component of position, normal and
 * wo (27), or a normal or wo whose components are all 0, 1e-16 or 1e-38 (squared lengths at
 * most 3e-32, below the 1e-30 the library requires; a normal of zeros marks a point in a
 * medium, and comes with phase_g NaN, which is what is refused there). `what` receives a
 * description. */
enum { NFT_BAD_CONTEXTS = 27 + 6 };
nf_context nft_bad_context(const nf_context *good, int which, char *what, size_t size);

#endif /* NF_TEST_SUPPORT_H */
