/*
 * square.c - the public map between directions and the unit square (SPEC section 1), over
 * the one definition in sphere.h.
 */
#include "sphere.h"

void nf_direction_to_square(const float dir[3], float s[2])
{
    nf_to_square(dir, s);
}

void nf_square_to_direction(const float s[2], float dir[3])
{
    nf_from_square(s, dir);
}
