/*
 * shading_point.h - shading points: prepare a context once, then draw and evaluate any number
 * of directions at it. Internal (not installed): renderers reach points through the vertex
 * object (nisflow/vertex.h, NF_VERTEX_POINT), which keeps one; the tests, fuzzers and the
 * benchmark call these directly.
 *
 * A path tracer asks the guide several questions about one shading context: a direction drawn
 * from the flow, the flow's density of the direction the BSDF drew, the flow's density of the
 * light sample for MIS. nf_point_prepare does once everything that depends on the context
 * alone: it validates and normalizes the context, encodes position, normal and wo, and runs
 * the part of every conditioner's first layer that reads them. What remains per direction is
 * the pass-through coordinate's one-blob (three weight rows), the rest of each small MLP, the
 * splines and the map to the sphere. Results are bit-identical to nf_sample / nf_pdf for the
 * same model, context and inputs, except for the two presets on the AVX2 and AVX-512 kernels:
 * there a path designed for one direction (vectors across units and bins, sums in another
 * order) agrees with them within a bound, asserted by tests/correctness/test_point.c on
 * randomized models: densities within 2e-3 relatively (0.2 % of them beyond 1e-4; in a medium with
 * |g| > 0.9, directions in the phase function's peak within 1.5e-2), direction components
 * within 2e-5. Calls through points agree with each other to the bit on every path, and that
 * path gives the same bits on the AVX2 kernels as on the AVX-512 ones.
 * docs/architecture.md ("Which rule holds where") has the measured figures.
 *
 * The recipe of a guided vertex (docs/integration.md has it in full), two questions per call:
 *
 *     nf_shading_point sp;
 *     nf_point_prepare(model, &ctx, NULL, &sp);              once per vertex
 *     nf_point_sample_and_pdf(model, &sp, u, dir, &pdf,      a direction drawn, and the
 *                             light_dir, &p_light);          light sample's density for MIS
 *   or, when the BSDF drew the direction:
 *     nf_point_pdf(model, &sp, 2, bsdf_and_light_dirs, p);   both densities
 *
 * One direction's walk through the flow is a chain of dependent arithmetic that leaves most
 * of a core idle; with the AVX2 or AVX-512 kernels and a preset a call with two directions
 * walks them in step, interleaved, and costs less than two calls (docs/performance.md has the
 * figures; the generic kernels and other shapes walk them one after the other).
 *
 * Memory: an nf_shading_point is a plain struct (1,152 bytes on 64-bit targets) that the
 * caller owns (stack, arrays, anything). Nothing is allocated and nothing needs freeing.
 * Its fields are the library's: read or write none of them. 64-byte alignment of the struct
 * is best for speed (its cache starts at offset 128) but not required.
 *
 * Validity: a prepared point belongs to the model it was prepared on and to that model's
 * current parameters. Any change of the parameters (a training step, nf_model_set_params,
 * a publication into it) makes every point prepared before or during it stale: using it then
 * returns NF_ERROR_STALE and writes nothing; prepare it again. A sample or pdf call that
 * overlaps such a change on another thread (misuse: see below) returns NF_ERROR_STALE with its
 * outputs unspecified; a point prepared while a change runs is never accepted. A point used with
 * another model (a clone included) returns NF_ERROR_INVALID_ARGUMENT, and so does a point whose
 * header (the fields before check_) was overwritten: a hash of the header is checked on every call,
 * with the model's id and generation, for about 50 instructions. The cache after the header is not
 * checked (that would cost a pass over it per call): a point whose cache was overwritten gives
 * wrong but finite results, never a crash. A point may be copied with memcpy or assignment; a
 * copy is as valid as the original.
 *
 * Thread-safety: every function here takes a const model and may run concurrently with the
 * others and with nf_sample / nf_pdf, provided no thread changes the model meanwhile; a change
 * that overlaps a call anyway is detected (NF_ERROR_STALE), not answered wrongly. To train
 * while render threads sample, sample a guide's published models (guide.h). A point
 * is written by nf_point_prepare only; any number of threads may sample one prepared point at
 * once. Nothing here allocates.
 *
 * Stack: every call uses at most 5 KiB of the caller's stack, for any shape up to the
 * configuration limits; renderers that shade on fiber stacks should allow that much per call.
 * tests/correctness/test_point.c measures every call against that bound (with GCC and clang)
 * and prints what each used.
 */
#ifndef NISFLOW_SRC_SHADING_POINT_H
#define NISFLOW_SRC_SHADING_POINT_H

#include <stddef.h>
#include <stdint.h>

#include "nisflow/model.h"
#include "nisflow/status.h"
#include "nisflow/version.h"

/* The floats a point keeps of the first layers' context sums: coupling_layers times the
 * hidden width rounded up to 16. Both presets fit (small 32, large 64); a model above it
 * (for example 8 layers of 64 units) keeps the encodings instead and recomputes its first
 * layers' context sums for each direction: same results, slower calls. */
