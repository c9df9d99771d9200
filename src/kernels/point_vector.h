/*
 * point_vector.h - the shading-point API's per-direction path in the AVX2 and AVX-512 kernels,
 * designed for one direction: its vectors run across hidden units, bins and knots, not across
 * samples.
 *
 * The tile and the same-bits point path (point.h) sum in sample order: a 16-unit output layer
 * is a chain of 16 dependent multiply-adds, the knots are two running sums of K steps, and
 * softplus and the bin search run bin by bin. One direction leaves most of a core idle on
 * those chains. Here the output layer keeps partial sums, the knots come from a prefix scan
 * of the exps in registers, the knot derivatives from one vector softplus, the bin search
 * from one comparison mask, and each bin's slope and inverse width from one vector before the
 * search; the inverse's root is solved in float. The results are not the tile's bits: they
 * differ by rounding, within the bound that tests/correctness/test_point.c states and checks
 * against nf_sample / nf_pdf (docs/architecture.md, "Which rule holds where"). The walks' ends
 * take the sphere maps' angles in one vector (fastmath.h's polynomials, four lanes at a time)
 * and, for the cosine prior on surfaces, the draw's prior density from the drawn direction;
 * other priors and media end as point.h's walks do.
 *
 * A coupling layer's registers are the instruction set's own: point_vector_avx512.h holds a
 * direction's hidden units, knots and bins in one 16-lane register each,
 * point_vector_avx2.h in 8-lane ones. This file walks the layers they build and maps the ends.
 *
 * It serves the two presets (16 hidden units, K = 8 or 16 spline bins, the context sums cached
 * in the point): kernel.c compiles it for their shapes, as constants (in the AVX-512 kernels for
 * the large preset only: the small one's points run the AVX2 kernels' copy).
 */
#ifndef NISFLOW_KERNELS_POINT_VECTOR_H
#define NISFLOW_KERNELS_POINT_VECTOR_H

#if defined(__AVX512F__)
#include "point_vector_avx512.h"
#define NF_PV_AVAILABLE 1
#elif defined(__AVX2__) && defined(__FMA__)
#include "point_vector_avx2.h"
#define NF_PV_AVAILABLE 1
#endif

#if defined(NF_PV_AVAILABLE)

/* Sines (lanes 0-3) and cosines (lanes 4-7) of four angles t given in turns, |t| <= 1:
 * nf_fast_sincos_turns's exact reduction to the nearest quarter turn and its Taylor series, to
 * r^11 and r^10 on |r| <= pi/4, for four angles in one polynomial whose coefficients differ
 * between the halves. The reduced angle is scaled to radians in float, not double, and the
 * polynomial fuses its multiply-adds: within a few ulps of the scalar function. */
