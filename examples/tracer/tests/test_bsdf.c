/*
 * test_bsdf.c - every material with a non-delta lobe is checked against its own density:
 *
 *   - chi-square goodness of fit: sample N directions, histogram them on a grid of equal
 *     solid angle (cos theta x phi), and compare with the expected counts from integrating
 *     bsdf_pdf over each cell; failed and delta samples form one more cell, whose expected
 *     count is the mass missing from the density;
 *   - the sample's weight and pdf equal bsdf_eval / bsdf_pdf at the sampled direction;
 *   - the same chi-square test for the flow's BSDF prior (bsdf_lobe_sample / _pdf), which
 *     must never fail and integrate to one;
 *   - the rough dielectric, nearly smooth, is the smooth one: its Fresnel split and the
 *     radiance a refraction carries.
 *
 * A deliberately wrong density must be rejected (the negative control shows that the test
 * has the power to fail).
 */
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "nf_test_main.h"

#include "bsdf.h"
#include "rng.h"

#ifdef TRACER_SANITIZED
#define SAMPLES 200000 /* instrumented code is ~10x slower; the test keeps its power */
#else
#define SAMPLES 1000000
#endif

#define NZ 20  /* bins in cos(theta), edges at -1, -0.9, ..., 0, ..., 1: one edge at the horizon */
#define NP 40  /* bins in phi */
#define SUB 10 /* midpoint rule on SUB x SUB points per cell for the expected counts */
#define CONFIGS 16 /* chi-square tests in this file, for the Sidak correction */
#define PI_D 3.14159265358979323846

/* ---- Regularized upper incomplete gamma Q(a, x) (p-value of a chi-square statistic) ---- */

static double gamma_q(double a, double x)
{
    if (x <= 0.0)
        return 1.0;
    double gln = lgamma(a);
    if (x < a + 1.0) { /* series for P, then Q = 1 - P */
        double sum = 1.0 / a, term = sum, ap = a;
        for (int n = 0; n < 1000; ++n) {
            ap += 1.0;
            term *= x / ap;
            sum += term;
            if (fabs(term) < fabs(sum) * 1e-15)
                break;
        }
        return 1.0 - sum * exp(-x + a * log(x) - gln);
    }
    /* Continued fraction for Q (modified Lentz). */
    double b = x + 1.0 - a, c = 1.0 / 1e-300, d = 1.0 / b, h = d;
    for (int i = 1; i < 1000; ++i) {
        double an = -i * (i - a);
        b += 2.0;
        d = an * d + b;
        if (fabs(d) < 1e-300)
            d = 1e-300;
        c = b + an / c;
        if (fabs(c) < 1e-300)
            c = 1e-300;
        d = 1.0 / d;
        double del = d * c;
        h *= del;
        if (fabs(del - 1.0) < 1e-15)
            break;
    }
    return exp(-x + a * log(x) - gln) * h;
}

/* ---- The test harness ------------------------------------------------------------------ */

typedef int (*sample_fn)(const bsdf_point *bp, vec3 wo, rng *r, vec3 *wi); /* 0: failed */
typedef double (*pdf_fn)(const bsdf_point *bp, vec3 wo, vec3 wi);

static int sample_bsdf(const bsdf_point *bp, vec3 wo, rng *r, vec3 *wi)
{
    bsdf_sample s;
    float ul = rng_next(r), u0 = rng_next(r), u1 = rng_next(r);
    if (!bsdf_sample_dir(bp, wo, ul, u0, u1, &s) || s.delta)
        return 0;
    *wi = s.wi;
    return 1;
}
static double pdf_bsdf(const bsdf_point *bp, vec3 wo, vec3 wi) { return bsdf_pdf(bp, wo, wi); }

static int sample_lobe(const bsdf_point *bp, vec3 wo, rng *r, vec3 *wi)
{
    float pdf, u0 = rng_next(r), u1 = rng_next(r);
    *wi = bsdf_lobe_sample(bp, wo, u0, u1, &pdf);
    return 1;
}
static double pdf_lobe(const bsdf_point *bp, vec3 wo, vec3 wi) { return bsdf_lobe_pdf(bp, wo, wi); }

