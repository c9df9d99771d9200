/*
 * deprecated.c - the names that 0.8.1 renamed, kept until 0.10 as calls of the new ones
 * (CHANGELOG.md). Their errors carry the new names' messages.
 */
#include "internal.h"

size_t nf_param_count(const nf_model *m) { return nf_model_param_count(m); }

nf_status nf_get_params(const nf_model *m, float *params) { return nf_model_get_params(m, params); }

nf_status nf_set_params(nf_model *m, const float *params) { return nf_model_set_params(m, params); }

nf_status nf_set_learning_rate(nf_model *m, float learning_rate)
{
    return nf_model_set_learning_rate(m, learning_rate);
}

nf_status nf_model_config(const nf_model *model, nf_config *out)
{
    return nf_model_get_config(model, out);
}

nf_status nf_points_sample(const nf_model *m, size_t n, const nf_shading_point *points,
                           const float *u, float *dir, float *pdf)
{
    return nf_point_sample_batch(m, n, points, u, dir, pdf);
}

nf_status nf_points_pdf(const nf_model *m, size_t n, const nf_shading_point *points,
                        const float *dir, float *pdf)
{
    return nf_point_pdf_batch(m, n, points, dir, pdf);
}
