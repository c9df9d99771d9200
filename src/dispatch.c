/*
 * dispatch.c - picks the kernels (kernel.c, compiled per instruction set) that this CPU can
 * run, so one binary of the library is fast on every x86-64 without -march=native.
 */
#include "internal.h"
#include "kernels/kernels.h"

#if defined(NF_HAVE_X86_KERNELS)
static int nf_cpu_has_avx2(void)
{
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

static int nf_cpu_has_avx512(void)
{
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") &&
           nf_cpu_has_avx2();
}
#endif

const nf_kernels *nf_select_kernels(nf_isa isa, const char *fn)
{
    const char *lacks = "the x86-64 kernels (this build has only the generic ones)";
    switch (isa) {
    case NF_ISA_AUTO:
#if defined(NF_HAVE_X86_KERNELS)
        if (nf_cpu_has_avx512())
            return &nf_kernels_avx512;
        if (nf_cpu_has_avx2())
            return &nf_kernels_avx2;
#endif
        return &nf_kernels_generic;
    case NF_ISA_GENERIC: return &nf_kernels_generic;
    case NF_ISA_AVX2:
#if defined(NF_HAVE_X86_KERNELS)
        if (nf_cpu_has_avx2())
            return &nf_kernels_avx2;
        lacks = "AVX2 and FMA (this CPU lacks one of them)";
#endif
        break;
    case NF_ISA_AVX512:
#if defined(NF_HAVE_X86_KERNELS)
        if (nf_cpu_has_avx512())
            return &nf_kernels_avx512;
        lacks = "AVX-512 F/VL/DQ/BW and AVX2 (this CPU lacks one of them)";
#endif
        break;
    default:
        nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: isa = %u is not an nf_isa value", fn,
                (unsigned)isa);
        return NULL;
    }
    nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: isa = %u (%s) needs %s", fn, (unsigned)isa,
            isa == NF_ISA_AVX2 ? "NF_ISA_AVX2" : "NF_ISA_AVX512", lacks);
    return NULL;
}

const char *nf_model_isa_name(const nf_model *m) { return m ? m->kernels->name : ""; }

nf_status nf_model_set_isa(nf_model *m, nf_isa isa)
{
    if (!m)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "nf_model_set_isa: model is NULL");
    const nf_kernels *kernels = nf_select_kernels(isa, "nf_model_set_isa");
    if (!kernels)
        return NF_ERROR_INVALID_ARGUMENT; /* the message says what is missing */
    if (kernels != m->kernels) { /* points hold context sums of the old kernels: prepare again */
        nf_generation_begin(m);
        m->kernels = kernels;
        nf_generation_end(m);
    }
    m->cfg.isa = isa;
    return NF_OK;
}
