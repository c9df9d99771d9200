/*
 * model.c - creating, copying and destroying models; the parameter layout; the weight
 * initialisation.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

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

/* The struct and every array live in one block, so a model is one allocation. */
static size_t nf_header_bytes(void)
{
    return (sizeof(nf_model) + 63u) & ~(size_t)63u;
}

nf_status nf_model_allocate(const nf_config *cfg, nf_model **out)
{
    size_t p = (size_t)cfg->coupling_layers * nf_layer_param_count(cfg);
    size_t bytes = nf_header_bytes() + 7u * p * sizeof(float);
    nf_allocator alloc = cfg->allocator;
    if (!alloc.alloc) {
        alloc.alloc = nf_default_alloc;
        alloc.free = nf_default_free;
        alloc.user = NULL;
    }
    unsigned char *block = (unsigned char *)alloc.alloc(alloc.user, bytes);
    if (!block)
        return nf_fail(NF_ERROR_OUT_OF_MEMORY, "could not allocate %zu bytes for a model",
                       bytes);
    memset(block, 0, bytes);
    nf_model *m = (nf_model *)block;
    m->cfg = *cfg;
    m->cfg.allocator = alloc;
    m->input_dim = 4u * cfg->oneblob_bins + 2u * cfg->sh_bands * cfg->sh_bands;
    m->raw_dim = 3u * cfg->spline_bins + 1u;
    m->layer_params = nf_layer_param_count(cfg);
    m->param_count = p;
    m->step = 0;
    float *arrays = (float *)(block + nf_header_bytes());
    m->params = arrays;
    m->adam_m = arrays + p;
    m->adam_v = arrays + 2 * p;
    m->grad = arrays + 3 * p;
    m->staging = arrays + 4 * p;
    *out = m;
    return NF_OK;
}

nf_linear nf_model_linear(const nf_model *m, uint32_t layer, uint32_t j)
{
    uint32_t h = m->cfg.hidden_width;
    size_t offset = (size_t)layer * m->layer_params;
    nf_linear lin;
    lin.in = m->input_dim;
    lin.out = h;
    for (uint32_t k = 0; k < j; ++k) {
        offset += ((size_t)lin.in + 1) * lin.out;
        lin.in = h;
        lin.out = h;
    }
    if (j == m->cfg.hidden_layers)
        lin.out = m->raw_dim;
    lin.weight = offset;
    lin.bias = offset + (size_t)lin.in * lin.out;
    return lin;
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
            nf_linear lin = nf_model_linear(m, layer, j);
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
    if ((st = nf_model_allocate(cfg, &m)) != NF_OK)
        return st;
    nf_initialise_params(m);
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
    nf_status st = nf_model_allocate(&model->cfg, &copy);
    if (st != NF_OK)
        return st;
    size_t p = model->param_count;
    memcpy(copy->params, model->params, p * sizeof(float));
    memcpy(copy->adam_m, model->adam_m, p * sizeof(float));
    memcpy(copy->adam_v, model->adam_v, p * sizeof(float));
    copy->step = model->step;
    *out = copy;
    return NF_OK;
}

nf_status nf_model_config(const nf_model *model, nf_config *out)
{
    if (!model || !out)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_config: model or out is NULL");
    *out = model->cfg;
    return NF_OK;
}