/* The negative control: the true sampler judged against a density 10% too wide. */
static double pdf_wrong(const bsdf_point *bp, vec3 wo, vec3 wi)
{
    bsdf b = *bp->b;
    b.alpha *= 1.1f;
    bsdf_point q = *bp;
    q.b = &b;
    return bsdf_pdf(&q, wo, wi);
}

static int cell_of(vec3 w)
{
    int iz = (int)((w.z + 1.0f) * 0.5f * NZ);
    float phi = atan2f(w.y, w.x);
    if (phi < 0.0f)
        phi += 2.0f * PI_F;
    int ip = (int)(phi / (2.0f * PI_F) * NP);
    iz = iz < 0 ? 0 : (iz >= NZ ? NZ - 1 : iz);
    ip = ip < 0 ? 0 : (ip >= NP ? NP - 1 : ip);
    return iz * NP + ip;
}

/* Returns the p-value of the fit; prints the table of the worst cells on failure. */
static double chi_square(const char *name, const bsdf_point *bp, float theta_o_deg, sample_fn sample,
                         pdf_fn pdf, uint64_t seed)
{
    static double observed[NZ * NP + 1], expected[NZ * NP + 1];
    float t = theta_o_deg * PI_F / 180.0f;
    vec3 wo = v3(sinf(t), 0.0f, cosf(t));
    memset(observed, 0, sizeof observed);
    rng r = rng_seed(seed, RNG_TEST, 0, 0);
    for (int i = 0; i < SAMPLES; ++i) {
        vec3 wi;
        if (sample(bp, wo, &r, &wi))
            observed[cell_of(wi)] += 1.0;
        else
            observed[NZ * NP] += 1.0; /* failed or delta */
    }
    double total = 0.0;
    for (int iz = 0; iz < NZ; ++iz)
        for (int ip = 0; ip < NP; ++ip) {
            double sum = 0.0;
            for (int a = 0; a < SUB; ++a)
                for (int b = 0; b < SUB; ++b) {
                    double z = -1.0 + (iz + (a + 0.5) / SUB) * 2.0 / NZ;
                    double phi = (ip + (b + 0.5) / SUB) * 2.0 * PI_D / NP;
                    double s = sqrt(fmax(0.0, 1.0 - z * z));
                    sum += pdf(bp, wo, v3((float)(s * cos(phi)), (float)(s * sin(phi)), (float)z));
                }
            /* Cells are equal in solid angle: 4 pi / (NZ NP). */
            expected[iz * NP + ip] = SAMPLES * sum / (SUB * SUB) * 4.0 * PI_D / (NZ * NP);
            total += expected[iz * NP + ip];
        }
    expected[NZ * NP] = SAMPLES - total;
    /* Pool every cell expecting fewer than 5 samples (the chi-square approximation needs
     * that many). */
    double chi2 = 0.0, pool_o = 0.0, pool_e = 0.0;
    int cells = 0;
    for (int c = 0; c <= NZ * NP; ++c) {
        if (expected[c] < 5.0) {
            pool_o += observed[c];
            pool_e += fmax(expected[c], 0.0);
            continue;
        }
        chi2 += (observed[c] - expected[c]) * (observed[c] - expected[c]) / expected[c];
        ++cells;
    }
    if (pool_e >= 5.0) {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        ++cells;
    } else if (pool_o > 20.0) {
        chi2 += 1e9; /* many samples where the density says there are (almost) none */
    }
    double p = gamma_q(0.5 * (cells - 1), 0.5 * chi2);
    printf("  %-44s chi2 %10.1f, %3d cells, p = %.4f\n", name, chi2, cells, p);
    return p;
}

static double alpha_per_test(void)
{
    /* 1% overall, Sidak-corrected over the tests of this file. */
    return 1.0 - pow(1.0 - 0.01, 1.0 / CONFIGS);
}

/* ---- Materials ------------------------------------------------------------------------------ */

typedef struct material {
    texture diffuse, specular;
    bsdf b;
    bsdf_point bp;
} material;

