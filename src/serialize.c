/*
 * serialize.c - the model file format (docs/format.md): explicit little-endian fields, the
 * configuration, parameters, AdamW state and a CRC-32, validated field by field on load.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

/* Version 2 adds phi_map after version 1's header; version-1 files are read as
 * NF_PHI_INTERVAL, the only parameterization they could hold. */
#define NF_FORMAT_VERSION 2u
#define NF_HEADER_BYTES_V1 112u
#define NF_HEADER_BYTES 116u
#define NF_TRAILER_BYTES 4u
/* No valid configuration needs more; a larger file is refused before it is read. */
#define NF_MAX_FILE_BYTES ((size_t)1 << 28)

/* strerror's text for an errno value, or a fixed text when the C library set none. Known
 * values map to static strings in glibc, musl and the BSDs, so concurrent calls are safe. */
static const char *nf_errno_text(int err) { return err ? strerror(err) : "unknown error"; }

static const unsigned char nf_magic[8] = {'N', 'I', 'S', 'F', 'L', 'O', 'W', 0};

/* CRC-32 (IEEE 802.3, reflected, as zlib and PNG), four bits at a time. */
static uint32_t nf_crc32(const unsigned char *p, size_t n)
{
    static const uint32_t table[16] = {0x00000000u, 0x1DB71064u, 0x3B6E20C8u, 0x26D930ACu,
                                       0x76DC4190u, 0x6B6B51F4u, 0x4DB26158u, 0x5005713Cu,
                                       0xEDB88320u, 0xF00F9344u, 0xD6D6A3E8u, 0xCB61B38Cu,
                                       0x9B64C2B0u, 0x86D3D2D4u, 0xA00AE278u, 0xBDBDF21Cu};
    uint32_t crc = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; ++i) {
        crc ^= p[i];
        crc = (crc >> 4) ^ table[crc & 15u];
        crc = (crc >> 4) ^ table[crc & 15u];
    }
    return crc ^ 0xFFFFFFFFu;
}

static unsigned char *nf_put_u32(unsigned char *p, uint32_t v)
{
    for (int i = 0; i < 4; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
    return p + 4;
}

static unsigned char *nf_put_u64(unsigned char *p, uint64_t v)
{
    for (int i = 0; i < 8; ++i)
        p[i] = (unsigned char)(v >> (8 * i));
    return p + 8;
}

static unsigned char *nf_put_f32(unsigned char *p, float v)
{
    uint32_t bits;
    memcpy(&bits, &v, 4);
    return nf_put_u32(p, bits);
}

static uint32_t nf_get_u32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t nf_get_u64(const unsigned char *p)
{
    return (uint64_t)nf_get_u32(p) | (uint64_t)nf_get_u32(p + 4) << 32;
}

static float nf_get_f32(const unsigned char *p)
{
    uint32_t bits = nf_get_u32(p);
    float v;
    memcpy(&v, &bits, 4);
    return v;
}

static size_t nf_serialized_size(size_t header_bytes, size_t param_count)
{
    return header_bytes + 3u * param_count * sizeof(float) + NF_TRAILER_BYTES;
}

nf_status nf_model_serialize(const nf_model *m, void *buf, size_t capacity, size_t *size)
{
    if (!m || !size)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_serialize: %s is NULL",
                       !m ? "m" : "size");
    size_t need = nf_serialized_size(NF_HEADER_BYTES, m->param_count);
    *size = need;
    if (!buf)
        return NF_OK;
    if (capacity < need)
        return nf_fail(NF_ERROR_CAPACITY,
                       "nf_model_serialize: capacity %zu < %zu bytes needed (nothing written)",
                       capacity, need);
    const nf_config *c = &m->cfg;
    unsigned char *start = (unsigned char *)buf, *p = start;
    memcpy(p, nf_magic, 8);
    p += 8;
    p = nf_put_u32(p, NF_FORMAT_VERSION);
    p = nf_put_u32(p, c->coupling_layers);
    p = nf_put_u32(p, c->spline_bins);
    p = nf_put_u32(p, c->hidden_layers);
    p = nf_put_u32(p, c->hidden_width);
    p = nf_put_u32(p, c->oneblob_bins);
    p = nf_put_u32(p, c->sh_bands);
    p = nf_put_u32(p, (uint32_t)c->prior);
    p = nf_put_f32(p, c->prior_epsilon);
    for (int a = 0; a < 3; ++a)
        p = nf_put_f32(p, c->bounds_min[a]);
    for (int a = 0; a < 3; ++a)
        p = nf_put_f32(p, c->bounds_max[a]);
    p = nf_put_f32(p, c->learning_rate);
    p = nf_put_f32(p, c->beta1);
    p = nf_put_f32(p, c->beta2);
    p = nf_put_f32(p, c->adam_epsilon);
    p = nf_put_f32(p, c->weight_decay);
    p = nf_put_u64(p, c->seed);
    p = nf_put_u64(p, m->step);
    p = nf_put_u64(p, (uint64_t)m->param_count);
    p = nf_put_u32(p, (uint32_t)c->phi_map);
    const float *arrays[3] = {m->params, m->adam_m, m->adam_v};
    for (int k = 0; k < 3; ++k)
        for (size_t i = 0; i < m->param_count; ++i)
            p = nf_put_f32(p, arrays[k][i]);
    nf_put_u32(p, nf_crc32(start, (size_t)(p - start)));
    return NF_OK;
}