#define NF_SHADING_POINT_CACHE_FLOATS 256u

/* A prepared shading point. Its layout is private: the names exist only to size it. */
typedef struct nf_shading_point {
    nf_context context_;       /* the context as given, passed to custom priors     */
    uint32_t magic_;           /* marks a prepared point                              */
    uint32_t cached_;          /* 1: cache_ holds context sums; 0: encodings          */
    uint64_t model_id_;        /* the model it belongs to                             */
    uint64_t generation_;      /* that model's parameter generation                   */
    nf_prior_callbacks prior_; /* the custom prior's callbacks at this point          */
    float frame_[3];           /* the unit normal                                     */
    uint32_t zero_;            /* 0, so that the hashed header is whole 64-bit words  */
    uint32_t check_;           /* a hash of the fields above                          */
    uint32_t reserved_[5];
    float cache_[NF_SHADING_POINT_CACHE_FLOATS];
} nf_shading_point;

/* Prepares `point` for sampling and evaluating directions at the shading context `ctx` (the
 * same rules as nf_sample: finite position, normal and wo with squared lengths above 1e-30).
 *
 * prior: NULL, or callbacks that replace the model's custom prior (NF_PRIOR_CUSTOM) for the
 *        calls through this point: per-point data such as this shading point's BSDF travel in
 *        prior->user, with no global or thread-local side channel. Both callbacks must be
 *        non-NULL. They receive a pointer to the point's copy of `ctx` (not `ctx` itself), and
 *        are called from whichever thread samples the point. Training still uses the model's
 *        callbacks. A non-NULL prior on a model with another prior kind is refused.
 *
 * On any error (NF_ERROR_INVALID_ARGUMENT: NULL pointers, a bad context, a bad prior) the
 * point is not written, so a point that was valid stays valid. Its cost is in
 * docs/performance.md.
 * Thread-safe on a const model; writes only *point; never allocates. */
nf_status nf_point_prepare(const nf_model *m, const nf_context *ctx,
                           const nf_prior_callbacks *prior, nf_shading_point *point);

/* Draws n directions at the prepared point: u[2i], u[2i+1] in [0,1) (values outside are
 * clamped, as in nf_sample) give dir[3i..3i+2], a unit vector, and, if pdf is not NULL,
 * pdf[i], its solid-angle density (per steradian), clamped to [FLT_MIN, FLT_MAX]. The same
 * bits as nf_sample for the point's context (within the bound above on the vector path). n = 0 is a
 * no-op. Errors: NF_ERROR_INVALID_ARGUMENT (NULL, an unprepared or corrupted point, a point of
 * another model, NaN or Inf in u) and NF_ERROR_STALE write nothing; NF_ERROR_NUMERIC (a
 * custom prior callback returned an invalid value) may come after earlier directions were
 * written. Thread-safe on a const model and point; never allocates. */
nf_status nf_point_sample(const nf_model *m, const nf_shading_point *point, size_t n,
                          const float *u, float *dir, float *pdf);

/* The solid-angle densities of n directions at the prepared point: pdf[i] for dir[3i..3i+2],
 * which must be finite and non-zero (squared length above 1e-30) and is normalized by the
 * library. The same bits as nf_pdf for the point's context (within the bound above on the
 * vector path). n = 0 is a no-op. Directions go
 * two at a time, walked in step (the presets on the AVX2 and AVX-512 kernels): n = 2 costs
 * less than two calls of n = 1.
 * Errors as nf_point_sample (a bad direction is NF_ERROR_INVALID_ARGUMENT, nothing written).
 * Thread-safe on a const model and point; never allocates. */
nf_status nf_point_pdf(const nf_model *m, const nf_shading_point *point, size_t n, const float *dir,
                       float *pdf);

/* A guided vertex's two questions of the flow in one call: draws a direction for u (as
 * nf_point_sample with n = 1: dir, and pdf if not NULL) and returns the density of another
 * direction, eval_dir (as nf_point_pdf with n = 1: *eval_pdf), usually the light sample's,
 * for MIS. With the AVX2 or AVX-512 kernels the two walks through the flow run interleaved,
 * which costs less than the two calls (docs/performance.md) for the presets; the results are the
 * same bits as theirs.
 * Errors: as the two calls; every input is checked before anything is written, and
 * NF_ERROR_NUMERIC (a custom prior callback returned an invalid value) writes nothing either.
 * Thread-safe on a const model and point; never allocates. */
nf_status nf_point_sample_and_pdf(const nf_model *m, const nf_shading_point *point,
                                  const float u[2], float dir[3], float *pdf,
                                  const float eval_dir[3], float *eval_pdf);

#endif /* NISFLOW_SRC_SHADING_POINT_H */
