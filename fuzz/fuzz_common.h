/*
 * fuzz_common.h - shared by the libFuzzer targets of fuzz/ (docs/robustness.md): a CRC-32
 * of our own (so that mutated files can be made structurally valid), a well-behaved custom
 * prior for models saved with NF_PRIOR_CUSTOM, and abort-on-failure checks. A target that
 * finds a broken invariant aborts, which libFuzzer reports as a crash with the input saved.
 */
#ifndef NF_FUZZ_COMMON_H
#define NF_FUZZ_COMMON_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <nisflow/nisflow.h>

#define NF_FUZZ_CHECK(cond, ...)                                                               \
    do {                                                                                       \
        if (!(cond)) {                                                                         \
            fprintf(stderr, "fuzz check failed at %s:%d: %s\n  ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                                      \
            fprintf(stderr, "\n  last library message: %s\n", nf_last_error_message());       \
            abort();                                                                           \
        }                                                                                      \
    } while (0)

/* A program's bytes, read front to back; past the end every byte is 0 (fuzz_guide,
 * fuzz_schedule). */
typedef struct nf_fuzz_reader {
    const uint8_t *p;
    size_t n;
} nf_fuzz_reader;

static inline uint8_t nf_fuzz_byte(nf_fuzz_reader *r)
{
    if (r->n == 0)
        return 0;
    r->n--;
    return *r->p++;
}

static inline uint32_t nf_fuzz_u32(nf_fuzz_reader *r)
{
    uint32_t v = 0;
    for (int i = 0; i < 4; ++i)
        v |= (uint32_t)nf_fuzz_byte(r) << (8 * i);
    return v;
}

/* The format's header and trailer sizes (docs/format.md). */
#define NF_FUZZ_HEADER_V1 112u /* format version 1's header; version 2 adds phi_map */
#define NF_FUZZ_HEADER 116u
#define NF_FUZZ_TRAILER 4u

/* CRC-32/IEEE (zlib, PNG), bit by bit. */
static inline uint32_t nf_fuzz_crc32(const unsigned char *p, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) {
        crc ^= p[i];
        for (int b = 0; b < 8; ++b)
            crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

/* Rewrites the trailing checksum so the buffer passes the CRC check (size >= trailer). */
static inline void nf_fuzz_fix_crc(unsigned char *buf, size_t size)
{
    uint32_t crc = nf_fuzz_crc32(buf, size - NF_FUZZ_TRAILER);
    for (int i = 0; i < 4; ++i)
        buf[size - NF_FUZZ_TRAILER + (size_t)i] = (unsigned char)(crc >> (8 * i));
}

/* A cosine lobe around the context's normal (in a medium around -wo), in solid-angle terms:
 * p(w) = max(0, n.w) / pi.
 * Sampling by Malley's method in a frame around n; it never returns a density <= 0. */
static inline void nf_fuzz_unit(const float v[3], double out[3])
{
    double x = v[0], y = v[1], z = v[2], len = sqrt(x * x + y * y + z * z);
    out[0] = x / len;
    out[1] = y / len;
    out[2] = z / len;
}

/* The lobe's axis: the normal, or at a point in a medium (zero normal) -wo. */
static inline void nf_fuzz_axis(const nf_context *ctx, double n[3])
{
    const float *v = ctx->normal;
    nf_fuzz_unit(v[0] == 0.0f && v[1] == 0.0f && v[2] == 0.0f ? ctx->wo : v, n);
    if (v[0] == 0.0f && v[1] == 0.0f && v[2] == 0.0f)
        for (int k = 0; k < 3; ++k)
            n[k] = -n[k];
}

static inline float nf_fuzz_cosine_pdf(void *user, const nf_context *ctx, const float dir[3])
{
    (void)user;
    double n[3], w[3];
    nf_fuzz_axis(ctx, n);
    nf_fuzz_unit(dir, w);
    double c = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
    return c > 0.0 ? (float)(c / 3.14159265358979323846) : 0.0f;
}

static inline float nf_fuzz_cosine_sample(void *user, const nf_context *ctx, float u0, float u1,
                                          float dir[3])
{
    (void)user;
    double n[3];
    nf_fuzz_axis(ctx, n);
    double sign = n[2] >= 0.0 ? 1.0 : -1.0, a = -1.0 / (sign + n[2]), b = n[0] * n[1] * a;
    double t[3] = {1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]};
    double bt[3] = {b, sign + n[1] * n[1] * a, -n[1]};
    double r = sqrt((double)u0), phi = 2.0 * 3.14159265358979323846 * (double)u1;
    double c = sqrt(fmax(1.0 - (double)u0, 1e-6));
    for (int k = 0; k < 3; ++k)
        dir[k] = (float)(r * cos(phi) * t[k] + r * sin(phi) * bt[k] + c * n[k]);
    return (float)(c / 3.14159265358979323846);
}

static inline nf_prior_callbacks nf_fuzz_callbacks(void)
{
    nf_prior_callbacks cb;
    cb.sample = nf_fuzz_cosine_sample;
    cb.pdf = nf_fuzz_cosine_pdf;
    cb.user = NULL;
    return cb;
}

/* The serialized bytes of a model, in a new buffer (NULL on failure). */
static inline unsigned char *nf_fuzz_serialize(const nf_model *m, size_t *size)
{
    if (nf_model_serialize(m, NULL, 0, size) != NF_OK)
        return NULL;
    unsigned char *buf = (unsigned char *)malloc(*size);
    if (buf && nf_model_serialize(m, buf, *size, size) != NF_OK) {
        free(buf);
        return NULL;
    }
    return buf;
}

#endif /* NF_FUZZ_COMMON_H */
