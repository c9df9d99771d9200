/*
 * table.c - a shading point's flow tabulated on a grid of directions (nisflow/table.h): the
 * build asks the flow at the cells' centres; a draw searches two cumulative sums, a density
 * looks one cell up. Scalar code, compiled once.
 */
#include <float.h>

#include "internal.h"
#include "direction_table.h"
#include "point_batch.h"
#include "kernels/fastmath.h"
#include "kernels/kernels.h"
#include "kernels/prior.h"

#if UINTPTR_MAX == UINT64_MAX
_Static_assert(sizeof(nf_direction_table) == 2176 && offsetof(nf_direction_table, rows_) == 128,
               "table.h states the table's size, and its rows start on a cache line");
#endif

/* Where num falls in a cell of width den, in [0, 1]; the middle of an empty cell. */
static float nf_table_within(float num, float den)
{
    return den > 0.0f ? nf_clampf(num / den, 0.0f, 1.0f) : 0.5f;
}

/* The bin that u falls in among n bins whose inner edges are cdf[0..n-2] (the outer ones 0
 * and 1): a count of the edges at or below u, without branches. The compiler turns it into
 * vector compares; a binary search's branches, one mispredicted in two, cost more. */
static uint32_t nf_table_search(const float *cdf, uint32_t n, float u)
{
    uint32_t count = 0;
    for (uint32_t k = 0; k + 1 < n; ++k)
        count += cdf[k] <= u;
    return count;
}

/* The direction at (row coordinate r, azimuth in turns phi) of the table's grid: sin^2 theta =
 * r about the frame's normal on a surface, z = 1 - 2 r about +z in a medium. Returns the
 * cosine about the normal (surface) or 1 (medium), the factor of the density. */
static float nf_table_direction(const nf_direction_table *t, float r, float phi, float d[3])
{
    float s, c, sp, cp;
    if (t->medium_) {
        c = 1.0f - 2.0f * r;
        s = sqrtf(nf_maxf(1.0f - c * c, 0.0f));
    } else {
        s = sqrtf(r);
        c = sqrtf(nf_maxf(1.0f - r, 0.0f));
    }
    nf_fast_sincos_turns(phi, &sp, &cp);
    const float *f = t->frame_;
    for (int a = 0; a < 3; ++a)
        d[a] = s * cp * f[a] + s * sp * f[3 + a] + c * f[6 + a];
    /* |d|^2 is 1 within about 1e-6 (an orthonormal frame, s^2 + c^2 = 1, the sine and cosine
     * within 3e-7): one Newton step of 1 / sqrt about 1 leaves 1e-12, below float rounding,
     * without the square root and division on the draw's path. */
    const float scale = 1.5f - 0.5f * (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int a = 0; a < 3; ++a)
        d[a] *= scale;
    return t->medium_ ? 1.0f : c;
}

/* Column j's share of its row (the row's mass aside: row[0]; its cumulative shares row[1..]). */
static float nf_table_share(const float *row, uint32_t j)
{
    const float lo = j > 0 ? row[j] : 0.0f, hi = j + 1 < NF_TABLE_COLS ? row[j + 1] : 1.0f;
    return hi - lo;
}

/* Density per steradian of cell (i, j) at a direction whose cosine factor is c. */
static float nf_table_density(const nf_direction_table *t, uint32_t i, uint32_t j, float c)
{
    const float *row = t->rows_[i];
    /* at most NF_TABLE_CELLS / pi for masses and shares in [0, 1] */
    const float cell = row[0] * nf_table_share(row, j) * (float)NF_TABLE_CELLS;
    const float p =
        t->medium_ ? cell * (float)(1.0 / (4.0 * NF_PI)) : cell * c * (float)(1.0 / NF_PI);
    return p > FLT_MAX ? FLT_MAX : p < FLT_MIN ? FLT_MIN : p;
}

static nf_status nf_table_usable(const char *fn, const nf_model *m, const nf_direction_table *t)
{
    if (t->magic_ != NF_TABLE_MAGIC)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT,
                       "%s: the table was never built (or overwritten): call nf_table_build", fn);
    if (t->model_id_ != m->id)
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: the table was built on another model", fn);
    if (nf_generation_moved(m, t->generation_))
        return nf_fail(NF_ERROR_STALE,
                       "%s: the model's parameters changed since the table was built (a training "
                       "step, nf_model_set_params or nf_apply_gradient): build it again",
                       fn);
    return NF_OK;
}

