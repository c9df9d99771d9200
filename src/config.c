/*
 * config.c - presets, defaults and validation of nf_config.
 */
#include <float.h>
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
    cfg->phi_map = NF_PHI_CIRCULAR;
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

/* Every float of the configuration goes through here (docs/robustness.md, "Configuration
 * ranges"): NaN, infinities, denormals and values outside [lo, hi] are refused, with a
 * message naming the field and its range. -0 counts as 0. */
static nf_status nf_check_float(const char *fn, const char *field, float v, float lo, float hi)
{
    int denormal = fpclassify(v) == FP_SUBNORMAL;
    if (!(v >= lo && v <= hi) || denormal)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.%s = %g is outside [%g, %g]%s", fn,
                       field, (double)v, (double)lo, (double)hi,
                       denormal ? " (denormals are refused)" : "");
    return NF_OK;
}

nf_status nf_config_validate(const nf_config *cfg, const char *fn)
{
    if (!cfg)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config is NULL", fn);
    /* A config nobody filled (zeroed, say) fails on its first field: say what to do. */
    if (cfg->coupling_layers == 0 && cfg->spline_bins == 0 && cfg->hidden_width == 0)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.coupling_layers, spline_bins and hidden_width are 0: fill the "
                       "config with nf_config_init(&cfg, NF_PRESET_SMALL) first, then change the "
                       "fields you need",
                       fn);
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
    unsigned phi_map = (unsigned)cfg->phi_map;
    if (phi_map > (unsigned)NF_PHI_CIRCULAR)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.phi_map = %u is not a phi map", fn,
                       phi_map);
    if ((st = nf_check_float(fn, "prior_epsilon", cfg->prior_epsilon, NF_PRIOR_EPSILON_MIN, 1.0f)))
        return st;
    if (cfg->prior == NF_PRIOR_CUSTOM && (!cfg->custom_prior.sample || !cfg->custom_prior.pdf))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.prior is NF_PRIOR_CUSTOM but custom_prior.sample or .pdf "
                       "is NULL",
                       fn);
    static const char *const min_names[3] = {"bounds_min[0]", "bounds_min[1]", "bounds_min[2]"};
    static const char *const max_names[3] = {"bounds_max[0]", "bounds_max[1]", "bounds_max[2]"};
    for (int a = 0; a < 3; ++a) {
        if ((st = nf_check_float(fn, min_names[a], cfg->bounds_min[a], -FLT_MAX, FLT_MAX)) ||
            (st = nf_check_float(fn, max_names[a], cfg->bounds_max[a], -FLT_MAX, FLT_MAX)))
            return st;
        /* The position encoding divides by the extent: a normal extent keeps 1 / extent
         * finite (1 / FLT_MIN is 8.5e37). */
        float extent = cfg->bounds_max[a] - cfg->bounds_min[a];
        if (!(extent >= FLT_MIN && extent <= FLT_MAX))
            return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                           "%s: config.bounds_max[%d] - bounds_min[%d] = %g is outside [%g, %g]",
                           fn, a, a, (double)extent, (double)FLT_MIN, (double)FLT_MAX);
    }
    if ((st = nf_check_float(fn, "learning_rate", cfg->learning_rate, NF_LEARNING_RATE_MIN,
                             NF_LEARNING_RATE_MAX)) ||
        (st = nf_check_float(fn, "beta1", cfg->beta1, 0.0f, NF_BETA1_MAX)) ||
        (st = nf_check_float(fn, "beta2", cfg->beta2, 0.0f, NF_BETA2_MAX)) ||
        (st = nf_check_float(fn, "adam_epsilon", cfg->adam_epsilon, NF_ADAM_EPSILON_MIN,
                             NF_ADAM_EPSILON_MAX)) ||
        (st = nf_check_float(fn, "weight_decay", cfg->weight_decay, 0.0f, NF_WEIGHT_DECAY_MAX)))
        return st;
    /* Decoupled decay multiplies parameters by (1 - lr * wd), which must stay positive. */
    if (!(cfg->learning_rate * cfg->weight_decay < 1.0f))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: config.learning_rate * weight_decay = %g must be < 1", fn,
                       (double)(cfg->learning_rate * cfg->weight_decay));
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