static NF_ALWAYS_INLINE __m256 nf_pv_sincos_turns(__m128 t)
{
    __m128 q = _mm_round_ps(_mm_mul_ps(t, _mm_set1_ps(4.0f)),
                            _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m128 r4 = _mm_mul_ps(_mm_fnmadd_ps(q, _mm_set1_ps(0.25f), t), _mm_set1_ps(NF_TWO_PI));
    __m256 r = _mm256_set_m128(r4, r4);
    __m256 r2 = _mm256_mul_ps(r, r);
#define NF_PV_HALVES(s, c) _mm256_setr_ps(s, s, s, s, c, c, c, c)
    __m256 p = NF_PV_HALVES(-2.5052108385e-8f, -2.7557319224e-7f);
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(2.7557319224e-6f, 2.4801587302e-5f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(-1.9841269841e-4f, -1.3888888889e-3f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(8.3333333333e-3f, 4.1666666667e-2f));
    p = _mm256_fmadd_ps(p, r2, NF_PV_HALVES(-1.6666666667e-1f, -0.5f));
#undef NF_PV_HALVES
    /* sin r = r (1 + r^2 p), cos r = 1 + r^2 p */
    __m256 base = _mm256_blend_ps(r, _mm256_set1_ps(1.0f), 0xf0);
    __m256 f = _mm256_fmadd_ps(_mm256_mul_ps(base, r2), p, base);
    /* quadrant: odd ones swap sine and cosine; the sine is negated in quadrants 2 and 3, the
     * cosine in 1 and 2 */
    __m128i quad = _mm_and_si128(_mm_cvtps_epi32(q), _mm_set1_epi32(3));
    __m256i qq = _mm256_set_m128i(_mm_add_epi32(quad, _mm_set1_epi32(1)), quad);
    __m256i odd = _mm256_set_m128i(quad, quad);
    odd = _mm256_slli_epi32(odd, 31);
    f = _mm256_blendv_ps(f, _mm256_permute2f128_ps(f, f, 0x01), _mm256_castsi256_ps(odd));
    __m256i sign = _mm256_slli_epi32(_mm256_and_si256(qq, _mm256_set1_epi32(2)), 30);
    return _mm256_xor_ps(f, _mm256_castsi256_ps(sign));
}

/* atan2(y, x) in (-pi, pi] of four pairs, atan2(0, 0) = 0: nf_fast_atan2's reduction and
 * polynomial, with its two divisions (lo / hi, then (a - 1) / (a + 1) above tan(pi/8)) as
 * one, (lo - hi) / (lo + hi) there. */
static NF_ALWAYS_INLINE __m128 nf_pv_atan2(__m128 y, __m128 x)
{
    const __m128 sign = _mm_set1_ps(-0.0f);
    __m128 ax = _mm_andnot_ps(sign, x), ay = _mm_andnot_ps(sign, y);
    __m128 hi = _mm_max_ps(ax, ay), lo = _mm_min_ps(ax, ay);
    __m128 big = _mm_cmpgt_ps(lo, _mm_mul_ps(hi, _mm_set1_ps(0.4142135623730950f)));
    __m128 num = _mm_blendv_ps(lo, _mm_sub_ps(lo, hi), big);
    __m128 den = _mm_blendv_ps(hi, _mm_add_ps(lo, hi), big);
    __m128 a = _mm_and_ps(_mm_div_ps(num, den), _mm_cmpgt_ps(hi, _mm_setzero_ps())); /* 0 / 0 */
    __m128 z = _mm_mul_ps(a, a);
    __m128 p = _mm_fmadd_ps(_mm_set1_ps(8.05374449538e-2f), z, _mm_set1_ps(-1.38776856032e-1f));
    p = _mm_fmadd_ps(p, z, _mm_set1_ps(1.99777106478e-1f));
    p = _mm_fmadd_ps(p, z, _mm_set1_ps(-3.33329491539e-1f));
    __m128 r = _mm_fmadd_ps(_mm_mul_ps(p, z), a, a);
    r = _mm_add_ps(r, _mm_and_ps(big, _mm_set1_ps(0.78539816339744831f)));
    r = _mm_blendv_ps(r, _mm_sub_ps(_mm_set1_ps(1.57079632679489662f), r), _mm_cmpgt_ps(ay, ax));
    r = _mm_blendv_ps(r, _mm_sub_ps(_mm_set1_ps(3.14159265358979324f), r),
                      _mm_cmplt_ps(x, _mm_setzero_ps()));
    return _mm_xor_ps(r, _mm_and_ps(sign, _mm_cmplt_ps(y, _mm_setzero_ps())));
}

/* nf_to_square's point of a direction of any positive length, both angles in one vector. The
 * angles are invariant under exact scaling, so a direction whose largest component lies in
 * [2^-60, 2^60] (every one a renderer asks about) skips nf_square_scaled's power of two. */
static NF_ALWAYS_INLINE void nf_pv_to_square(const float dir_in[3], float s[2])
{
    float d[3] = {dir_in[0], dir_in[1], dir_in[2]};
    const float big = nf_maxf(nf_maxf(fabsf(d[0]), fabsf(d[1])), fabsf(d[2]));
    if (__builtin_expect(!(big >= 0x1p-60f && big <= 0x1p60f), 0))
        nf_square_scaled(dir_in, d);
    float rho = sqrtf(d[0] * d[0] + d[1] * d[1]);
    __m128 a = nf_pv_atan2(_mm_setr_ps(rho, d[1], 0.0f, 0.0f), _mm_setr_ps(d[2], d[0], 1.0f, 1.0f));
    float theta = _mm_cvtss_f32(a), phi = _mm_cvtss_f32(_mm_movehdup_ps(a));
    phi = phi < 0.0f ? phi + NF_TWO_PI : phi;
    s[0] = nf_clampf(theta * (1.0f / NF_PI), 0.0f, 1.0f);
    s[1] = nf_clampf(phi * (1.0f / NF_TWO_PI), 0.0f, 0x1.fffffep-1f);
}

/* y and dy/dx at x in the bin: nf_spline_bin_eval's formula, with the bin's slope and inverse
 * width given (a multiply where it divides) and its multiply-adds fused. */
static NF_ALWAYS_INLINE float nf_pv_bin_eval(const nf_pv_bin *b, float x, float *dydx)
{
    float xi = nf_clampf((x - b->xk) * b->iw, 0.0f, 1.0f);
    float sk = b->sk, om = 1.0f - xi, e = xi * om, xi2 = xi * xi;
    /* fused, and y from one division instead of a reciprocal and a product: the chain from x
     * to y is the layer's last stretch before the next layer can start */
    float den = __builtin_fmaf(b->d1 + b->d0 - 2.0f * sk, e, sk);
    float num = __builtin_fmaf(b->d0, e, sk * xi2);
    float p = __builtin_fmaf(b->d1, xi2, __builtin_fmaf(2.0f * sk, e, b->d0 * (om * om)));
    float slope = sk / den;
    *dydx = slope * slope * p;
    float y = __builtin_fmaf(b->hk, num / den, b->yk);
    return xi >= 1.0f ? b->y1 : nf_clampf(y, 0.0f, 1.0f);
}

/* x in the bin with forward(x) = y: nf_spline_bin_solve's root 2c / (-b - sqrt(disc)), which
 * has no cancellation, in float, its multiply-adds fused. Without its double coefficients the root
 * may lose monotonicity in y by rounding where s_k and d_k nearly cancel; a density only needs it
 * close, which the bound of the tests covers. */
static NF_ALWAYS_INLINE float nf_pv_bin_solve(const nf_pv_bin *b, float y)
{
    float hk = b->hk, d0 = b->d0, sk = b->sk;
    float t = y - b->yk, sum = b->d1 + d0 - 2.0f * sk;
    float qa = __builtin_fmaf(t, sum, hk * (sk - d0));
    float qb = __builtin_fmaf(-t, sum, hk * d0);
    float qc = -sk * t;
    float disc = __builtin_fmaf(qb, qb, qa * (-4.0f * qc));
    float denom = -qb - sqrtf(disc > 0.0f ? disc : 0.0f);
    float xi = denom != 0.0f ? 2.0f * qc / denom : 0.0f;
    /* one clamp, into the bin, where nf_spline_bin_solve clamps xi and then x: a root outside
     * [0, 1] (rounding) lands on the bin's end either way */
    return y >= b->y1 ? b->x1 : nf_minf(nf_maxf(b->xk + xi * b->wk, b->xk), b->x1);
}

/* Step j's map with the layer's spline in s (nf_point_walk_map's, on the vector knots). Both
 * directions multiply w->det by the slope: an inverse walk's det is the forward |det J|, which
 * nf_pv_walk_density divides by once. */
static NF_ALWAYS_INLINE void nf_pv_map(nf_point_shape sh, int inverse, uint32_t j, nf_point_walk *w,
                                       const nf_pv_spline *s)
{
    uint32_t i = nf_point_walk_layer(sh, inverse, j), t = nf_transformed(i);
    const int turns = nf_shape_turns(sh, i);
    nf_pv_bin bin;
    float slope;
    if (!inverse) {
        nf_pv_bin_at(s, nf_pv_find(s->x, sh.bins, w->x[t]), &bin);
        w->x[t] = nf_pv_bin_eval(&bin, w->x[t], &slope);
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] + nf_rotation(s->rotation, sh.bins));
        w->det *= slope;
    } else {
        if (turns)
            w->x[t] = nf_wrap_unit(w->x[t] - nf_rotation(s->rotation, sh.bins));
        nf_pv_bin_at(s, nf_pv_find(s->y, sh.bins, w->x[t]), &bin);
        float solved = nf_pv_bin_solve(&bin, w->x[t]);
        nf_pv_bin_eval(&bin, solved, &slope);
        w->x[t] = solved;
        w->det *= slope; /* the forward |det J| here: one division at the end, not per layer */
    }
}

