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
#endif
        break;
    case NF_ISA_AVX512:
#if defined(NF_HAVE_X86_KERNELS)
        if (nf_cpu_has_avx512())
            return &nf_kernels_avx512;
#endif
        break;
    }
    nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: config.isa = %u is not supported by this CPU or build",
            fn, (unsigned)isa);
    return NULL;
}

const char *nf_model_isa_name(const nf_model *m) { return m ? m->kernels->name : ""; }
