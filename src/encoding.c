/*
 * encoding.c - the public encodings (nf_encode_oneblob, nf_encode_sh) over the kernels' inline
 * versions (encoding.h), so the API and the conditioners compute identical values.
 */
#include <math.h>
#include <string.h>

#include "internal.h"
#include "blocks.h"
#include "kernels/encoding.h"

void nf_encode_oneblob(float v, uint32_t bins, float *out)
{
    if (!out || bins == 0)
        return;
    float vb = nf_clampf(v, 0.0f, 1.0f) * (float)bins;
    for (uint32_t j = 0; j < bins; ++j)
        out[j] = nf_quartic_cdf((float)(j + 1) - vb) - nf_quartic_cdf((float)j - vb);
}

void nf_encode_sh(const float dir[3], uint32_t bands, float *out)
{
    if (!out || bands == 0 || !dir)
        return;
    if (bands > NF_MAX_SH_BANDS)
        bands = NF_MAX_SH_BANDS;
    if (!nf_all_finite(dir, 3) || (dir[0] == 0.0f && dir[1] == 0.0f && dir[2] == 0.0f)) {
        memset(out, 0, sizeof(float) * bands * bands);
        return;
    }
    float unit[3];
    nf_normalize3(dir, unit);
    nf_sh_unit(unit, bands, out);
}