static void make_material(material *m, bsdf_type type, mf_type dist, float alpha)
{
    memset(m, 0, sizeof *m);
    texture_init_constant(&m->diffuse, rgb_make(0.8f, 0.5f, 0.2f));
    texture_init_constant(&m->specular, rgb_gray(1.0f));
    m->b.type = type;
    m->b.diffuse = &m->diffuse;
    m->b.specular = &m->specular;
    m->b.transmission = &m->specular; /* white: the dielectrics' transmittance */
    m->b.distribution = dist;
    m->b.alpha = alpha;
    m->b.eta = rgb_make(0.2f, 0.9f, 1.1f); /* a coloured conductor */
    m->b.k = rgb_make(3.9f, 2.4f, 2.2f);
    m->b.ior = 1.5f;
    bsdf_prepare(&m->b);
    bsdf_point_init(&m->bp, &m->b, 0.5f, 0.5f);
}

/* The fits checked: the BSDFs' own sampling, then the BSDF prior's lobe (bsdf_prior.c). The coating
 * of plastic is a delta lobe: its samples land in the "other" cell with the mass the density
 * of the diffuse base leaves out. Case i draws from seed i + 1. */
static const struct fit_case {
    const char *name;
    bsdf_type type;
    mf_type dist;
    float alpha, theta;
    int lobe; /* the prior's lobe instead of the BSDF's sampling */
} fits[] = {
    {"diffuse, 30 deg", BSDF_DIFFUSE, MF_GGX, 0.0f, 30.0f, 0},
    {"roughconductor GGX 0.3, 30 deg", BSDF_ROUGHCONDUCTOR, MF_GGX, 0.3f, 30.0f, 0},
    {"roughconductor GGX 0.3, 75 deg", BSDF_ROUGHCONDUCTOR, MF_GGX, 0.3f, 75.0f, 0},
    {"roughconductor Beckmann 0.3, 30 deg", BSDF_ROUGHCONDUCTOR, MF_BECKMANN, 0.3f, 30.0f, 0},
    {"roughconductor Beckmann 0.5, 75 deg", BSDF_ROUGHCONDUCTOR, MF_BECKMANN, 0.5f, 75.0f, 0},
    {"roughplastic GGX 0.3, 45 deg", BSDF_ROUGHPLASTIC, MF_GGX, 0.3f, 45.0f, 0},
    {"roughplastic Beckmann 0.5, 70 deg", BSDF_ROUGHPLASTIC, MF_BECKMANN, 0.5f, 70.0f, 0},
    {"plastic (diffuse base), 60 deg", BSDF_PLASTIC, MF_GGX, 0.0f, 60.0f, 0},
    {"roughdielectric GGX 0.3, 30 deg", BSDF_ROUGHDIELECTRIC, MF_GGX, 0.3f, 30.0f, 0},
    {"roughdielectric Beckmann 0.5, 70 deg", BSDF_ROUGHDIELECTRIC, MF_BECKMANN, 0.5f, 70.0f, 0},
    {"roughdielectric GGX 0.2, inside, 140 deg", BSDF_ROUGHDIELECTRIC, MF_GGX, 0.2f, 140.0f, 0},
    {"prior: roughconductor GGX 0.3, 75 deg", BSDF_ROUGHCONDUCTOR, MF_GGX, 0.3f, 75.0f, 1},
    {"prior: roughconductor Beckmann 0.5, 40 deg", BSDF_ROUGHCONDUCTOR, MF_BECKMANN, 0.5f, 40.0f,
     1},
    {"prior: roughplastic GGX 0.3, 60 deg", BSDF_ROUGHPLASTIC, MF_GGX, 0.3f, 60.0f, 1},
    {"prior: diffuse, 20 deg", BSDF_DIFFUSE, MF_GGX, 0.0f, 20.0f, 1},
};

static void test_chi2_fits(void **state)
{
    (void)state;
    int failed = 0;
    for (size_t i = 0; i < sizeof fits / sizeof fits[0]; ++i) {
        const struct fit_case *f = &fits[i];
        material m;
        make_material(&m, f->type, f->dist, f->alpha);
        double p = chi_square(f->name, &m.bp, f->theta, f->lobe ? sample_lobe : sample_bsdf,
                              f->lobe ? pdf_lobe : pdf_bsdf, i + 1);
        if (p < alpha_per_test()) {
            print_error("%s: the samples do not follow the density (p = %g)\n", f->name, p);
            ++failed;
        }
    }
    if (failed)
        fail_msg("%d fits failed", failed);
}