/* `count` (1 or 2) walks at the point, each coupling layer of them in step. */
static NF_ALWAYS_INLINE void nf_pv_walks(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, uint32_t count,
                                         const int *inverse, nf_point_walk *w)
{
    for (uint32_t j = 0; j < sh.layers; ++j) {
        nf_pv_spline s[NF_PV_PAIR];
        for (uint32_t d = 0; d < count; ++d) {
            uint32_t layer = nf_point_walk_layer(sh, inverse[d], j);
            nf_pv_layer(m, sh, p, layer, w[d].x[1u - nf_transformed(layer)], &s[d]);
        }
        for (uint32_t d = 0; d < count; ++d)
            nf_pv_map(sh, inverse[d], j, &w[d], &s[d]);
    }
}

/* The walks' ends, as point.h's (nf_point_walk_sample, _pdf, _sampled, _density) with the
 * trigonometry of each end in one vector: the sphere maps' two angles together, and at a
 * density's end sin(theta) of the direction asked about beside them. For the cosine prior on
 * surfaces, a draw's prior density comes from the drawn direction itself, where point.h maps
 * the square's point back to a direction first. Other priors, the cosine's uniform share and
 * media take point.h's ends (a density's start aside): with the phase function's draw and
 * density on these ends, the lobe at g = 0.99 turned the vector maps' last-bit differences into
 * 0.26-0.35 % of a draw's density against nf_sample's (tried), beyond the bound. */
