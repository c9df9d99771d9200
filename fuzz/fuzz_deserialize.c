/*
 * fuzz_deserialize.c - libFuzzer target for nf_model_deserialize (docs/robustness.md).
 *
 * Each input is tried twice: as it is (so truncations, bad magic, versions and checksums are
 * explored), and with its checksum recomputed (so that mutations of the configuration, the
 * sizes and the values reach the validation behind the CRC). Invariants, checked by abort():
 *   - the status is NF_OK, NF_ERROR_FORMAT, or NF_ERROR_INVALID_ARGUMENT for a custom-prior
 *     model loaded without callbacks; never a crash, a leak or a sanitizer report;
 *   - on failure *out is NULL and a message is recorded;
 *   - on success, serializing the model gives back exactly the input bytes, and the model
 *     loads again from them;
 *   - nf_model_create agrees with the loader about the configuration in the header: it
 *     accepts a loaded model's, and refuses (NF_ERROR_INVALID_ARGUMENT) one the loader
 *     refused as an invalid configuration; nf_model_set_learning_rate accepts a rate taken from the
 *     input exactly when nf_model_create accepts the configuration with it, and leaves the
 *     model unchanged when it refuses.
 */
#include "fuzz_common.h"

static float get_f32(const unsigned char *p)
{
    uint32_t bits =
        (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
    float v;
    memcpy(&v, &bits, 4);
    return v;
}

/* The configuration of a header of `size` bytes (docs/format.md, version 1 or 2); 0 if its
 * prior kind or phi map is unknown or a version-2 header is cut short. */
static int header_config(const unsigned char *p, size_t size, nf_config *cfg)
{
    nf_config_init(cfg, NF_PRESET_SMALL);
    uint32_t u[7];
    for (int i = 0; i < 7; ++i)
        u[i] = (uint32_t)p[12 + 4 * i] | (uint32_t)p[13 + 4 * i] << 8 |
               (uint32_t)p[14 + 4 * i] << 16 | (uint32_t)p[15 + 4 * i] << 24;
    if (u[6] > (uint32_t)NF_PRIOR_CUSTOM)
        return 0;
    cfg->coupling_layers = u[0];
    cfg->spline_bins = u[1];
    cfg->hidden_layers = u[2];
    cfg->hidden_width = u[3];
    cfg->oneblob_bins = u[4];
    cfg->sh_bands = u[5];
    cfg->prior = (nf_prior_kind)u[6];
    cfg->custom_prior = nf_fuzz_callbacks();
    cfg->prior_epsilon = get_f32(p + 40);
    for (int a = 0; a < 3; ++a) {
        cfg->bounds_min[a] = get_f32(p + 44 + 4 * a);
        cfg->bounds_max[a] = get_f32(p + 56 + 4 * a);
    }
    cfg->learning_rate = get_f32(p + 68);
    cfg->beta1 = get_f32(p + 72);
    cfg->beta2 = get_f32(p + 76);
    cfg->adam_epsilon = get_f32(p + 80);
    cfg->weight_decay = get_f32(p + 84);
    cfg->phi_map = NF_PHI_INTERVAL;
    uint32_t version = (uint32_t)p[8] | (uint32_t)p[9] << 8 | (uint32_t)p[10] << 16 |
                       (uint32_t)p[11] << 24;
    if (version == 2u) {
        if (size < NF_FUZZ_HEADER + NF_FUZZ_TRAILER)
            return 0;
        uint32_t map = (uint32_t)p[112] | (uint32_t)p[113] << 8 | (uint32_t)p[114] << 16 |
                       (uint32_t)p[115] << 24;
        if (map > (uint32_t)NF_PHI_CIRCULAR)
            return 0;
        cfg->phi_map = (nf_phi_map)map;
    }
    return 1;
}

/* nf_model_create and nf_model_set_learning_rate against the loader's verdict `st` on `data`
 * (whose checksum is valid); `m` is the loaded model when st is NF_OK. */
static void check_create_agrees(const unsigned char *data, size_t size, nf_status st, nf_model *m)
{
    nf_config cfg;
    if (size < NF_FUZZ_HEADER_V1 + NF_FUZZ_TRAILER || !header_config(data, size, &cfg))
        return;
    nf_model *made = NULL;
    if (st == NF_OK) {
        NF_FUZZ_CHECK(nf_model_create(&cfg, &made) == NF_OK, "create refuses a loaded config");
        nf_model_destroy(made);
        /* A learning rate from the input's last bytes (the checksum: any bit pattern). */
        float lr = get_f32(data + size - 4);
        nf_config with = cfg;
        with.learning_rate = lr;
        nf_status created = nf_model_create(&with, &made);
        nf_model_destroy(made);
        size_t before_size = 0, after_size = 0;
        unsigned char *before = nf_fuzz_serialize(m, &before_size);
        nf_status set = nf_model_set_learning_rate(m, lr);
        unsigned char *after = nf_fuzz_serialize(m, &after_size);
        NF_FUZZ_CHECK(before && after && before_size == after_size, "serialize");
        NF_FUZZ_CHECK(created == set, "learning rate %g: create %d, set %d", (double)lr,
                      (int)created, (int)set);
        NF_FUZZ_CHECK(set == NF_OK || memcmp(before, after, before_size) == 0,
                      "a refused nf_model_set_learning_rate changed the model");
        free(before);
        free(after);
    } else if (st == NF_ERROR_FORMAT && strstr(nf_last_error_message(), "invalid configuration")) {
        made = (nf_model *)&cfg;
        NF_FUZZ_CHECK(nf_model_create(&cfg, &made) == NF_ERROR_INVALID_ARGUMENT && !made,
                      "create accepts a configuration the loader refused");
    }
}

static void try_buffer(const unsigned char *data, size_t size, int crc_valid)
{
    static const nf_prior_callbacks none = {NULL, NULL, NULL};
    const nf_prior_callbacks cb = nf_fuzz_callbacks();
    nf_model *m = (nf_model *)&none; /* not NULL: the library must clear it */
    nf_status st = nf_model_deserialize(data, size, &cb, &m);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(st == NF_ERROR_FORMAT, "status %d with callbacks", (int)st);
        NF_FUZZ_CHECK(m == NULL, "*out not cleared");
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "no message");
        if (crc_valid)
            check_create_agrees(data, size, st, NULL);
        return;
    }
    NF_FUZZ_CHECK(m != NULL, "NF_OK without a model");
    size_t out_size = 0;
    unsigned char *out = nf_fuzz_serialize(m, &out_size);
    NF_FUZZ_CHECK(out != NULL, "serialize failed");
    if (data[8] == 1u) {
        /* A version-1 file comes back as version 2: the same header with the version 2 and
         * phi_map NF_PHI_INTERVAL (0) inserted before the parameters, the same arrays, and a
         * checksum of its own. */
        static const unsigned char two[4] = {2, 0, 0, 0}, interval[4] = {0, 0, 0, 0};
        NF_FUZZ_CHECK(out_size == size + 4u && memcmp(out, data, 8) == 0 &&
                          memcmp(out + 8, two, 4) == 0 &&
                          memcmp(out + 12, data + 12, NF_FUZZ_HEADER_V1 - 12u) == 0 &&
                          memcmp(out + NF_FUZZ_HEADER_V1, interval, 4) == 0 &&
                          memcmp(out + NF_FUZZ_HEADER, data + NF_FUZZ_HEADER_V1,
                                 size - NF_FUZZ_HEADER_V1 - NF_FUZZ_TRAILER) == 0,
                      "a version-1 file did not come back as its version-2 form (%zu -> %zu "
                      "bytes)",
                      size, out_size);
    } else {
        NF_FUZZ_CHECK(out_size == size && memcmp(out, data, size) == 0,
                      "the round trip changed the bytes (%zu -> %zu bytes)", size, out_size);
    }
    free(out);
    nf_config cfg;
    NF_FUZZ_CHECK(nf_model_get_config(m, &cfg) == NF_OK, "config");
    /* Without callbacks: the same, except that a custom-prior model is refused. */
    nf_model *again = (nf_model *)&none;
    st = nf_model_deserialize(data, size, &none, &again);
    if (cfg.prior == NF_PRIOR_CUSTOM) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT && again == NULL, "custom without callbacks");
    } else {
        NF_FUZZ_CHECK(st == NF_OK && again != NULL, "status %d without callbacks", (int)st);
        nf_model_destroy(again);
    }
    check_create_agrees(data, size, st, m);
    nf_model_destroy(m);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* A copy of exactly `size` bytes, so that any read past the end is caught by ASan (the
     * fuzzer's own buffer may be larger). */
    unsigned char *copy = (unsigned char *)malloc(size ? size : 1u);
    if (!copy)
        return 0;
    if (size)
        memcpy(copy, data, size);
    int crc_valid = 0;
    if (size >= NF_FUZZ_TRAILER) {
        uint32_t stored = (uint32_t)copy[size - 4] | (uint32_t)copy[size - 3] << 8 |
                          (uint32_t)copy[size - 2] << 16 | (uint32_t)copy[size - 1] << 24;
        crc_valid = stored == nf_fuzz_crc32(copy, size - NF_FUZZ_TRAILER);
    }
    try_buffer(copy, size, crc_valid);
    if (size >= NF_FUZZ_TRAILER && !crc_valid) {
        nf_fuzz_fix_crc(copy, size);
        try_buffer(copy, size, 1);
    }
    free(copy);
    return 0;
}
