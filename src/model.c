/*
 * model.c - creating, copying and destroying models; the parameter layout; the weight
 * initialisation.
 */
#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "kernels/kernels.h"

static void *nf_default_alloc(void *user, size_t size)
{
    (void)user;
    return malloc(size);
}

static void nf_default_free(void *user, void *ptr)
{
    (void)user;
    free(ptr);
}

nf_allocator nf_default_allocator(void)
{
    nf_allocator a = {nf_default_alloc, nf_default_free, NULL};
    return a;
}

/* The struct and every array live in one block, so a model is one allocation. */
static size_t nf_header_bytes(void) { return (sizeof(nf_model) + 63u) & ~(size_t)63u; }

/* Fills the offset tables of both layouts: the public one (stride = out) and the packed one
 * (stride = out rounded up to NF_CHUNK). Returns the floats each layout needs. */
static void nf_model_layout(nf_model *m, size_t *public_count, size_t *packed_count)
{
    const nf_config *cfg = &m->cfg;
    size_t pub = 0, pk = 0;
    for (uint32_t layer = 0; layer < cfg->coupling_layers; ++layer) {
        uint32_t in = m->input_dim;
        for (uint32_t j = 0; j <= cfg->hidden_layers; ++j) {
            uint32_t out = j == cfg->hidden_layers ? m->raw_dim : cfg->hidden_width;
            nf_linear a = {pub, pub + (size_t)in * out, in, out, out};
            nf_linear b = {pk, pk + (size_t)in * NF_PAD(out), in, out, NF_PAD(out)};
            m->linear[layer][j] = a;
            m->packed_linear[layer][j] = b;
            pub += ((size_t)in + 1) * out;
            pk += ((size_t)in + 1) * NF_PAD(out);
            in = cfg->hidden_width;
        }
    }
    *public_count = pub;
    *packed_count = pk;
}

nf_status nf_model_allocate(const nf_config *cfg, const char *fn, nf_model **out)
{
    const nf_kernels *kernels = nf_select_kernels(cfg->isa, fn);
    if (!kernels)
        return NF_ERROR_INVALID_ARGUMENT;
    nf_allocator alloc = cfg->allocator;
    if (!alloc.alloc) {
        alloc.alloc = nf_default_alloc;
        alloc.free = nf_default_free;
        alloc.user = NULL;
    }
    /* The layout is computed on a stack copy first: the block's size depends on it. */
    nf_model probe;
    memset(&probe, 0, sizeof probe);
    probe.cfg = *cfg;
    probe.input_dim = 4u * cfg->oneblob_bins + 2u * cfg->sh_bands * cfg->sh_bands;
    probe.raw_dim = 3u * cfg->spline_bins + 1u;
    size_t p, packed;
    nf_model_layout(&probe, &p, &packed);
    size_t bytes = nf_header_bytes() + (7u * p + packed) * sizeof(float);
    unsigned char *block = (unsigned char *)alloc.alloc(alloc.user, bytes);
    if (!block)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "%s: could not allocate %zu bytes for a model", fn,
                       bytes);
    /* Zero the header, the parameters and optimizer state, and the packed weights (whose
     * padding columns must stay zero); the gradient and staging scratch (4 of the 7
     * parameter-sized arrays) are written before they are read, and untouched pages cost
     * nothing until a training step (a clone or a create of a large model faulted every page
     * in: megabytes for the largest shapes). */
    size_t header = nf_header_bytes();
    memset(block, 0, header + 3u * p * sizeof(float));
    memset(block + header + 7u * p * sizeof(float), 0, packed * sizeof(float));
    nf_model *m = (nf_model *)block;
    *m = probe;
    m->cfg.allocator = alloc;
    m->layer_params = nf_layer_param_count(cfg);
    m->param_count = p;
    m->packed_count = packed;
    m->step = 0;
    /* Shading points record the id of their model: a point used with another model, even one
     * allocated at the same address after the first was destroyed, is refused. */
    static atomic_uint_fast64_t next_id = 1;
    m->id = (uint64_t)atomic_fetch_add(&next_id, 1);
    atomic_init(&m->generation, 0u);
    m->kernels = kernels;
    float *arrays = (float *)(block + nf_header_bytes());
    m->params = arrays;
    m->adam_m = arrays + p;
    m->adam_v = arrays + 2 * p;
    m->grad = arrays + 3 * p;
    m->staging = arrays + 4 * p;
    m->packed = arrays + 7 * p;
    *out = m;
    return NF_OK;
}

void nf_model_pack(nf_model *m)
{
    nf_generation_begin(m); /* every prepared shading point is now stale */
    /* Padding columns stay zero from allocation; only the real columns are copied. */
    for (uint32_t layer = 0; layer < m->cfg.coupling_layers; ++layer) {
        for (uint32_t j = 0; j <= m->cfg.hidden_layers; ++j) {
            const nf_linear *a = &m->linear[layer][j], *b = &m->packed_linear[layer][j];
            for (uint32_t i = 0; i < a->in; ++i)
                memcpy(m->packed + b->weight + (size_t)i * b->stride,
                       m->params + a->weight + (size_t)i * a->stride, a->out * sizeof(float));
            memcpy(m->packed + b->bias, m->params + a->bias, a->out * sizeof(float));
        }
    }
    nf_generation_end(m);
}