static NF_ALWAYS_INLINE nf_status nf_pv_walk_sample(const nf_model *m, const nf_shading_point *p,
                                                    const float u[2], nf_point_walk *w)
{
    const float eps = m->cfg.prior_epsilon, u0 = nf_clamp_unit(u[0]);
    if (m->cfg.prior != NF_PRIOR_COSINE || nf_context_in_medium(&p->context_) || !(u0 < 1.0f - eps))
        return nf_point_walk_sample(m, p, &p->context_, u, w);
    /* nf_cosine_direction around the point's unit normal, its azimuth's sincos in a vector */
    float d[3];
    __m256 sc = nf_pv_sincos_turns(_mm_set1_ps(nf_clamp_unit(u[1])));
    const float lz =
        nf_cosine_direction_at(p->frame_, nf_clamp_unit(u0 / (1.0f - eps)), _mm256_cvtss_f32(sc),
                               _mm_cvtss_f32(_mm256_extractf128_ps(sc, 1)), d);
    nf_pv_to_square(d, w->x);
    /* q_s = sin(theta) lobe(n.w), with n.w = lz and |d| = 1 up to rounding */
    const float sin_theta = nf_maxf(sqrtf(d[0] * d[0] + d[1] * d[1]), NF_SIN_THETA_MIN);
    w->p = p;
    w->user = &p->context_;
    w->q = sin_theta * nf_cosine_lobe(lz, eps);
    w->det = 1.0;
    return NF_OK;
}

static NF_ALWAYS_INLINE void nf_pv_walk_pdf(const nf_shading_point *p, const float dir[3],
                                            nf_point_walk *w)
{
    nf_pv_to_square(dir, w->x);
    w->p = p;
    w->user = &p->context_;
    w->s0 = w->x[0];
    w->det = 1.0;
}

static NF_ALWAYS_INLINE void nf_pv_walk_sampled(nf_point_walk *w, float dir[3], float *pdf)
{
    w->x[1] = nf_minf(w->x[1], 0x1.fffffep-1f); /* as nf_point_walk_sampled */
    float v[8];
    _mm256_storeu_ps(v, nf_pv_sincos_turns(_mm_setr_ps(0.5f * w->x[0], w->x[1], 0.0f, 0.0f)));
    const float sin_theta = nf_maxf(v[0], 0.0f);
    dir[0] = sin_theta * v[5];
    dir[1] = sin_theta * v[1];
    dir[2] = v[4];
    if (pdf)
        *pdf = nf_solid_angle_pdf_at((double)w->q / w->det, sin_theta);
}

static NF_ALWAYS_INLINE nf_status nf_pv_walk_density(const nf_model *m, const nf_point_walk *w,
                                                     float *pdf)
{
    const nf_prior_kind kind = m->cfg.prior;
    if ((kind != NF_PRIOR_COSINE && kind != NF_PRIOR_UNIFORM_DIRECTION) ||
        nf_context_in_medium(&w->p->context_)) {
        nf_point_walk inverted = *w; /* point.h's walks keep 1 / |det J| */
        inverted.det = 1.0 / w->det;
        return nf_point_walk_density(m, &inverted, pdf);
    }
    /* sin and cos of theta and phi at the latent point, and sin(theta) of the direction */
    float v[8];
    _mm256_storeu_ps(v,
                     nf_pv_sincos_turns(_mm_setr_ps(0.5f * w->x[0], w->x[1], 0.5f * w->s0, 0.0f)));
    const float sin_raw = nf_maxf(v[0], 0.0f);
    const float sin_theta = nf_maxf(sin_raw, NF_SIN_THETA_MIN);
    float q = NF_HALF_PI * sin_theta;
    if (kind == NF_PRIOR_COSINE) {
        const float *n = w->p->frame_;
        const float c = n[0] * (sin_raw * v[5]) + n[1] * (sin_raw * v[1]) + n[2] * v[4];
        q = sin_theta * nf_cosine_lobe(c, m->cfg.prior_epsilon);
    }
    *pdf = nf_solid_angle_pdf_at((double)q / w->det, nf_maxf(v[2], 0.0f));
    return NF_OK;
}

