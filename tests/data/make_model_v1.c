/*
 * make_model_v1.c - writes model-v1.nfm and model-v1.txt, the format-version-1 file that
 * tests/correctness/test_persistence.c loads: a model file as libnisflow 0.1.0 saved it
 * (before NF_PHI_CIRCULAR and format version 2), and the densities that library gave.
 *
 * Not built by CMake: it needs the library of commit 6d18009 (format version 1), e.g.
 *   git worktree add /tmp/v1 6d18009 && cmake -S /tmp/v1 -B /tmp/v1/b -DCMAKE_BUILD_TYPE=Release
 *   cmake --build /tmp/v1/b --target nisflow
 *   cc -O2 -I/tmp/v1/include tests/data/make_model_v1.c /tmp/v1/b/libnisflow.a -lm -o make_v1
 *   (cd tests/data && ../../make_v1)   # writes the two files here
 *
 * model-v1.txt: one line per (context, direction): position, normal, wo, direction (12
 * floats, %a) and nf_pdf's density (%a), computed with NF_ISA_GENERIC.
 */
#include <stdio.h>
#include <stdlib.h>

#include <nisflow/nisflow.h>

static uint64_t state = 0x853c49e6748fea9bu;

/* A uniform float in [-1, 1) from a 64-bit LCG (the top 24 bits). */
static float next(void)
{
    state = state * 6364136223846793005u + 1442695040888963407u;
    return (float)(state >> 40) / 8388608.0f - 1.0f;
}

int main(void)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.isa = NF_ISA_GENERIC;
    nf_model *m = NULL;
    if (nf_model_create(&cfg, &m) != NF_OK)
        return 1;
    size_t n = nf_model_param_count(m);
    float *p = malloc(n * sizeof *p);
    if (!p || nf_model_get_params(m, p) != NF_OK)
        return 1;
    for (size_t i = 0; i < n; ++i)
        p[i] += 0.3f * next();
    if (nf_model_set_params(m, p) != NF_OK || nf_model_save(m, "model-v1.nfm") != NF_OK)
        return 1;
    FILE *f = fopen("model-v1.txt", "w");
    if (!f)
        return 1;
    for (int k = 0; k < 64; ++k) {
        nf_context c;
        float d[3], pdf;
        for (int a = 0; a < 3; ++a) {
            c.position[a] = 0.5f + 0.5f * next();
            c.normal[a] = next();
            c.wo[a] = next();
            d[a] = next();
        }
        if (nf_pdf(m, 1, &c, d, &pdf) != NF_OK)
            return 1;
        const float *v[4] = {c.position, c.normal, c.wo, d};
        for (int j = 0; j < 4; ++j)
            for (int a = 0; a < 3; ++a)
                fprintf(f, "%a ", (double)v[j][a]);
        fprintf(f, "%a\n", (double)pdf);
    }
    fclose(f);
    free(p);
    nf_model_destroy(m);
    return 0;
}
