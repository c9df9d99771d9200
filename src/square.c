/*
 * square.c - the map between unit directions and the unit square (SPEC section 1).
 */
#include <math.h>

#include "internal.h"

float nf_sin_pi(float x)
{
    /* sin(pi x) = sin(pi (1 - x)); 1 - x is exact for x in [0.5, 1], so the folded argument
     * keeps full relative precision near both poles. */
    float folded = nf_minf(x, 1.0f - x);
    return sinf(NF_PI * nf_maxf(folded, 0.0f));
}

void nf_direction_to_square(const float dir[3], float s[2])
{
    float theta = atan2f(hypotf(dir[0], dir[1]), dir[2]);
    float phi = atan2f(dir[1], dir[0]);
    if (phi < 0.0f)
        phi += NF_TWO_PI;
    s[0] = nf_clampf(theta / NF_PI, 0.0f, 1.0f);
    /* phi just below 2 pi can round up to 2 pi; keep s1 below 1 so the seam stays on the side
     * it was approached from. */
    s[1] = nf_clampf(phi / NF_TWO_PI, 0.0f, 0x1.fffffep-1f);
}

void nf_square_to_direction(const float s[2], float dir[3])
{
    float sin_theta = nf_sin_pi(s[0]);
    float cos_theta = cosf(NF_PI * s[0]);
    float phi = NF_TWO_PI * s[1];
    dir[0] = sin_theta * cosf(phi);
    dir[1] = sin_theta * sinf(phi);
    dir[2] = cos_theta;
}