/* nf_point_prepare_at with the position's one-blob slots from nf_pv_oneblob, three axes in
 * three vectors where the tile's polynomial runs twelve times in scalar code: the point's
 * context sums then differ from the tile's by rounding, within the path's bound. */
static NF_ALWAYS_INLINE void nf_pv_prepare(const nf_model *m, nf_point_shape sh,
                                           const nf_context *ctx, const nf_prior_callbacks *prior,
                                           nf_shading_point *p)
{
    nf_point feat;
    nf_context_direction_features(m, ctx, &feat);
    for (uint32_t a = 0; a < 3; ++a) {
        float v[4];
        _mm_storeu_ps(v, nf_pv_oneblob(nf_position_unit(&m->cfg, ctx, a), sh.blob_bins, 0,
                                       feat.rows + 3 * a));
        for (uint32_t c = 0; c < 3; ++c) {
            feat.rows[3 * a + c] += (a + 1) * sh.blob_bins;
            feat.values[3 * a + c] = v[c];
        }
    }
    nf_point_prepare_from(m, ctx, prior, &feat, p);
}

static inline nf_status nf_pv_sample_one(const nf_model *m, nf_point_shape sh,
                                         const nf_shading_point *p, const float u[2], float dir[3],
                                         float *pdf)
{
    static const int forward[1] = {0};
    nf_point_walk w;
    nf_status st = nf_pv_walk_sample(m, p, u, &w);
    if (st != NF_OK)
        return st;
    nf_pv_walks(m, sh, p, 1, forward, &w);
    nf_pv_walk_sampled(&w, dir, pdf);
    return NF_OK;
}

static inline nf_status nf_pv_pdf_one(const nf_model *m, nf_point_shape sh,
                                      const nf_shading_point *p, const float dir[3], float *pdf)
{
    static const int inverse[1] = {1};
    nf_point_walk w;
    nf_pv_walk_pdf(p, dir, &w);
    nf_pv_walks(m, sh, p, 1, inverse, &w);
    return nf_pv_walk_density(m, &w, pdf);
}

static inline nf_status nf_pv_pdf_pair(const nf_model *m, nf_point_shape sh,
                                       const nf_shading_point *p, const float dir[6], float pdf[2])
{
    static const int inverse[2] = {1, 1};
    nf_point_walk w[2];
    nf_pv_walk_pdf(p, dir, &w[0]);
    nf_pv_walk_pdf(p, dir + 3, &w[1]);
    nf_pv_walks(m, sh, p, 2, inverse, w);
    nf_status st = nf_pv_walk_density(m, &w[0], &pdf[0]);
    return st != NF_OK ? st : nf_pv_walk_density(m, &w[1], &pdf[1]);
}

/* A draw and another direction's density; a custom prior's failure writes nothing. */
static inline nf_status nf_pv_sample_and_pdf(const nf_model *m, nf_point_shape sh,
                                             const nf_shading_point *p, const float u[2],
                                             float dir[3], float *pdf, const float eval_dir[3],
                                             float *eval_pdf)
{
    static const int inverse[2] = {0, 1};
    nf_point_walk w[2];
    nf_status st = nf_pv_walk_sample(m, p, u, &w[0]);
    if (st != NF_OK)
        return st;
    nf_pv_walk_pdf(p, eval_dir, &w[1]);
    nf_pv_walks(m, sh, p, 2, inverse, w);
    float q;
    if ((st = nf_pv_walk_density(m, &w[1], &q)) != NF_OK)
        return st;
    nf_pv_walk_sampled(&w[0], dir, pdf);
    *eval_pdf = q;
    return NF_OK;
}

#endif /* NF_PV_AVAILABLE */
#endif /* NISFLOW_KERNELS_POINT_VECTOR_H */
