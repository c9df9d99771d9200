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
 *     loads again from them.
 */
#include "fuzz_common.h"

static void try_buffer(const unsigned char *data, size_t size)
{
    static const nf_prior_callbacks none = {NULL, NULL, NULL};
    const nf_prior_callbacks cb = nf_fuzz_callbacks();
    nf_model *m = (nf_model *)&none; /* not NULL: the library must clear it */
    nf_status st = nf_model_deserialize(data, size, &cb, &m);
    if (st != NF_OK) {
        NF_FUZZ_CHECK(st == NF_ERROR_FORMAT, "status %d with callbacks", (int)st);
        NF_FUZZ_CHECK(m == NULL, "*out not cleared");
        NF_FUZZ_CHECK(nf_last_error_message()[0] != '\0', "no message");
        return;
    }
    NF_FUZZ_CHECK(m != NULL, "NF_OK without a model");
    size_t out_size = 0;
    unsigned char *out = nf_fuzz_serialize(m, &out_size);
    NF_FUZZ_CHECK(out != NULL, "serialize failed");
    NF_FUZZ_CHECK(out_size == size && memcmp(out, data, size) == 0,
                  "the round trip changed the bytes (%zu -> %zu bytes)", size, out_size);
    free(out);
    nf_config cfg;
    NF_FUZZ_CHECK(nf_model_config(m, &cfg) == NF_OK, "config");
    /* Without callbacks: the same, except that a custom-prior model is refused. */
    nf_model *again = (nf_model *)&none;
    st = nf_model_deserialize(data, size, &none, &again);
    if (cfg.prior == NF_PRIOR_CUSTOM) {
        NF_FUZZ_CHECK(st == NF_ERROR_INVALID_ARGUMENT && again == NULL, "custom without callbacks");
    } else {
        NF_FUZZ_CHECK(st == NF_OK && again != NULL, "status %d without callbacks", (int)st);
        nf_model_destroy(again);
    }
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
    try_buffer(copy, size);
    if (size >= NF_FUZZ_TRAILER) {
        uint32_t stored = (uint32_t)copy[size - 4] | (uint32_t)copy[size - 3] << 8 |
                          (uint32_t)copy[size - 2] << 16 | (uint32_t)copy[size - 1] << 24;
        if (stored != nf_fuzz_crc32(copy, size - NF_FUZZ_TRAILER)) {
            nf_fuzz_fix_crc(copy, size);
            try_buffer(copy, size);
        }
    }
    free(copy);
    return 0;
}