/* Decodes a model for nf_model_deserialize and nf_model_load; `fn` begins every message (the
 * function the caller called, and for a file its path). */
static nf_status nf_decode(const char *fn, const void *buf, size_t size,
                           const nf_prior_callbacks *custom, nf_model **out)
{
    const unsigned char *p = (const unsigned char *)buf;
    if (size < NF_HEADER_BYTES_V1 + NF_TRAILER_BYTES)
        return nf_fail(NF_ERROR_FORMAT, "%s: %zu bytes is too short for a model", fn, size);
    if (memcmp(p, nf_magic, 8) != 0)
        return nf_fail(NF_ERROR_FORMAT, "%s: not a libnisflow model (bad magic)", fn);
    uint32_t version = nf_get_u32(p + 8);
    if (version != 1u && version != NF_FORMAT_VERSION)
        return nf_fail(NF_ERROR_FORMAT, "%s: format version %u is not supported (expected 1 to %u)",
                       fn, version, NF_FORMAT_VERSION);
    const size_t header = version == 1u ? NF_HEADER_BYTES_V1 : NF_HEADER_BYTES;
    if (size < header + NF_TRAILER_BYTES)
        return nf_fail(NF_ERROR_FORMAT, "%s: %zu bytes is too short for a model", fn, size);
    if (nf_crc32(p, size - NF_TRAILER_BYTES) != nf_get_u32(p + size - NF_TRAILER_BYTES))
        return nf_fail(NF_ERROR_FORMAT, "%s: checksum mismatch (corrupt or truncated)", fn);

    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    const unsigned char *q = p + 12;
    cfg.coupling_layers = nf_get_u32(q);
    q += 4;
    cfg.spline_bins = nf_get_u32(q);
    q += 4;
    cfg.hidden_layers = nf_get_u32(q);
    q += 4;
    cfg.hidden_width = nf_get_u32(q);
    q += 4;
    cfg.oneblob_bins = nf_get_u32(q);
    q += 4;
    cfg.sh_bands = nf_get_u32(q);
    q += 4;
    uint32_t prior = nf_get_u32(q);
    q += 4;
    if (prior > (uint32_t)NF_PRIOR_CUSTOM)
        return nf_fail(NF_ERROR_FORMAT, "%s: prior kind %u is unknown", fn, prior);
    cfg.prior = (nf_prior_kind)prior;
    cfg.prior_epsilon = nf_get_f32(q);
    q += 4;
    for (int a = 0; a < 3; ++a, q += 4)
        cfg.bounds_min[a] = nf_get_f32(q);
    for (int a = 0; a < 3; ++a, q += 4)
        cfg.bounds_max[a] = nf_get_f32(q);
    cfg.learning_rate = nf_get_f32(q);
    q += 4;
    cfg.beta1 = nf_get_f32(q);
    q += 4;
    cfg.beta2 = nf_get_f32(q);
    q += 4;
    cfg.adam_epsilon = nf_get_f32(q);
    q += 4;
    cfg.weight_decay = nf_get_f32(q);
    q += 4;
    cfg.seed = nf_get_u64(q);
    q += 8;
    uint64_t step = nf_get_u64(q);
    q += 8;
    uint64_t count = nf_get_u64(q);
    q += 8;
    cfg.phi_map = NF_PHI_INTERVAL;
    if (version >= 2u) {
        uint32_t phi_map = nf_get_u32(q);
        q += 4;
        if (phi_map > (uint32_t)NF_PHI_CIRCULAR)
            return nf_fail(NF_ERROR_FORMAT, "%s: phi map %u is unknown", fn, phi_map);
        cfg.phi_map = (nf_phi_map)phi_map;
    }

    if (cfg.prior == NF_PRIOR_CUSTOM) {
        if (!custom || !custom->sample || !custom->pdf)
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: the model uses a custom prior; pass its callbacks", fn);
        cfg.custom_prior = *custom;
    }
    if (nf_config_validate(&cfg, fn) != NF_OK) {
        char reason[256]; /* nf_fail overwrites the message it would otherwise quote */
        snprintf(reason, sizeof reason, "%s", nf_last_error_message());
        return nf_fail(NF_ERROR_FORMAT, "%s (invalid configuration in file)", reason);
    }
    size_t expected = (size_t)cfg.coupling_layers * nf_layer_param_count(&cfg);
    if (count != (uint64_t)expected || size != nf_serialized_size(header, expected))
        return nf_fail(NF_ERROR_FORMAT,
                       "%s: parameter count or size does not match the configuration", fn);
    const unsigned char *data = p + header;
    for (size_t i = 0; i < 3 * expected; ++i) {
        float v = nf_get_f32(data + 4 * i);
        if (!isfinite(v) || (i >= 2 * expected && v < 0.0f))
            return nf_fail(NF_ERROR_FORMAT,
                           "%s: value %zu of the parameters or optimizer state "
                           "is invalid",
                           fn, i);
    }

    nf_model *m = NULL;
    nf_status st = nf_model_allocate(&cfg, fn, &m);
    if (st != NF_OK)
        return st;
    float *arrays[3] = {m->params, m->adam_m, m->adam_v};
    for (int k = 0; k < 3; ++k)
        for (size_t i = 0; i < expected; ++i)
            arrays[k][i] = nf_get_f32(data + 4 * ((size_t)k * expected + i));
    m->step = step;
    nf_model_pack(m);
    *out = m;
    return NF_OK;
}