nf_status nf_table_build(const nf_model *m, const nf_shading_point *point,
                         nf_direction_table *table)
{
    static const char fn[] = "nf_table_build";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "point", point, "table", table, NULL, NULL)) != NF_OK ||
        (st = nf_point_usable(fn, m, point, SIZE_MAX)) != NF_OK)
        return st;
    /* Built on the stack and copied at the end: a failed build leaves a valid table valid. */
    nf_direction_table t;
    memset(&t, 0, sizeof t);
    t.magic_ = NF_TABLE_MAGIC;
    t.model_id_ = m->id;
    t.generation_ = point->generation_;
    t.medium_ = (uint32_t)nf_context_in_medium(&point->context_);
    if (t.medium_) {
        t.frame_[0] = t.frame_[4] = t.frame_[8] = 1.0f;
    } else {
        nf_frame(point->frame_, t.frame_, t.frame_ + 3);
        for (int a = 0; a < 3; ++a)
            t.frame_[6 + a] = point->frame_[a];
    }
    /* Each cell's weight: the flow's density at its centre, over the cosine lobe's on a
     * surface (whose cells have equal lobe probability), as is in a medium (equal solid
     * angle). Summed in double, rows first, so that every row's columns normalize alone. */
    double row_sum[NF_TABLE_ROWS], total = 0.0;
    for (uint32_t i = 0; i < NF_TABLE_ROWS; ++i) {
        float dirs[3 * NF_TABLE_COLS], pdf[NF_TABLE_COLS], c[NF_TABLE_COLS]; /* a row a call */
        float *row = t.rows_[i];
        for (uint32_t j = 0; j < NF_TABLE_COLS; ++j)
            c[j] = nf_table_direction(&t, ((float)i + 0.5f) / NF_TABLE_ROWS,
                                      ((float)j + 0.5f) / NF_TABLE_COLS, dirs + 3 * j);
        st = m->kernels->point_pdf(m, point, NF_TABLE_COLS, 0, dirs, pdf);
        if ((st = nf_point_checked(fn, m, point->generation_, st)) != NF_OK)
            return st;
        double acc = 0.0, cum[NF_TABLE_COLS];
        for (uint32_t j = 0; j < NF_TABLE_COLS; ++j) {
            acc += (double)pdf[j] / (double)c[j];
            cum[j] = acc;
        }
        if (!(acc > 0.0) || !isfinite(acc))
            return nf_fail(NF_ERROR_NUMERIC, "%s: the flow's densities in row %u sum to %g", fn, i,
                           acc);
        for (uint32_t j = 1; j < NF_TABLE_COLS; ++j)
            row[j] = (float)(cum[j - 1] / acc);
        row_sum[i] = acc;
        total += acc;
    }
    if (!isfinite(total))
        return nf_fail(NF_ERROR_NUMERIC, "%s: the flow's densities sum to %g", fn, total);
    double acc = 0.0;
    for (uint32_t i = 0; i < NF_TABLE_ROWS; ++i) {
        t.rows_[i][0] = (float)(row_sum[i] / total);
        acc += row_sum[i];
        if (i + 1 < NF_TABLE_ROWS)
            t.row_cdf_[i] = (float)(acc / total);
    }
    *table = t;
    return NF_OK;
}

nf_status nf_table_sample(const nf_model *m, const nf_direction_table *table, const float u[2],
                          float dir[3], float *pdf)
{
    static const char fn[] = "nf_table_sample";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "table", table, "u", u, "dir", dir)) != NF_OK ||
        (st = nf_table_usable(fn, m, table)) != NF_OK)
        return st;
    if (!nf_all_finite(u, 2))
        return nf_fail(NF_ERROR_INVALID_ARGUMENT, "%s: u contains NaN or Inf", fn);
    const float u0 = nf_clamp_unit(u[0]), u1 = nf_clamp_unit(u[1]);
    const uint32_t i = nf_table_search(table->row_cdf_, NF_TABLE_ROWS, u0);
    const float *row = table->rows_[i];
    const uint32_t j = nf_table_search(row + 1, NF_TABLE_COLS, u1);
    /* where u falls inside its cell, reused for the point in the cell */
    const float r0 = nf_table_within(u0 - (i > 0 ? table->row_cdf_[i - 1] : 0.0f), row[0]);
    const float r1 = nf_table_within(u1 - (j > 0 ? row[j] : 0.0f), nf_table_share(row, j));
    float d[3];
    const float c = nf_table_direction(table, ((float)i + r0) / NF_TABLE_ROWS,
                                       ((float)j + r1) / NF_TABLE_COLS, d);
    for (int a = 0; a < 3; ++a)
        dir[a] = d[a];
    if (pdf)
        *pdf = nf_table_density(table, i, j, c);
    return NF_OK;
}

nf_status nf_table_pdf(const nf_model *m, const nf_direction_table *table, const float dir[3],
                       float *pdf)
{
    static const char fn[] = "nf_table_pdf";
    nf_status st;
    if ((st = nf_check_pointers(fn, "m", m, "table", table, "dir", dir, "pdf", pdf)) != NF_OK ||
        (st = nf_table_usable(fn, m, table)) != NF_OK ||
        (st = nf_validate_directions(fn, "dir", 1, dir)) != NF_OK)
        return st;
    const float *f = table->frame_;
    float x = 0.0f, y = 0.0f, z = 0.0f;
    for (int a = 0; a < 3; ++a) {
        x += dir[a] * f[a];
        y += dir[a] * f[3 + a];
        z += dir[a] * f[6 + a];
    }
    const float len = sqrtf(x * x + y * y + z * z);
    z /= len;
    if (!table->medium_ && !(z > 0.0f)) {
        *pdf = 0.0f; /* at or below the horizon */
        return NF_OK;
    }
    float phi = nf_fast_atan2(y, x) * (1.0f / NF_TWO_PI);
    phi = phi < 0.0f ? phi + 1.0f : phi;
    const float r = table->medium_ ? 0.5f * (1.0f - z) : 1.0f - z * z;
    const uint32_t i = nf_table_cell(r, NF_TABLE_ROWS), j = nf_table_cell(phi, NF_TABLE_COLS);
    *pdf = nf_table_density(table, i, j, z);
    return NF_OK;
}