/* splitmix64: a tiny, well-mixed generator; the initialisation only needs reproducibility. */
static uint64_t nf_splitmix64(uint64_t *state)
{
    uint64_t z = (*state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static float nf_uniform_pm(uint64_t *state, float bound)
{
    float u = (float)(nf_splitmix64(state) >> 40) * 0x1p-24f; /* [0, 1) */
    return (2.0f * u - 1.0f) * bound;
}

static void nf_initialise_params(nf_model *m)
{
    uint64_t state = m->cfg.seed;
    for (uint32_t layer = 0; layer < m->cfg.coupling_layers; ++layer) {
        for (uint32_t j = 0; j <= m->cfg.hidden_layers; ++j) {
            nf_linear lin = m->linear[layer][j];
            size_t count = ((size_t)lin.in + 1) * lin.out;
            if (j == m->cfg.hidden_layers) {
                /* Zero output layer: raw parameters 0, every spline the identity. */
                memset(m->params + lin.weight, 0, count * sizeof(float));
                continue;
            }
            /* PyTorch nn.Linear: kaiming_uniform(a = sqrt 5) weights and the bias both
             * uniform in +-1/sqrt(fan_in). */
            float bound = 1.0f / sqrtf((float)lin.in);
            for (size_t i = 0; i < count; ++i)
                m->params[lin.weight + i] = nf_uniform_pm(&state, bound);
        }
    }
}

nf_status nf_model_create(const nf_config *cfg, nf_model **out)
{
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_create: out is NULL");
    *out = NULL;
    nf_status st = nf_config_validate(cfg, "nf_model_create");
    if (st != NF_OK)
        return st;
    nf_model *m = NULL;
    if ((st = nf_model_allocate(cfg, "nf_model_create", &m)) != NF_OK)
        return st;
    nf_initialise_params(m);
    nf_model_pack(m);
    *out = m;
    return NF_OK;
}

void nf_model_destroy(nf_model *model)
{
    if (!model)
        return;
    nf_allocator alloc = model->cfg.allocator;
    alloc.free(alloc.user, model);
}

nf_status nf_model_clone(const nf_model *model, nf_model **out)
{
    if (!out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_clone: out is NULL");
    *out = NULL;
    if (!model)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_clone: model is NULL");
    nf_model *copy = NULL;
    nf_status st = nf_model_allocate(&model->cfg, "nf_model_clone", &copy);
    if (st != NF_OK)
        return st;
    size_t p = model->param_count;
    memcpy(copy->params, model->params, p * sizeof(float));
    memcpy(copy->adam_m, model->adam_m, p * sizeof(float));
    memcpy(copy->adam_v, model->adam_v, p * sizeof(float));
    memcpy(copy->packed, model->packed, model->packed_count * sizeof(float));
    copy->step = model->step;
    *out = copy;
    return NF_OK;
}

nf_status nf_model_copy(nf_model *dst, const nf_model *src)
{
    static const char fn[] = "nf_model_copy";
    if (!dst || !src)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: %s is NULL", fn, !dst ? "dst" : "src");
    if (dst == src)
        return NF_OK;
    const nf_config *a = &dst->cfg, *b = &src->cfg;
    if (a->coupling_layers != b->coupling_layers || a->spline_bins != b->spline_bins ||
        a->hidden_layers != b->hidden_layers || a->hidden_width != b->hidden_width ||
        a->oneblob_bins != b->oneblob_bins || a->sh_bands != b->sh_bands || a->prior != b->prior ||
        a->phi_map != b->phi_map || a->prior_epsilon != b->prior_epsilon ||
        memcmp(a->bounds_min, b->bounds_min, sizeof a->bounds_min) != 0 ||
        memcmp(a->bounds_max, b->bounds_max, sizeof a->bounds_max) != 0)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: dst and src differ in architecture, prior or bounds (nf_config): "
                       "copy only between models of one configuration",
                       fn);
    size_t p = src->param_count;
    nf_generation_begin(dst); /* dst's prepared points are stale from here on */
    memcpy(dst->params, src->params, p * sizeof(float));
    memcpy(dst->adam_m, src->adam_m, p * sizeof(float));
    memcpy(dst->adam_v, src->adam_v, p * sizeof(float));
    memcpy(dst->packed, src->packed, src->packed_count * sizeof(float));
    dst->step = src->step;
    dst->cfg.learning_rate = src->cfg.learning_rate;
    dst->cfg.weight_decay = src->cfg.weight_decay;
    nf_generation_end(dst);
    return NF_OK;
}

nf_status nf_model_get_config(const nf_model *model, nf_config *out)
{
    if (!model || !out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_get_config: model or out is NULL");
    *out = model->cfg;
    return NF_OK;
}
