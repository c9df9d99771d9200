/*
 * kernel.c - the batch kernels behind nf_sample, nf_pdf and nf_loss_gradient. CMake compiles
 * this file once per instruction set with NF_KERNEL_ISA set to generic, avx2 or avx512 (and
 * the matching -m flags); each copy defines the table nf_kernels_<isa>. Inputs arrive
 * validated from flow.c and train.c.
 */
#include <math.h>

#include "flow_eval.h"
#include "tile_flow.h"
#include "internal.h"

#ifndef NF_KERNEL_ISA
#define NF_KERNEL_ISA generic
#endif
#define NF_KERNEL_CAT2(a, b) a##b
#define NF_KERNEL_CAT(a, b) NF_KERNEL_CAT2(a, b)
#define NF_KERNEL_STR2(a) #a
#define NF_KERNEL_STR(a) NF_KERNEL_STR2(a)

/* Tiles of NF_TILE samples (tile_flow.h): the scratch is declared once per call. */
static nf_status nf_kernel_sample(const nf_model *m, size_t n, const nf_context *ctx,
                                  const float *u, float *dir, float *pdf)
{
    nf_tile_work w;
    for (size_t i = 0; i < n; i += NF_TILE) {
        uint32_t count = (uint32_t)(n - i < NF_TILE ? n - i : NF_TILE);
        nf_status st = nf_tile_sample(m, ctx + i, u + 2 * i, count, dir + 3 * i,
                                      pdf ? pdf + i : NULL, &w);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

static nf_status nf_kernel_pdf(const nf_model *m, size_t n, const nf_context *ctx,
                               const float *dir, float *pdf)
{
    nf_tile_work w;
    for (size_t i = 0; i < n; i += NF_TILE) {
        uint32_t count = (uint32_t)(n - i < NF_TILE ? n - i : NF_TILE);
        nf_status st = nf_tile_pdf(m, ctx + i, dir + 3 * i, count, pdf + i, &w);
        if (st != NF_OK)
            return st;
    }
    return NF_OK;
}

static nf_status nf_kernel_gradient(const nf_model *m, size_t n, const nf_context *ctx,
                                    const float *dir, const float *weight, double total,
                                    double *loss, float *grad)
{
    nf_scratch sc;
    double acc = 0.0;
    for (size_t i = 0; i < n; ++i) {
        if (weight[i] == 0.0f)
            continue; /* contributes nothing, and its context need not be evaluated */
        nf_point pt;
        nf_point_prepare(m, &ctx[i], &pt);
        float s[2];
        double p_s = 0.0, log_p = 0.0, share = (double)weight[i] / total;
        nf_to_square(dir + 3 * i, s);
        nf_status st = nf_flow_density(m, &pt, s, (float)-share, grad, &p_s, &log_p, &sc);
        if (st != NF_OK)
            return st;
        /* log p_w = log p_s - log(2 pi^2 sin theta) */
        double sin_theta = (double)nf_maxf(nf_sin_pi(s[0]), NF_SIN_THETA_MIN);
        acc -= share * (log_p - log((double)NF_TWO_PI_SQUARED * sin_theta));
    }
    *loss = acc;
    return NF_OK;
}

const nf_kernels NF_KERNEL_CAT(nf_kernels_, NF_KERNEL_ISA) = {
    NF_KERNEL_STR(NF_KERNEL_ISA), nf_kernel_sample, nf_kernel_pdf, nf_kernel_gradient};
