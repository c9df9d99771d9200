/*
 * make_seeds.c - writes the committed seed corpus of the model fuzz targets into the
 * directory given on the command line (fuzz/corpus/model). Rebuild the corpus with
 *
 *   cc -std=c11 -O2 -Iinclude fuzz/make_seeds.c <libnisflow> -lm -o /tmp/make_seeds
 *   /tmp/make_seeds fuzz/corpus/model
 *
 * The seeds are small models (the fuzzers run with -max_len 16384) of several
 * configurations and all four priors, fresh, trained and with extreme parameters; and
 * broken files: truncated, a foreign version, a bad checksum, a bad magic, a parameter count
 * that does not match. Deterministic: the same library gives the same bytes.
 */
#include <float.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"

static const char *dir_name;

static void write_seed(const char *name, const unsigned char *bytes, size_t size)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", dir_name, name);
    FILE *f = fopen(path, "wb");
    if (!f || fwrite(bytes, 1, size, f) != size || fclose(f) != 0) {
        fprintf(stderr, "make_seeds: cannot write %s\n", path);
        exit(1);
    }
    printf("%-36s %6zu bytes\n", name, size);
}

static uint64_t state = 0x9E3779B97F4A7C15ull;
static float next_unit(void) /* [-1, 1) */
{
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return (float)(state >> 40) * 0x1p-23f - 1.0f;
}

typedef struct seed_spec {
    const char *name;
    uint32_t layers, bins, hidden_layers, width, blob, sh;
    nf_prior_kind prior;
    int steps;   /* training steps (moments, step count)         */
    float scale; /* 0: fresh; else parameters uniform in +-scale */
} seed_spec;

static nf_model *make(const seed_spec *s)
{
    nf_config cfg;
    nf_config_init(&cfg, NF_PRESET_SMALL);
    cfg.coupling_layers = s->layers;
    cfg.spline_bins = s->bins;
    cfg.hidden_layers = s->hidden_layers;
    cfg.hidden_width = s->width;
    cfg.oneblob_bins = s->blob;
    cfg.sh_bands = s->sh;
    cfg.prior = s->prior;
    cfg.custom_prior = nf_fuzz_callbacks();
    cfg.bounds_min[0] = -2.0f;
    cfg.bounds_max[2] = 3.0f;
    nf_model *m = NULL;
    if (nf_model_create(&cfg, &m) != NF_OK) {
        fprintf(stderr, "make_seeds: %s: %s\n", s->name, nf_last_error_message());
        exit(1);
    }
    size_t count = nf_param_count(m);
    float *p = malloc(count * sizeof *p);
    if (!p)
        exit(1);
    if (s->scale != 0.0f) {
        for (size_t i = 0; i < count; ++i)
            p[i] = s->scale * next_unit();
        nf_set_params(m, p);
    }
    enum { N = 16 };
    nf_context ctx[N];
    float dir[3 * N], w[N];
    for (int step = 0; step < s->steps; ++step) {
        for (int i = 0; i < N; ++i) {
            for (int a = 0; a < 3; ++a) {
                ctx[i].position[a] = 0.5f + next_unit();
                ctx[i].normal[a] = next_unit();
                ctx[i].wo[a] = next_unit();
                dir[3 * i + a] = next_unit();
            }
            ctx[i].normal[2] += 2.0f; /* keep the vectors away from zero */
            ctx[i].wo[2] += 2.0f;
            dir[3 * i] += 2.0f;
            w[i] = 1.0f + next_unit();
        }
        nf_train_step(m, N, ctx, dir, w, NULL); /* NF_ERROR_NUMERIC is fine for extreme ones */
    }
    free(p);
    return m;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: make_seeds DIRECTORY\n");
        return 2;
    }
    dir_name = argv[1];
    static const seed_spec specs[] = {
        {"tiny-uniform-direction.nfm", 1, 2, 1, 1, 2, 0, NF_PRIOR_UNIFORM_DIRECTION, 0, 0.0f},
        {"tiny-uniform-angle-trained.nfm", 1, 2, 1, 2, 2, 1, NF_PRIOR_UNIFORM_ANGLE, 3, 0.0f},
        {"two-layers-cosine-trained.nfm", 2, 3, 2, 3, 2, 1, NF_PRIOR_COSINE, 4, 0.5f},
        {"three-layers-custom.nfm", 3, 4, 1, 4, 4, 2, NF_PRIOR_CUSTOM, 2, 1.0f},
        {"cosine-extreme-params.nfm", 2, 2, 1, 2, 3, 1, NF_PRIOR_COSINE, 0, 1e30f},
        {"custom-huge-params.nfm", 2, 3, 2, 2, 2, 0, NF_PRIOR_CUSTOM, 1, FLT_MAX},
        {"sixteen-layers.nfm", 16, 2, 1, 1, 2, 0, NF_PRIOR_COSINE, 1, 2.0f},
        {"eight-hidden-layers.nfm", 2, 2, 8, 2, 2, 0, NF_PRIOR_UNIFORM_DIRECTION, 2, 1.0f},
        {"sh-six-bands.nfm", 1, 2, 1, 1, 2, 6, NF_PRIOR_CUSTOM, 1, 0.3f},
        {"sixty-four-bins.nfm", 1, 64, 1, 1, 2, 0, NF_PRIOR_UNIFORM_ANGLE, 2, 3.0f},
        {"sixty-four-blob-bins.nfm", 1, 2, 1, 1, 64, 1, NF_PRIOR_COSINE, 1, 10.0f},
    };
    for (size_t k = 0; k < sizeof specs / sizeof specs[0]; ++k) {
        nf_model *m = make(&specs[k]);
        size_t size = 0;
        unsigned char *bytes = nf_fuzz_serialize(m, &size);
        if (!bytes || size > 16384) {
            fprintf(stderr, "make_seeds: %s: %zu bytes\n", specs[k].name, size);
            return 1;
        }
        write_seed(specs[k].name, bytes, size);
        if (k == 2) {
            /* Broken variants of one seed. */
            unsigned char *b = malloc(size);
            if (!b)
                return 1;
            write_seed("broken-header-only.nfm", bytes, NF_FUZZ_HEADER);
            write_seed("broken-truncated-half.nfm", bytes, size / 2);
            write_seed("broken-missing-crc.nfm", bytes, size - NF_FUZZ_TRAILER);
            memcpy(b, bytes, size);
            b[8] = 2; /* format version 2, valid checksum */
            nf_fuzz_fix_crc(b, size);
            write_seed("broken-version-2.nfm", b, size);
            memcpy(b, bytes, size);
            b[NF_FUZZ_HEADER + 40] ^= 0x10; /* one bit of a parameter, stale checksum */
            write_seed("broken-bit-flip.nfm", b, size);
            memcpy(b, bytes, size);
            b[0] = 'M'; /* bad magic */
            nf_fuzz_fix_crc(b, size);
            write_seed("broken-magic.nfm", b, size);
            memcpy(b, bytes, size);
            b[104] ^= 1; /* parameter count off by one, valid checksum */
            nf_fuzz_fix_crc(b, size);
            write_seed("broken-param-count.nfm", b, size);
            free(b);
        }
        free(bytes);
        nf_model_destroy(m);
    }
    return 0;
}