static void test_chi2_detects_a_wrong_density(void **state)
{
    (void)state;
    material m;
    make_material(&m, BSDF_ROUGHCONDUCTOR, MF_GGX, 0.3f);
    double p = chi_square("negative control: alpha 10% off", &m.bp, 30.0f, sample_bsdf, pdf_wrong, 13);
    assert_true(p < alpha_per_test());
}

/* ---- Weights ------------------------------------------------------------------------------- */

static void test_sample_weight_is_f_cos_over_pdf(void **state)
{
    (void)state;
    static const struct { bsdf_type type; mf_type dist; float alpha; } cases[] = {
        {BSDF_DIFFUSE, MF_GGX, 0.0f},          {BSDF_ROUGHCONDUCTOR, MF_GGX, 0.2f},
        {BSDF_ROUGHCONDUCTOR, MF_BECKMANN, 0.2f}, {BSDF_ROUGHPLASTIC, MF_GGX, 0.1f},
        {BSDF_ROUGHPLASTIC, MF_BECKMANN, 0.4f}, {BSDF_PLASTIC, MF_GGX, 0.0f}};
    rng r = rng_seed(99, RNG_TEST, 1, 0);
    for (size_t c = 0; c < sizeof cases / sizeof cases[0]; ++c) {
        material m;
        make_material(&m, cases[c].type, cases[c].dist, cases[c].alpha);
        int checked = 0;
        for (int i = 0; i < 20000; ++i) {
            vec3 wo = sample_cosine_hemisphere(rng_next(&r), rng_next(&r));
            bsdf_sample s;
            if (!bsdf_sample_dir(&m.bp, wo, rng_next(&r), rng_next(&r), rng_next(&r), &s))
                continue;
            if (s.delta) { /* the plastic's coating: F * specular / P(coating) */
                float f = fresnel_dielectric(wo.z, m.b.ior, NULL, NULL);
                assert_float_equal(s.weight.g, f / s.pdf, 1e-5f * s.weight.g);
                continue;
            }
            float pdf = bsdf_pdf(&m.bp, wo, s.wi);
            rgb f = bsdf_eval(&m.bp, wo, s.wi);
            /* Recomputing the density must give the sampler's value to float rounding. */
            assert_float_equal(s.pdf, pdf, 1e-5f * pdf);
            assert_float_equal(s.weight.r, f.r / pdf, 1e-4f * fmaxf(s.weight.r, 1e-6f));
            assert_float_equal(s.weight.g, f.g / pdf, 1e-4f * fmaxf(s.weight.g, 1e-6f));
            assert_float_equal(s.weight.b, f.b / pdf, 1e-4f * fmaxf(s.weight.b, 1e-6f));
            ++checked;
        }
        assert_true(checked > 1000);
    }
}

/* The rough dielectric from both sides: each sample's weight is f |cos| / pdf and its density
 * the one bsdf_pdf recomputes, for reflections and refractions alike. */
static void test_rough_dielectric_weights(void **state)
{
    (void)state;
    rng r = rng_seed(98, RNG_TEST, 1, 0);
    for (int dist = 0; dist < 2; ++dist) {
        material m;
        make_material(&m, BSDF_ROUGHDIELECTRIC, dist ? MF_GGX : MF_BECKMANN, 0.25f);
        int seen[2] = {0, 0};
        for (int i = 0; i < 20000; ++i) {
            vec3 wo = sample_cosine_hemisphere(rng_next(&r), rng_next(&r));
            if (i & 1)
                wo.z = -wo.z; /* inside */
            bsdf_sample s;
            if (!bsdf_sample_dir(&m.bp, wo, rng_next(&r), rng_next(&r), rng_next(&r), &s))
                continue;
            assert_false(s.delta);
            float pdf = bsdf_pdf(&m.bp, wo, s.wi);
            rgb f = bsdf_eval(&m.bp, wo, s.wi);
            /* The same float arithmetic: equal to rounding. */
            assert_float_equal(s.pdf, pdf, 1e-5f * pdf);
            assert_float_equal(s.weight.g, f.g / pdf, 1e-4f * fmaxf(s.weight.g, 1e-6f));
            seen[s.wi.z * wo.z < 0.0f]++;
        }
        assert_true(seen[0] > 1000 && seen[1] > 1000);
    }
}

