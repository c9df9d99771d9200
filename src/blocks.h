/*
 * blocks.h - the building blocks of the flow as functions of their own: the
 * rational-quadratic spline, the input encodings and the map between directions and the unit
 * square. Internal (not installed): the kernels inline their own copies; the tests and
 * fuzz_blocks check these against docs/theory.md. All are pure functions: thread-safe, no
 * allocation.
 */
#ifndef NISFLOW_SRC_BLOCKS_H
#define NISFLOW_SRC_BLOCKS_H

#include <stdint.h>

#include "nisflow/status.h"

/* The monotone rational-quadratic spline of docs/theory.md section 3 on [0,1] with `bins` bins
 * (2..NF_MAX_SPLINE_BINS). `raw` holds 3*bins+1 raw parameters: bins raw widths, bins raw
 * heights, bins+1 raw derivatives. All raw zeros give the identity. x is clamped to [0,1];
 * *y receives the spline's value in [0,1] and *dydx (if not NULL) its derivative, > 0.
 * NF_ERROR_INVALID_ARGUMENT for NULL pointers, bad `bins`, or non-finite inputs. */
nf_status nf_spline_forward(uint32_t bins, const float *raw, float x, float *y, float *dydx);

/* The inverse of nf_spline_forward: *x such that forward(*x) = y (y clamped to [0,1]), and
 * *dydx (if not NULL) the forward derivative dy/dx at *x (so dx/dy = 1 / *dydx). */
nf_status nf_spline_inverse(uint32_t bins, const float *raw, float y, float *x, float *dydx);

/* One-blob encoding of v in [0,1] (clamped) into `bins` floats (docs/theory.md section 5): bin j
 * gets Q((j+1)/B - v) - Q(j/B - v) with Q the CDF of a quartic kernel of radius 1/B. At most three
 * entries are non-zero and they sum to 1 inside the domain. bins 0 or out NULL: no-op. */
void nf_encode_oneblob(float v, uint32_t bins, float *out);

/* Real orthonormal spherical harmonics of the direction `dir` (normalized internally), bands
 * 0..bands-1 ordered by l then m = -l..l, into bands*bands floats; Y_00 = 0.28209479. bands
 * up to NF_MAX_SH_BANDS. A zero or non-finite dir yields zeros. bands 0 or out NULL: no-op. */
void nf_encode_sh(const float dir[3], uint32_t bands, float *out);

/* s = (theta/pi, phi/(2 pi)) of a direction (any positive length): theta = atan2(hypot(x,y),
 * z) in [0, pi], phi = atan2(y, x) wrapped to [0, 2 pi); s1 is kept below 1. */
void nf_direction_to_square(const float dir[3], float s[2]);

/* The unit vector (sin theta cos phi, sin theta sin phi, cos theta) with theta = pi s0,
 * phi = 2 pi s1. s is clamped to [0,1]^2 (NaN to 0). */
void nf_square_to_direction(const float s[2], float dir[3]);

#endif /* NISFLOW_SRC_BLOCKS_H */
