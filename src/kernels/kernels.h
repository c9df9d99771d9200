/*
 * kernels.h - the table of kernels that kernels/kernel.c defines once per instruction set
 * (nf_kernels_generic, _avx2, _avx512) and dispatch.c picks from: the one boundary between
 * the API files of src/, compiled once, and the per-ISA code of src/kernels/.
 */
#ifndef NISFLOW_KERNELS_KERNELS_H
#define NISFLOW_KERNELS_KERNELS_H

#include "internal.h"

struct nf_kernels {
    const char *name;
    /* Inputs already validated by the public entry points. */
    nf_status (*sample)(const nf_model *m, size_t n, const nf_context *ctx, const float *u,
                        float *dir, float *pdf);
    nf_status (*pdf)(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                     float *pdf);
    /* Adds the gradient of the loss (weights normalized by `total` > 0) into grad and returns
     * the loss in *loss. `work`: NULL, or gradient_work_bytes of caller memory aligned to
     * NF_WORK_ALIGN, which then holds the tiles' work area instead of the stack. */
    nf_status (*gradient)(const nf_model *m, size_t n, const nf_context *ctx, const float *dir,
                          const float *weight, double total, double *loss, float *grad, void *work);
    /* The shading-point API (nisflow/point.h) on kernels/point.h, inputs validated by
     * point.c. point_sample and point_pdf take points[i * stride] for direction i: stride 0
     * for n directions at one point, 1 for one direction at each of n points. */
    void (*point_prepare)(const nf_model *m, const nf_context *ctx, const nf_prior_callbacks *prior,
                          nf_shading_point *point);
    nf_status (*point_sample)(const nf_model *m, const nf_shading_point *points, size_t n,
                              size_t stride, const float *u, float *dir, float *pdf);
    nf_status (*point_pdf)(const nf_model *m, const nf_shading_point *points, size_t n,
                           size_t stride, const float *dir, float *pdf);
    nf_status (*point_sample_and_pdf)(const nf_model *m, const nf_shading_point *point,
                                      const float u[2], float dir[3], float *pdf,
                                      const float eval_dir[3], float *eval_pdf);
    /* One AdamW step from parameters p and moments m, v with gradient g into p_new, m_new,
     * v_new (count floats each, no overlap); returns 0 if any new value is not finite. */
    int (*adamw)(const nf_adamw_step *step, size_t count, const float *g, const float *p,
                 const float *m, const float *v, float *p_new, float *m_new, float *v_new);
    size_t gradient_work_bytes; /* the gradient's work area, for any configuration */
};

/* The alignment of a caller's work area (the kernels' widest vectors). */
#define NF_WORK_ALIGN 64u

extern const nf_kernels nf_kernels_generic;
#if defined(NF_HAVE_X86_KERNELS)
extern const nf_kernels nf_kernels_avx2;
extern const nf_kernels nf_kernels_avx512;
#endif

/* The kernels for a requested instruction set, or NULL (with a message) if this CPU or build
 * lacks it. */
const nf_kernels *nf_select_kernels(nf_isa isa, const char *fn);

#endif /* NISFLOW_KERNELS_KERNELS_H */