/* Nearly smooth (alpha 1e-3), the rough dielectric is the smooth one: at 30 degrees from
 * outside and inside, the reflected share is the Fresnel reflectance (within 5 standard
 * errors of 20,000 draws) and a refraction carries (n_wo / n_wi)^2 of the radiance on
 * average (the solid angle's compression: 1 / 1.5^2 entering, 1.5^2 leaving; 0.5 %: a draw's
 * weight moves by tan(30 deg) times its microfacet's tilt, of mean 0, and GGX's long tail
 * tilts a few of them by 1e-2). */
static void test_rough_dielectric_smooth_limit(void **state)
{
    (void)state;
    rng r = rng_seed(97, RNG_TEST, 1, 0);
    material m;
    make_material(&m, BSDF_ROUGHDIELECTRIC, MF_GGX, 1e-3f);
    for (int side = 0; side < 2; ++side) {
        float t = 30.0f * PI_F / 180.0f;
        vec3 wo = v3(sinf(t), 0.0f, side ? -cosf(t) : cosf(t));
        float F = fresnel_dielectric(wo.z, m.b.ior, NULL, NULL);
        float want = side ? m.b.ior * m.b.ior : 1.0f / (m.b.ior * m.b.ior);
        const int n = 20000;
        int reflected = 0, refracted = 0;
        double sum[2] = {0.0, 0.0};
        for (int i = 0; i < n; ++i) {
            bsdf_sample s;
            if (!bsdf_sample_dir(&m.bp, wo, rng_next(&r), rng_next(&r), rng_next(&r), &s))
                continue;
            const int through = s.wi.z * wo.z < 0.0f;
            reflected += !through;
            refracted += through;
            sum[through] += s.weight.g;
        }
        assert_float_equal(sum[0] / reflected, 1.0, 0.005);
        assert_float_equal(sum[1] / refracted, want, 0.005 * want);
        double share = (double)reflected / n, se = sqrt(F * (1.0 - F) / n);
        assert_true(fabs(share - F) < 5.0 * se + 1e-9);
        assert_true(reflected + refracted > n * 99 / 100); /* nearly every draw succeeds */
    }
}

static void test_energy_is_conserved(void **state)
{
    (void)state;
    /* A white diffuse surface reflects everything: E[weight] = 1 exactly; the microfacet
     * materials may lose energy (masking) but never create any. 2e5 samples: the standard
     * error of the mean weight is below 0.005, so the +0.02 margin is 4 standard errors. */
    rng r = rng_seed(5, RNG_TEST, 2, 0);
    static const bsdf_type types[] = {BSDF_DIFFUSE, BSDF_ROUGHCONDUCTOR, BSDF_ROUGHPLASTIC,
                                      BSDF_PLASTIC};
    for (size_t k = 0; k < 4; ++k) {
        material m;
        make_material(&m, types[k], MF_GGX, 0.3f);
        texture_init_constant(&m.diffuse, rgb_gray(1.0f));
        m.b.eta = rgb_gray(0.0f); /* a perfect mirror's Fresnel: F = 1 */
        m.b.k = rgb_gray(1.0f);
        bsdf_prepare(&m.b);
        bsdf_point_init(&m.bp, &m.b, 0.0f, 0.0f);
        for (int a = 0; a < 3; ++a) {
            float t = (15.0f + 30.0f * a) * PI_F / 180.0f;
            vec3 wo = v3(sinf(t), 0.0f, cosf(t));
            double sum = 0.0;
            const int n = 200000;
            for (int i = 0; i < n; ++i) {
                bsdf_sample s;
                if (bsdf_sample_dir(&m.bp, wo, rng_next(&r), rng_next(&r), rng_next(&r), &s))
                    sum += s.weight.g;
            }
            double albedo = sum / n;
            if (types[k] == BSDF_DIFFUSE)
                assert_float_equal(albedo, 1.0, 1e-6);
            assert_true(albedo <= 1.02);
            assert_true(albedo > 0.5);
        }
    }
}

NFT_TEST_MAIN(
    cmocka_unit_test(test_chi2_fits),
    cmocka_unit_test(test_chi2_detects_a_wrong_density),
    cmocka_unit_test(test_rough_dielectric_weights),
    cmocka_unit_test(test_rough_dielectric_smooth_limit),
    cmocka_unit_test(test_sample_weight_is_f_cos_over_pdf),
    cmocka_unit_test(test_energy_is_conserved),
)