nf_status nf_model_deserialize(const void *buf, size_t size, const nf_prior_callbacks *custom,
                               nf_model **out)
{
    static const char fn[] = "nf_model_deserialize";
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: out is NULL", fn);
    *out = NULL;
    if (!buf)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: buf is NULL", fn);
    return nf_decode(fn, buf, size, custom, out);
}

/* "fn: 'path'" for messages about a file, keeping the end of a long path (its file name) so
 * that the message after it still fits nf_last_error_message's 256 bytes. */
static void nf_file_prefix(char *dst, size_t cap, const char *fn, const char *path)
{
    size_t len = strlen(path);
    if (len <= 120)
        snprintf(dst, cap, "%s: '%s'", fn, path);
    else
        snprintf(dst, cap, "%s: '...%s'", fn, path + len - 117);
}

nf_status nf_model_save(const nf_model *m, const char *path)
{
    static const char fn[] = "nf_model_save";
    if (!m || !path)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn, !m ? "m" : "path");
    size_t size;
    nf_model_serialize(m, NULL, 0, &size);
    const nf_allocator *a = &m->cfg.allocator;
    void *buf = a->alloc(a->user, size);
    if (!buf)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate %zu bytes", fn, size);
    nf_model_serialize(m, buf, size, &size);
    nf_status st = NF_OK;
    char who[160];
    nf_file_prefix(who, sizeof who, fn, path);
    errno = 0;
    FILE *f = fopen(path, "wb");
    if (!f) {
        st = nf_fail(NF_ERROR_IO, "%s: cannot open for writing: %s", who, nf_errno_text(errno));
    } else {
        size_t written = fwrite(buf, 1, size, f);
        int err = errno;
        if (fclose(f) != 0 || written != size)
            st = nf_fail(NF_ERROR_IO, "%s: could not write all of it: %s", who,
                         nf_errno_text(errno ? errno : err));
    }
    a->free(a->user, buf);
    return st;
}

nf_status nf_model_load(const char *path, const nf_prior_callbacks *custom, nf_model **out)
{
    static const char fn[] = "nf_model_load";
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: out is NULL", fn);
    *out = NULL;
    if (!path)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: path is NULL", fn);
    char who[160];
    nf_file_prefix(who, sizeof who, fn, path);
    errno = 0;
    FILE *f = fopen(path, "rb");
    if (!f)
        return nf_fail(NF_ERROR_IO, "%s: cannot open: %s", who, nf_errno_text(errno));
    /* Read in bounded chunks rather than trusting a seek: the path may be a pipe. */
    size_t cap = 1u << 16, size = 0;
    unsigned char *buf = (unsigned char *)malloc(cap);
    nf_status st = NF_OK;
    while (buf) {
        size += fread(buf + size, 1, cap - size, f);
        if (size < cap)
            break;
        if (cap >= NF_MAX_FILE_BYTES) {
            st = nf_fail(NF_ERROR_FORMAT, "%s: larger than any model", who);
            break;
        }
        unsigned char *grown = (unsigned char *)realloc(buf, cap * 2);
        if (!grown) {
            free(buf);
            buf = NULL;
            break;
        }
        buf = grown;
        cap *= 2;
    }
    if (!buf)
        st = nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate a read buffer", who);
    else if (st == NF_OK && ferror(f))
        st = nf_fail(NF_ERROR_IO, "%s: error while reading: %s", who, nf_errno_text(errno));
    fclose(f);
    if (st == NF_OK)
        st = nf_decode(who, buf, size, custom, out);
    free(buf);
    return st;
}
