/*
 * make_seeds.c - writes the committed seed corpora of the fuzz targets: the model files of
 * fuzz_deserialize and fuzz_model_api into the first directory given on the command line
 * (fuzz/corpus/model) and, if a second one is given, the programs of fuzz_point into it
 * (fuzz/corpus/point). Rebuild the corpora with
 *
 *   cc -std=c11 -O2 -Iinclude fuzz/make_seeds.c <libnisflow> -lm -o /tmp/make_seeds
 *   /tmp/make_seeds fuzz/corpus/model fuzz/corpus/point
 *
 * The seeds are small models (the fuzzers run with -max_len 16384) of several
 * configurations and all four priors, fresh, trained and with extreme parameters; and
 * broken files: truncated, a foreign version, a bad checksum, a bad magic, a parameter count
 * that does not match. The point programs follow fuzz_point.c's encoding: each prepares
 * points (ordinary, hostile and per-point-prior contexts), samples and evaluates them alone and
 * in batches, changes the parameters, corrupts, copies and clones. Deterministic: the same
 * library gives the same bytes.
 */
#include <float.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fuzz_common.h"
#include "shading_point.h"

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
    /* Both phi maps: the trained seeds (odd step counts) with the one that is not the
     * default. */
    cfg.phi_map = s->steps & 1 ? NF_PHI_INTERVAL : NF_PHI_CIRCULAR;
    cfg.bounds_min[0] = -2.0f;
    cfg.bounds_max[2] = 3.0f;
    nf_model *m = NULL;
    if (nf_model_create(&cfg, &m) != NF_OK) {
        fprintf(stderr, "make_seeds: %s: %s\n", s->name, nf_last_error_message());
        exit(1);
    }
    size_t count = nf_model_param_count(m);
    float *p = malloc(count * sizeof *p);
    if (!p)
        exit(1);
    if (s->scale != 0.0f) {
        for (size_t i = 0; i < count; ++i)
            p[i] = s->scale * next_unit();
        nf_model_set_params(m, p);
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

/* ---- programs of fuzz_point (its reader: bytes, little-endian u32, floats as selector 0
 * followed by their bits) ---------------------------------------------------------------- */

typedef struct program {
    unsigned char b[4096];
    size_t n;
} program;

static void put(program *p, unsigned v)
{
    if (p->n < sizeof p->b)
        p->b[p->n++] = (unsigned char)v;
}

static void put_u32(program *p, uint32_t v)
{
    for (int i = 0; i < 4; ++i)
        put(p, (v >> (8 * i)) & 0xffu);
}

static void put_float(program *p, float f)
{
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    put(p, 0);
    put_u32(p, bits);
}

/* arch: 0 preset, 1 uncached 8 x 64, 2 smallest, 3 odd widths; scale index into
 * fuzz_point's table (0, 0.1, 0.3, 1, 10, 1e6, 1e30, FLT_MAX). */
static void header(program *p, int large, unsigned arch, nf_prior_kind prior, nf_isa isa,
                   unsigned scale)
{
    p->n = 0;
    put(p, (large ? 1u : 0u) | arch << 1 | (unsigned)prior << 3 | (unsigned)isa << 5);
    put(p, scale);
    put_u32(p, 12345u);
    put(p, 0x11); /* the junk pattern of unprepared slots */
}

static void prepare(program *p, unsigned slot, int per_point_prior, const float c[9])
{
    put(p, 0);
    put(p, slot);
    put(p, per_point_prior ? 3u : 0u);
    for (int i = 0; i < 9; ++i)
        put_float(p, c[i]);
    put_float(p, 0.0f); /* phase_g (flags bit 4 clear: a float) */
}

static void sample(program *p, unsigned slot, unsigned n, float u0)
{
    put(p, 2);
    put(p, n - 1u);
    put(p, slot);
    for (unsigned i = 0; i < 2 * n; ++i)
        put_float(p, u0 + 0.37f * (float)i - (float)(int)(u0 + 0.37f * (float)i));
    put(p, 1); /* with pdf */
}

static void evaluate(program *p, unsigned slot, unsigned n)
{
    put(p, 3);
    put(p, n - 1u);
    put(p, slot);
    for (unsigned i = 0; i < n; ++i) {
        put_float(p, 0.3f * (float)i - 1.0f);
        put_float(p, 0.5f);
        put_float(p, (float)(i % 3) - 1.0f);
    }
}

/* nf_point_sample_and_pdf: op_sample's byte of options with bits 3 and 4 set, then the
 * direction to evaluate. with_pdf 0 passes pdf = NULL. */
static void sample_and_pdf(program *p, unsigned slot, float u0, int with_pdf, const float d[3])
{
    put(p, 2);
    put(p, 0); /* n = 1 */
    put(p, slot);
    put_float(p, u0);
    put_float(p, 1.0f - u0);
    put(p, 0x18u | (with_pdf ? 1u : 0u));
    for (int a = 0; a < 3; ++a)
        put_float(p, d[a]);
}

static void batch(program *p, unsigned n, int pdf)
{
    put(p, pdf ? 5 : 4);
    put(p, n - 1u);
    put(p, 0);
    for (unsigned i = 0; i < n; ++i)
        put(p, i % 4u);
    for (unsigned i = 0; i < (pdf ? 3u : 2u) * n; ++i)
        put_float(p, pdf ? 0.25f * (float)(i % 5) - 0.5f : 0.13f * (float)(i % 7));
    if (!pdf)
        put(p, 1);
}

static void program_seeds(const char *directory)
{
    dir_name = directory;
    const float plain[9] = {0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.3f, -0.5f, 0.81f};
    const float pole[9] = {0.0f, 1.0f, 0.0f, 0.0f, 0.0f, -1.0f, 0.2f, 0.4f, -0.89f};
    const float far[9] = {1e30f, -FLT_MAX, 7.0f, 1e-15f, 1e-15f, 1e-15f, 1e12f, 0.0f, 3.0f};
    const float nan_normal[9] = {0.5f, 0.5f, 0.5f, NAN, 0.0f, 1.0f, 0.0f, 0.0f, 1.0f};
    const float zero_wo[9] = {0.5f, 0.5f, 0.5f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f};
    const float tiny[9] = {0.1f, 0.2f, 0.3f, 1e-16f, 1e-16f, 1e-16f, FLT_TRUE_MIN, 0.0f, 1.0f};
    program p;

    /* Prepare, sample, evaluate, train (stale), prepare again, clone. */
    header(&p, 0, 0, NF_PRIOR_COSINE, NF_ISA_AUTO, 2);
    prepare(&p, 0, 0, plain);
    prepare(&p, 1, 0, pole);
    sample(&p, 0, 5, 0.1f);
    evaluate(&p, 1, 4);
    batch(&p, 6, 0);
    batch(&p, 6, 1);
    put(&p, 7), put(&p, 0), put(&p, 1), put(&p, 2), put(&p, 3), put(&p, 0); /* train */
    sample(&p, 0, 3, 0.2f);
    prepare(&p, 0, 0, plain);
    sample(&p, 0, 3, 0.2f);
    put(&p, 8), put(&p, 0); /* clone */
    write_seed("cosine-train-stale.bin", p.b, p.n);

    /* The large preset, custom prior with per-point callbacks, huge parameters. */
    header(&p, 1, 0, NF_PRIOR_CUSTOM, NF_ISA_AUTO, 7);
    prepare(&p, 0, 1, plain);
    prepare(&p, 1, 0, far);
    prepare(&p, 2, 1, pole);
    sample(&p, 0, 20, 0.05f);
    sample(&p, 2, 2, 0.9f);
    evaluate(&p, 1, 7);
    batch(&p, 8, 0);
    batch(&p, 8, 1);
    write_seed("custom-per-point-huge.bin", p.b, p.n);

    /* Uncached (8 x 64), corrupted bytes, a copy, nf_model_set_params. */
    header(&p, 0, 1, NF_PRIOR_UNIFORM_DIRECTION, NF_ISA_GENERIC, 4);
    prepare(&p, 0, 0, plain);
    put(&p, 9), put(&p, 1), put(&p, 0); /* copy slot 0 to slot 1 */
    put(&p, 6), put(&p, 1), put(&p, 40), put(&p, 0x80); /* model id of slot 1 */
    put(&p, 6), put(&p, 0), put(&p, 200), put(&p, 0x10), put(&p, 3); /* cache of slot 0 */
    sample(&p, 0, 4, 0.3f);
    sample(&p, 1, 4, 0.3f);
    put(&p, 7), put(&p, 1), put_float(&p, 0.75f), put_u32(&p, 77u); /* set params */
    evaluate(&p, 0, 3);
    write_seed("uncached-corrupt-copy.bin", p.b, p.n);

    /* The smallest network, hostile contexts, u and directions. */
    header(&p, 0, 2, NF_PRIOR_UNIFORM_ANGLE, NF_ISA_AUTO, 3);
    prepare(&p, 0, 0, nan_normal);
    prepare(&p, 1, 0, zero_wo);
    prepare(&p, 2, 0, tiny);
    prepare(&p, 3, 0, far);
    sample(&p, 3, 2, 0.5f);
    put(&p, 2), put(&p, 1), put(&p, 3), put_float(&p, NAN), put_float(&p, 2.0f),
        put_float(&p, -1.0f), put_float(&p, FLT_MAX), put(&p, 1);
    put(&p, 3), put(&p, 0), put(&p, 3), put_float(&p, 0.0f), put_float(&p, 0.0f),
        put_float(&p, 0.0f);
    write_seed("tiny-hostile-inputs.bin", p.b, p.n);

    /* Odd widths, the largest SH and one-blob, AVX2 kernels, apply_gradient. */
    header(&p, 1, 3, NF_PRIOR_COSINE, NF_ISA_AVX2, 5);
    prepare(&p, 0, 0, pole);
    prepare(&p, 1, 0, plain);
    batch(&p, 5, 1);
    put(&p, 7), put(&p, 2), put_float(&p, 1e-3f), put_u32(&p, 5u); /* apply a gradient */
    batch(&p, 5, 0);
    prepare(&p, 1, 0, plain);
    sample(&p, 1, 9, 0.6f);
    write_seed("odd-widths-gradient.bin", p.b, p.n);

    /* A draw and another direction's density in one call, on both presets: ordinary, without
     * pdf, a zero direction (refused), after a training step (stale), on a per-point prior. */
    const float up[3] = {0.0f, 0.3f, 1.0f}, zero[3] = {0.0f, 0.0f, 0.0f};
    for (int large = 0; large < 2; ++large) {
        header(&p, large, 0, large ? NF_PRIOR_CUSTOM : NF_PRIOR_COSINE, NF_ISA_AUTO, 2);
        prepare(&p, 0, large, plain);
        prepare(&p, 1, 0, pole);
        sample_and_pdf(&p, 0, 0.2f, 1, up);
        sample_and_pdf(&p, 1, 0.7f, 0, up);
        sample_and_pdf(&p, 0, 0.4f, 1, zero);
        put(&p, 7), put(&p, 0), put(&p, 1), put(&p, 2), put(&p, 3), put(&p, 0); /* train */
        sample_and_pdf(&p, 0, 0.9f, 1, up);
        write_seed(large ? "sample-and-pdf-large-custom.bin" : "sample-and-pdf-small.bin", p.b,
                   p.n);
    }
}

int main(int argc, char **argv)
{
    if (argc != 2 && argc != 3) {
        fprintf(stderr, "usage: make_seeds MODEL_DIRECTORY [POINT_DIRECTORY]\n");
        return 2;
    }
    if (argc == 3)
        program_seeds(argv[2]);
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
            b[8] = 3; /* format version 3, valid checksum */
            nf_fuzz_fix_crc(b, size);
            write_seed("broken-version-3.nfm", b, size);
            memcpy(b, bytes, size);
            b[NF_FUZZ_HEADER_V1] = 2; /* phi map 2, valid checksum */
            nf_fuzz_fix_crc(b, size);
            write_seed("broken-phi-map.nfm", b, size);
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
