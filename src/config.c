/*
 * config.c - presets, defaults and validation of nf_config.
 */
#include <math.h>
#include <string.h>

#include "internal.h"

void nf_config_init(nf_config *cfg, nf_preset preset)
{
    if (!cfg)
        return;
    memset(cfg, 0, sizeof *cfg);
    if (preset == NF_PRESET_LARGE) {
        cfg->coupling_layers = 4;
        cfg->spline_bins = 16;
        cfg->hidden_layers = 2;
    } else {
        cfg->coupling_layers = 2;
        cfg->spline_bins = 8;
        cfg->hidden_layers = 1;
    }
    cfg->hidden_width = 16;
    cfg->oneblob_bins = 32;
    cfg->sh_bands = 4;
    cfg->prior = NF_PRIOR_COSINE;
    cfg->prior_epsilon = 0.01f;
    for (int a = 0; a < 3; ++a) {
        cfg->bounds_min[a] = 0.0f;
        cfg->bounds_max[a] = 1.0f;
    }
    cfg->learning_rate = 1e-3f;
    cfg->beta1 = 0.9f;
    cfg->beta2 = 0.999f;
    cfg->adam_epsilon = 1e-8f;
    cfg->weight_decay = 0.01f;
    cfg->seed = 1;
}

static nf_status nf_check_range(const char *fn, const char *field, uint32_t v, uint32_t lo,
                                uint32_t hi)
{
    if (v < lo || v > hi)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.%s = %u is outside [%u, %u]", fn,
                       field, v, lo, hi);
    return NF_OK;
}

nf_status nf_config_validate(const nf_config *cfg, const char *fn)
{
    if (!cfg)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config is NULL", fn);
    nf_status st;
    if ((st = nf_check_range(fn, "coupling_layers", cfg->coupling_layers, 1,
                             NF_MAX_COUPLING_LAYERS)) ||
        (st = nf_check_range(fn, "spline_bins", cfg->spline_bins, 2, NF_MAX_SPLINE_BINS)) ||
        (st = nf_check_range(fn, "hidden_layers", cfg->hidden_layers, 1, NF_MAX_HIDDEN_LAYERS)) ||
        (st = nf_check_range(fn, "hidden_width", cfg->hidden_width, 1, NF_MAX_HIDDEN_WIDTH)) ||
        (st = nf_check_range(fn, "oneblob_bins", cfg->oneblob_bins, 2, NF_MAX_ONEBLOB_BINS)) ||
        (st = nf_check_range(fn, "sh_bands", cfg->sh_bands, 0, NF_MAX_SH_BANDS)))
        return st;
    /* The enum is compared through an unsigned copy: a caller may store any integer in it. */
    unsigned prior = (unsigned)cfg->prior;
    if (prior > (unsigned)NF_PRIOR_CUSTOM)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.prior = %u is not a prior kind", fn,
                       prior);
    if (!(cfg->prior_epsilon > 0.0f && cfg->prior_epsilon <= 1.0f))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.prior_epsilon = %g is outside (0, 1]",
                       fn, (double)cfg->prior_epsilon);
    if (cfg->prior == NF_PRIOR_CUSTOM && (!cfg->custom_prior.sample || !cfg->custom_prior.pdf))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.prior is NF_PRIOR_CUSTOM but custom_prior.sample or .pdf "
                       "is NULL",
                       fn);
    for (int a = 0; a < 3; ++a) {
        if (!isfinite(cfg->bounds_min[a]) || !isfinite(cfg->bounds_max[a]) ||
            !(cfg->bounds_max[a] > cfg->bounds_min[a]) ||
            !isfinite(cfg->bounds_max[a] - cfg->bounds_min[a]))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: config.bounds on axis %d are not finite with max > min", fn, a);
    }
    if (!(cfg->learning_rate > 0.0f) || !isfinite(cfg->learning_rate))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.learning_rate must be > 0", fn);
    if (!(cfg->beta1 >= 0.0f && cfg->beta1 < 1.0f) || !(cfg->beta2 >= 0.0f && cfg->beta2 < 1.0f))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.beta1/beta2 must be in [0, 1)", fn);
    if (!(cfg->adam_epsilon > 0.0f) || !isfinite(cfg->adam_epsilon))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.adam_epsilon must be > 0", fn);
    /* Decoupled decay multiplies parameters by (1 - lr * wd), which must stay positive. */
    if (!(cfg->weight_decay >= 0.0f) || !(cfg->learning_rate * cfg->weight_decay < 1.0f))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.weight_decay must be >= 0 with learning_rate * "
                       "weight_decay < 1",
                       fn);
    if ((cfg->allocator.alloc == NULL) != (cfg->allocator.free == NULL))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.allocator needs both alloc and free, or neither", fn);
    return NF_OK;
}

size_t nf_layer_param_count(const nf_config *cfg)
{
    size_t in = 4u * cfg->oneblob_bins + 2u * cfg->sh_bands * cfg->sh_bands;
    size_t h = cfg->hidden_width, out = 3u * cfg->spline_bins + 1u;
    size_t count = (in + 1) * h;                             /* input layer  */
    count += (size_t)(cfg->hidden_layers - 1) * (h + 1) * h; /* hidden to hidden */
    count += (h + 1) * out;                                  /* output layer */
    return count;
}
