/*
 * sphere.c - the public map between directions and the unit square (docs/theory.md section 1), over
 * the one definition in sphere.h.
 */
#include "blocks.h"
#include "kernels/sphere.h"

void nf_direction_to_square(const float dir[3], float s[2]) { nf_to_square(dir, s); }

void nf_square_to_direction(const float s_in[2], float dir[3])
{
    /* s is clamped to [0,1]^2 (NaN to 0), as u is in nf_sample. Unclamped, a large s reached
     * the float-to-int conversion of the fast sin/cos's range reduction (undefined behaviour,
     * found by UBSan in tests/robustness/test_numeric_robustness.c), and s0 outside [0,1] gave a
     * zero vector (sin theta < 0 is clamped in nf_from_square). The kernels only pass s inside. */
    float s[2] = {nf_clampf(s_in[0], 0.0f, 1.0f), nf_clampf(s_in[1], 0.0f, 1.0f)};
    nf_from_square(s, dir);
}
