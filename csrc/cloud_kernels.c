/* Hot loops of the measurement after the match; see cloud_kernels.h. */
#include "cloud_kernels.h"

#if defined(__x86_64__) || defined(__i386__)
#define CK_HAVE_X86 1
#include <immintrin.h>
#else
#define CK_HAVE_X86 0
#endif
#include <math.h>
#include <omp.h>
#include <stddef.h>

#define CK_NEAR 36
#define CK_BLOCK 20
#define CK_REACH 3 /* largest |dx|, |dy| of the offsets */

/* Minimum and maximum as single instructions: C's fmin/fmax are library calls without -ffast-math (their
 * NaN rules). Inputs here are never NaN (missing neighbours are infinite). */
static inline float min_f(float a, float b) { return a < b ? a : b; }
static inline float max_f(float a, float b) { return a > b ? a : b; }
static inline double min_d(double a, double b) { return a < b ? a : b; }
static inline double max_d(double a, double b) { return a > b ? a : b; }

/* Threads a call runs on: `threads`, or all OpenMP offers when 0 (as the matcher's cc_thread_count). */
static int thread_count(int threads) { return threads > 0 ? threads : omp_get_max_threads(); }

/* Below this many points or pixels a call stays on one thread: waking the others costs more. */
#define CK_PARALLEL_MIN 4096

/* The slow case of ck_neighbour_means, CK_LANES points at a time: branch-free on the data (min / max per
 * compare-exchange, the same instructions on every lane), where sorting each point's 36 distances alone
 * mispredicts about half its comparisons.
 * The comparators are Batcher's merge exchange for 36 keys (Knuth, TAOCP vol. 3, 5.2.2, Algorithm M, 241
 * comparators in 21 rounds) without those that cannot reach the 19 smallest (220 left): afterwards keys 0-18
 * of each lane are its 19 smallest in ascending order and 19-35 the rest (a permutation, so ties and
 * infinities come out as a sort gives them). Checked against a sort in tests/stereo/test_cloud_kernels.py. */
#define CK_LANES 8
static const uint8_t ck_nearest19[][2] = {
    {0, 32}, {1, 33}, {2, 34}, {3, 35}, {0, 16}, {1, 17}, {2, 18}, {3, 19}, {4, 20}, {5, 21}, {6, 22}, {7, 23},
    {8, 24}, {9, 25}, {10, 26}, {11, 27}, {12, 28}, {13, 29}, {14, 30}, {15, 31}, {16, 32}, {17, 33}, {18, 34},
    {19, 35}, {0, 8}, {1, 9}, {2, 10}, {3, 11}, {4, 12}, {5, 13}, {6, 14}, {7, 15}, {16, 24}, {17, 25},
    {18, 26}, {19, 27}, {20, 28}, {21, 29}, {22, 30}, {23, 31}, {8, 32}, {9, 33}, {10, 34}, {11, 35}, {8, 16},
    {9, 17}, {10, 18}, {11, 19}, {12, 20}, {13, 21}, {14, 22}, {15, 23}, {24, 32}, {25, 33}, {26, 34}, {27, 35},
    {0, 4}, {1, 5}, {2, 6}, {3, 7}, {8, 12}, {9, 13}, {10, 14}, {11, 15}, {16, 20}, {17, 21}, {18, 22},
    {19, 23}, {24, 28}, {25, 29}, {26, 30}, {27, 31}, {4, 32}, {5, 33}, {6, 34}, {7, 35}, {4, 16}, {5, 17},
    {6, 18}, {7, 19}, {12, 24}, {13, 25}, {14, 26}, {15, 27}, {20, 32}, {21, 33}, {22, 34}, {23, 35}, {4, 8},
    {5, 9}, {6, 10}, {7, 11}, {12, 16}, {13, 17}, {14, 18}, {15, 19}, {20, 24}, {21, 25}, {22, 26}, {23, 27},
    {28, 32}, {29, 33}, {30, 34}, {31, 35}, {0, 2}, {1, 3}, {4, 6}, {5, 7}, {8, 10}, {9, 11}, {12, 14},
    {13, 15}, {16, 18}, {17, 19}, {20, 22}, {21, 23}, {24, 26}, {25, 27}, {28, 30}, {29, 31}, {32, 34},
    {33, 35}, {2, 32}, {3, 33}, {2, 16}, {3, 17}, {6, 20}, {7, 21}, {10, 24}, {11, 25}, {14, 28}, {15, 29},
    {18, 32}, {19, 33}, {2, 8}, {3, 9}, {6, 12}, {7, 13}, {10, 16}, {11, 17}, {14, 20}, {15, 21}, {18, 24},
    {19, 25}, {22, 28}, {23, 29}, {26, 32}, {27, 33}, {2, 4}, {3, 5}, {6, 8}, {7, 9}, {10, 12}, {11, 13},
    {14, 16}, {15, 17}, {18, 20}, {19, 21}, {22, 24}, {23, 25}, {26, 28}, {27, 29}, {30, 32}, {31, 33}, {0, 1},
    {2, 3}, {4, 5}, {6, 7}, {8, 9}, {10, 11}, {12, 13}, {14, 15}, {16, 17}, {18, 19}, {20, 21}, {22, 23},
    {24, 25}, {26, 27}, {28, 29}, {30, 31}, {32, 33}, {34, 35}, {1, 32}, {3, 34}, {1, 16}, {3, 18}, {5, 20},
    {7, 22}, {9, 24}, {11, 26}, {13, 28}, {15, 30}, {17, 32}, {1, 8}, {3, 10}, {5, 12}, {7, 14}, {9, 16},
    {11, 18}, {13, 20}, {15, 22}, {17, 24}, {1, 4}, {3, 6}, {5, 8}, {7, 10}, {9, 12}, {11, 14}, {13, 16},
    {15, 18}, {17, 20}, {1, 2}, {3, 4}, {5, 6}, {7, 8}, {9, 10}, {11, 12}, {13, 14}, {15, 16}, {17, 18},
};

typedef struct {
    float near[CK_NEAR][CK_LANES]; /* lane l's distances in column l */
    int64_t point[CK_LANES];
    int count;
} slow_lanes;

/* Sort every lane's 19 smallest to the front, then each point's mean and exactness as the case defines them:
 * the 19 nearest (missing ones infinite, so last) each capped at 3.6 spacings, summed in double in ascending
 * order over 20. Unused lanes hold infinities and are not written. */
static void finish_slow_lanes(slow_lanes *lanes, const double *spacing, float *mean, uint8_t *exact) {
    for (int l = lanes->count; l < CK_LANES; ++l)
        for (int j = 0; j < CK_NEAR; ++j)
            lanes->near[j][l] = INFINITY;
    for (size_t c = 0; c < sizeof ck_nearest19 / sizeof ck_nearest19[0]; ++c) {
        float *restrict a = lanes->near[ck_nearest19[c][0]];
        float *restrict b = lanes->near[ck_nearest19[c][1]];
#pragma omp simd
        for (int l = 0; l < CK_LANES; ++l) {
            const float x = a[l], y = b[l];
            a[l] = min_f(x, y);
            b[l] = max_f(x, y);
        }
    }
    for (int l = 0; l < lanes->count; ++l) {
        const int64_t i = lanes->point[l];
        const double reach = 3.6 * spacing[i];
        double total = 0.0;
        for (int j = 0; j < 19; ++j)
            total += min_d((double)lanes->near[j][l], reach); /* infinite (missing): the cap */
        mean[i] = (float)(total / 20.0);
        /* at least 19 measured (the 19th smallest finite) and all within 0.95 of the cap */
        exact[i] = (uint8_t)((double)lanes->near[18][l] <= 0.95 * reach);
    }
    lanes->count = 0;
}

int ck_neighbour_means(const float *grid, int height, int width, const int64_t *at, int64_t count,
                       const double *spacing, const int32_t *offsets, float *mean, uint8_t *exact, int threads) {
    if (!grid || !at || !spacing || !offsets || !mean || !exact)
        return CK_ERR_NULL;
    if (height <= 2 * CK_REACH || width <= 2 * CK_REACH || count < 0 || threads < 0)
        return CK_ERR_SIZE;
    for (int j = 0; j < CK_NEAR; ++j)
        if (offsets[2 * j] < -CK_REACH || offsets[2 * j] > CK_REACH || offsets[2 * j + 1] < -CK_REACH ||
            offsets[2 * j + 1] > CK_REACH)
            return CK_ERR_RANGE;
    const int64_t plane = (int64_t)height * width;
    /* Every neighbour read stays inside the grid (the caller keeps points 3 px off its sides). */
    const int64_t lowest = (int64_t)CK_REACH * width + CK_REACH;
    for (int64_t i = 0; i < count; ++i)
        if (at[i] < lowest || at[i] >= plane - lowest)
            return CK_ERR_RANGE;
    int64_t shift[CK_NEAR];
    for (int j = 0; j < CK_NEAR; ++j)
        shift[j] = (int64_t)offsets[2 * j + 1] * width + offsets[2 * j];
    /* Each point's mean is computed whole by one thread in a fixed order: identical for any thread count and
     * whichever points share its lanes. Dynamic blocks because the edge points (the slow case) lie together
     * in pixel order. */
    const int64_t block = 1024, blocks = (count + block - 1) / block;
#pragma omp parallel for schedule(dynamic, 1) num_threads(thread_count(threads)) if (count >= CK_PARALLEL_MIN)
    for (int64_t b = 0; b < blocks; ++b) {
        slow_lanes lanes;
        lanes.count = 0;
        const int64_t end = (b + 1) * block < count ? (b + 1) * block : count;
        for (int64_t i = b * block; i < end; ++i) {
            const int64_t c = at[i];
            float near[CK_NEAR];
            for (int j = 0; j < CK_NEAR; ++j) {
                const int64_t o = c + shift[j];
                /* float32 as numpy's einsum: (x*x + y*y) + z*z, then sqrt; NaN (no point) becomes inf */
                float ox = grid[3 * o] - grid[3 * c], oy = grid[3 * o + 1] - grid[3 * c + 1];
                float oz = grid[3 * o + 2] - grid[3 * c + 2];
                near[j] = ox * ox + oy * oy + oz * oz;
            }
            /* The square roots four at a time (sqrtps rounds as sqrtss does); NaN (no point) becomes inf. */
#pragma omp simd
            for (int j = 0; j < CK_NEAR; ++j)
                near[j] = near[j] == near[j] ? sqrtf(near[j]) : INFINITY;
            /* Branch-free: the data decide every comparison, so branches would be mispredicted half the time. */
            float sum = 0.0f, largest = -INFINITY, second = -INFINITY;
            for (int j = 0; j < CK_BLOCK; ++j) {
                sum += near[j];
                second = max_f(second, min_f(largest, near[j]));
                largest = max_f(largest, near[j]);
            }
            float others = INFINITY;
            for (int j = CK_BLOCK; j < CK_NEAR; ++j)
                others = min_f(others, near[j]);
            if (isfinite(largest) && (double)second <= min_d((double)others, 3.5 * spacing[i])) {
                mean[i] = (sum - largest) / 20.0f;
                exact[i] = 1;
                continue;
            }
            /* Else the 19 nearest of the 36, each at most 3.6 spacings (where the next pixels lie), and
             * whether they lie within 0.95 of that (else a wider window must decide): in lanes. */
            for (int j = 0; j < CK_NEAR; ++j)
                lanes.near[j][lanes.count] = near[j];
            lanes.point[lanes.count++] = i;
            if (lanes.count == CK_LANES)
                finish_slow_lanes(&lanes, spacing, mean, exact);
        }
        if (lanes.count)
            finish_slow_lanes(&lanes, spacing, mean, exact);
    }
    return CK_OK;
}

/* Keeps the 19 smallest squared distances seen so far in best[] (ascending): d goes in where it belongs; NaN
 * (no point) never does. */
static inline void keep_nearest(float best[19], float d) {
    if (!(d < best[18]))
        return;
    int k = 18;
    for (; k > 0 && best[k - 1] > d; --k)
        best[k] = best[k - 1];
    best[k] = d;
}

/* The float32 squared distance from the point at pixel c to the one at pixel o (ck_neighbour_means' sum), NaN
 * where o has none. */
static inline float grid_squared(const float *grid, int64_t c, int64_t o) {
    float ox = grid[3 * o] - grid[3 * c], oy = grid[3 * o + 1] - grid[3 * c + 1];
    float oz = grid[3 * o + 2] - grid[3 * c + 2];
    return ox * ox + oy * oy + oz * oz;
}

int ck_window_means(const float *grid, int height, int width, const int64_t *at, int64_t count,
                    const double *spacing, const int32_t *halves, int n_halves, float *mean, uint8_t *settled,
                    int threads) {
    if (!grid || !at || !spacing || !halves || !mean || !settled)
        return CK_ERR_NULL;
    if (height <= 0 || width <= 0 || count < 0 || threads < 0 || n_halves < 1 || n_halves > 16)
        return CK_ERR_SIZE;
    for (int k = 0; k < n_halves; ++k)
        if (halves[k] < 1 || halves[k] > CK_MAX_HALF || (k > 0 && halves[k] <= halves[k - 1]))
            return CK_ERR_SIZE;
    const int64_t reach = halves[n_halves - 1];
    if (2 * reach >= height || 2 * reach >= width)
        return CK_ERR_SIZE;
    const int64_t plane = (int64_t)height * width;
    /* Every read stays inside the grid (the caller keeps points the widest half off its sides). */
    const int64_t lowest = reach * width + reach;
    for (int64_t i = 0; i < count; ++i)
        if (at[i] < lowest || at[i] >= plane - lowest)
            return CK_ERR_RANGE;
    /* Few points, each costly and unequal (an isolated one reads every window): small dynamic chunks. */
#pragma omp parallel for schedule(dynamic, 4) num_threads(thread_count(threads)) if (count >= 64)
    for (int64_t i = 0; i < count; ++i) {
        const int64_t c = at[i];
        /* The 19 smallest squared distances: their square roots are the 19 smallest distances, in the same
         * order (sqrtf is monotonic), and only those 19 need one. */
        float best[19];
        for (int j = 0; j < 19; ++j)
            best[j] = INFINITY;
        int done = 0; /* the ring radius searched so far */
        settled[i] = 0;
        for (int k = 0; k < n_halves; ++k) {
            const int h = halves[k];
            for (int r = done + 1; r <= h; ++r) {
                /* the ring at Chebyshev radius r: its top and bottom rows whole, then the two side columns */
                const int64_t top = c - (int64_t)r * width, bottom = c + (int64_t)r * width;
                for (int dx = -r; dx <= r; ++dx) {
                    keep_nearest(best, grid_squared(grid, c, top + dx));
                    keep_nearest(best, grid_squared(grid, c, bottom + dx));
                }
                for (int dy = -r + 1; dy <= r - 1; ++dy) {
                    const int64_t row = c + (int64_t)dy * width;
                    keep_nearest(best, grid_squared(grid, c, row - r));
                    keep_nearest(best, grid_squared(grid, c, row + r));
                }
            }
            done = h;
            const double beyond = (h + 1) * spacing[i];
            double total = 0.0;
            for (int j = 0; j < 19; ++j)
                total += min_d((double)sqrtf(best[j]), beyond);
            mean[i] = (float)(total / 20.0);
            if ((double)sqrtf(best[18]) <= 0.95 * beyond) {
                settled[i] = 1;
                break;
            }
        }
    }
    return CK_OK;
}

/* Solves the 3 x 3 system a x = b by elimination with partial pivoting (as LAPACK's dgesv). */
static void solve3(double a[3][3], double b[3], double x[3]) {
    for (int col = 0; col < 3; ++col) {
        int pivot = col;
        for (int r = col + 1; r < 3; ++r)
            if (fabs(a[r][col]) > fabs(a[pivot][col]))
                pivot = r;
        if (pivot != col) {
            for (int k = 0; k < 3; ++k) {
                double t = a[col][k];
                a[col][k] = a[pivot][k];
                a[pivot][k] = t;
            }
            double t = b[col];
            b[col] = b[pivot];
            b[pivot] = t;
        }
        for (int r = col + 1; r < 3; ++r) {
            double f = a[r][col] / a[col][col];
            for (int k = col; k < 3; ++k)
                a[r][k] -= f * a[col][k];
            b[r] -= f * b[col];
        }
    }
    for (int r = 2; r >= 0; --r) {
        double s = b[r];
        for (int k = r + 1; k < 3; ++k)
            s -= a[r][k] * x[k];
        x[r] = s / a[r][r];
    }
}

/* CK_OK when the thread count is valid and starts[0..patches] run from 0 without decreasing. */
static int check_patches(int64_t patches, const int64_t *starts, int threads) {
    if (patches < 0 || threads < 0)
        return CK_ERR_SIZE;
    if (starts[0] != 0)
        return CK_ERR_RANGE;
    for (int64_t k = 0; k < patches; ++k)
        if (starts[k + 1] < starts[k])
            return CK_ERR_RANGE;
    return CK_OK;
}

int ck_patch_shift(int64_t patches, const int64_t *starts, const double *params, const float *x,
                   const double *dx, const double *dy, float *out, int threads) {
    if (!starts || !params || !x || !dx || !dy || !out)
        return CK_ERR_NULL;
    int rc = check_patches(patches, starts, threads);
    if (rc != CK_OK)
        return rc;
#pragma omp parallel for schedule(static) num_threads(thread_count(threads)) \
    if (starts[patches] >= CK_PARALLEL_MIN)
    for (int64_t k = 0; k < patches; ++k) {
        const double a = params[3 * k], b = params[3 * k + 1], c = params[3 * k + 2];
        for (int64_t i = starts[k]; i < starts[k + 1]; ++i)
            out[i] = (float)((double)x[i] - (a + b * dx[i] + c * dy[i]));
    }
    return CK_OK;
}

int ck_patch_step(int64_t patches, const int64_t *starts, const double *l_dev, const double *l_energy,
                  const float *right, const double *dx, const double *dy, double *step, int threads) {
    if (!starts || !l_dev || !l_energy || !right || !dx || !dy || !step)
        return CK_ERR_NULL;
    int rc = check_patches(patches, starts, threads);
    if (rc != CK_OK)
        return rc;
    /* One thread sums each patch, in pixel order: the step is identical for any thread count. */
#pragma omp parallel for schedule(dynamic, 16) num_threads(thread_count(threads)) \
    if (starts[patches] >= CK_PARALLEL_MIN)
    for (int64_t k = 0; k < patches; ++k) {
        const int64_t lo = starts[k], hi = starts[k + 1];
        const double size = (double)(hi - lo > 1 ? hi - lo : 1);
        double r_sum = 0.0;
        for (int64_t i = lo; i < hi; ++i)
            r_sum += (double)right[2 * i];
        const double r_mean = r_sum / size;
        double r_energy = 0.0;
        for (int64_t i = lo; i < hi; ++i) {
            double dev = (double)right[2 * i] - r_mean;
            r_energy += dev * dev;
        }
        /* the right patch scaled to the left one's contrast (gain, vignetting, highlights) */
        const double gain = sqrt(l_energy[k] / max_d(r_energy, 1e-9));
        double abs_sum = 0.0;
        for (int64_t i = lo; i < hi; ++i)
            abs_sum += fabs(l_dev[i] - gain * ((double)right[2 * i] - r_mean));
        /* Huber weights scaled by the patch's mean absolute residual (sqrt(pi / 2) * mean |e| = sigma) */
        const double scale = 1.2533 * abs_sum / size + 1e-3;
        double m[9] = {0.0};
        for (int64_t i = lo; i < hi; ++i) {
            const double error = l_dev[i] - gain * ((double)right[2 * i] - r_mean);
            const double grad = (double)right[2 * i + 1] * gain;
            const double weight = min_d(1.0, 2.0 * scale / max_d(fabs(error), 1e-9));
            const double wg = weight * grad, ww = wg * grad, we = -wg * error;
            const double x = dx[i], y = dy[i];
            m[0] += ww;
            m[1] += ww * x;
            m[2] += ww * y;
            m[3] += ww * (x * x);
            m[4] += ww * (x * y);
            m[5] += ww * (y * y);
            m[6] += we;
            m[7] += we * x;
            m[8] += we * y;
        }
        double a[3][3] = {{m[0] + 1e-6, m[1], m[2]}, {m[1], m[3] + 1e-6, m[4]}, {m[2], m[4], m[5] + 1e-6}};
        double b[3] = {m[6], m[7], m[8]};
        solve3(a, b, step + 3 * k);
    }
    return CK_OK;
}

/* ---- cell grid of points in a plane (cellctl.vision.surface) ---- */

/* Cells of one axis a radius query at q reaches, [*lo, *hi] (empty when *lo > *hi). The span is widened by
 * 1e-6 cells so that rounding in the cell arithmetic never leaves out a point the distance test takes. */
static void reach(double q, double radius, double origin, double cell, int64_t n, int64_t *lo, int64_t *hi) {
    const double a = floor((q - radius - origin) / cell - 1e-6), b = floor((q + radius - origin) / cell + 1e-6);
    *lo = 1;
    *hi = 0;
    if (!(a <= b) || b < 0.0 || a > (double)(n - 1)) /* also NaN */
        return;
    *lo = a < 0.0 ? 0 : (int64_t)a;
    *hi = b > (double)(n - 1) ? n - 1 : (int64_t)b;
}

/* CK_OK when the grid's shape is usable. */
static int check_grid(double cell, int64_t cols, int64_t rows) {
    if (!(cell > 0.0) || cols < 1 || rows < 1 || cols > ((int64_t)1 << 24) || rows > ((int64_t)1 << 24) ||
        cols * rows > ((int64_t)1 << 30))
        return CK_ERR_SIZE;
    return CK_OK;
}

/* The cell (flat index) of a point, or -1 outside the grid (or NaN). */
static int64_t cell_of(double x, double y, double x0, double y0, double cell, int64_t cols, int64_t rows) {
    const double c = floor((x - x0) / cell), r = floor((y - y0) / cell);
    if (!(c >= 0.0 && c < (double)cols && r >= 0.0 && r < (double)rows))
        return -1;
    return (int64_t)r * cols + (int64_t)c;
}

int ck_grid_build(const double *x, const double *y, int64_t n, double x0, double y0, double cell, int64_t cols,
                  int64_t rows, int64_t *order, int64_t *starts) {
    if (!x || !y || !order || !starts)
        return CK_ERR_NULL;
    if (n < 0)
        return CK_ERR_SIZE;
    int rc = check_grid(cell, cols, rows);
    if (rc != CK_OK)
        return rc;
    const int64_t cells = cols * rows;
    for (int64_t c = 0; c <= cells; ++c)
        starts[c] = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t c = cell_of(x[i], y[i], x0, y0, cell, cols, rows);
        if (c < 0)
            return CK_ERR_RANGE;
        starts[c + 1] += 1;
    }
    for (int64_t c = 0; c < cells; ++c)
        starts[c + 1] += starts[c];
    /* starts[c] is the next free place of cell c while placing; afterwards it is cell c + 1's start. */
    for (int64_t i = 0; i < n; ++i) {
        const int64_t c = cell_of(x[i], y[i], x0, y0, cell, cols, rows);
        order[starts[c]++] = i;
    }
    for (int64_t c = cells; c > 0; --c)
        starts[c] = starts[c - 1];
    starts[0] = 0;
    return CK_OK;
}

/* CK_OK when the queries' arguments are usable. */
static int check_queries(const int64_t *starts, double cell, int64_t cols, int64_t rows, int64_t count,
                         double radius, int threads) {
    int rc = check_grid(cell, cols, rows);
    if (rc != CK_OK)
        return rc;
    if (count < 0 || threads < 0 || !(radius >= 0.0) || starts[0] != 0)
        return CK_ERR_SIZE;
    return CK_OK;
}

int ck_grid_radius(const double *gx, const double *gy, const int64_t *gi, const int64_t *starts, double x0,
                   double y0, double cell, int64_t cols, int64_t rows, const double *qx, const double *qy,
                   int64_t count, double radius, int64_t *counts, const int64_t *offsets, int64_t *found,
                   int threads) {
    if (!gx || !gy || !gi || !starts || !qx || !qy || !counts || (found && !offsets))
        return CK_ERR_NULL;
    int rc = check_queries(starts, cell, cols, rows, count, radius, threads);
    if (rc != CK_OK)
        return rc;
    const double r2 = radius * radius;
    int overflow = 0;
#pragma omp parallel for schedule(dynamic, 16) num_threads(thread_count(threads)) if (count >= 256)
    for (int64_t k = 0; k < count; ++k) {
        int64_t c0, c1, r0, r1, m = 0;
        const int64_t room = found ? offsets[k + 1] - offsets[k] : 0;
        reach(qx[k], radius, x0, cell, cols, &c0, &c1);
        reach(qy[k], radius, y0, cell, rows, &r0, &r1);
        for (int64_t r = r0; r <= r1; ++r)
            for (int64_t i = starts[r * cols + c0]; i < starts[r * cols + c1 + 1]; ++i) {
                /* as a k-d tree's radius search on (x, y, 0): (0 + dx^2) + dy^2 (+ 0^2), below radius^2 */
                const double dx = qx[k] - gx[i], dy = qy[k] - gy[i];
                if (dx * dx + dy * dy < r2) {
                    if (found) {
                        if (m >= room) {
#pragma omp atomic write
                            overflow = 1;
                            break;
                        }
                        found[offsets[k] + m] = gi[i];
                    }
                    ++m;
                }
            }
        counts[k] = m;
    }
    return overflow ? CK_ERR_RANGE : CK_OK;
}

static inline void swap_d(double *a, double *b) {
    const double t = *a;
    *a = *b;
    *b = t;
}

/* The k-th smallest of a[0..n) (n > k >= 0), leaving every a[i] for i > k at least as large. */
static double select_kth(double *a, int64_t n, int64_t k) {
    int64_t lo = 0, hi = n - 1;
    while (hi > lo) {
        const int64_t mid = lo + (hi - lo) / 2;
        if (a[mid] < a[lo])
            swap_d(&a[mid], &a[lo]);
        if (a[hi] < a[lo])
            swap_d(&a[hi], &a[lo]);
        if (a[hi] < a[mid])
            swap_d(&a[hi], &a[mid]);
        const double pivot = a[mid];
        int64_t i = lo, j = hi;
        while (i <= j) {
            while (a[i] < pivot)
                ++i;
            while (a[j] > pivot)
                --j;
            if (i <= j) {
                swap_d(&a[i], &a[j]);
                ++i;
                --j;
            }
        }
        if (k <= j)
            hi = j;
        else if (k >= i)
            lo = i;
        else
            break; /* a[j + 1 .. i - 1] all equal the pivot */
    }
    return a[k];
}

int ck_grid_radius_medians(const double *gx, const double *gy, const double *gz, const int64_t *starts, double x0,
                           double y0, double cell, int64_t cols, int64_t rows, const double *qx, const double *qy,
                           int64_t count, double radius, const int64_t *offsets, double *scratch, double *medians,
                           int threads) {
    if (!gx || !gy || !gz || !starts || !qx || !qy || !offsets || !scratch || !medians)
        return CK_ERR_NULL;
    int rc = check_queries(starts, cell, cols, rows, count, radius, threads);
    if (rc != CK_OK)
        return rc;
    if (offsets[0] != 0)
        return CK_ERR_RANGE;
    for (int64_t k = 0; k < count; ++k)
        if (offsets[k + 1] < offsets[k])
            return CK_ERR_RANGE;
    const double r2 = radius * radius;
    int overflow = 0;
#pragma omp parallel for schedule(dynamic, 16) num_threads(thread_count(threads)) if (count >= 256)
    for (int64_t k = 0; k < count; ++k) {
        int64_t c0, c1, r0, r1, m = 0;
        double *z = scratch + offsets[k];
        const int64_t room = offsets[k + 1] - offsets[k];
        reach(qx[k], radius, x0, cell, cols, &c0, &c1);
        reach(qy[k], radius, y0, cell, rows, &r0, &r1);
        for (int64_t r = r0; r <= r1 && m <= room; ++r)
            for (int64_t i = starts[r * cols + c0]; i < starts[r * cols + c1 + 1]; ++i) {
                const double dx = qx[k] - gx[i], dy = qy[k] - gy[i];
                if (dx * dx + dy * dy < r2) {
                    if (m >= room) {
                        m = room + 1;
                        break;
                    }
                    z[m++] = gz[i];
                }
            }
        if (m > room) {
#pragma omp atomic write
            overflow = 1;
            medians[k] = NAN;
            continue;
        }
        if (m == 0) {
            medians[k] = NAN;
            continue;
        }
        const int64_t half = (m - 1) / 2;
        const double lower = select_kth(z, m, half);
        double upper = lower;
        if (m % 2 == 0) { /* the smallest of those above the lower middle */
            upper = z[half + 1];
            for (int64_t i = half + 2; i < m; ++i)
                upper = min_d(upper, z[i]);
        }
        medians[k] = (lower + upper) / 2;
    }
    return overflow ? CK_ERR_RANGE : CK_OK;
}

int ck_cell_upper_medians(const double *gz, const int64_t *starts, int64_t cells, double *scratch, double *out,
                          int threads) {
    if (!gz || !starts || !scratch || !out)
        return CK_ERR_NULL;
    if (cells < 1 || cells > ((int64_t)1 << 30) || threads < 0)
        return CK_ERR_SIZE;
    if (starts[0] != 0)
        return CK_ERR_RANGE;
    for (int64_t c = 0; c < cells; ++c)
        if (starts[c + 1] < starts[c])
            return CK_ERR_RANGE;
#pragma omp parallel for schedule(dynamic, 256) num_threads(thread_count(threads)) if (cells >= CK_PARALLEL_MIN)
    for (int64_t c = 0; c < cells; ++c) {
        const int64_t lo = starts[c], n = starts[c + 1] - starts[c];
        if (n == 0) {
            out[c] = NAN;
            continue;
        }
        for (int64_t i = 0; i < n; ++i)
            scratch[lo + i] = gz[lo + i];
        out[c] = select_kth(scratch + lo, n, n / 2);
    }
    return CK_OK;
}

/* ---- points against a polygon (cellctl.vision.footprint) ---- */

/* The first of the m sorted values ys[2 i] (stride 2) not below y (ge) or above it (!ge). */
static int64_t first_index(const float *ys, int64_t m, float y, int ge) {
    int64_t lo = 0, hi = m;
    while (lo < hi) {
        const int64_t mid = lo + (hi - lo) / 2;
        if (ge ? ys[2 * mid] < y : ys[2 * mid] <= y)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

int ck_points_in_polygon(const float *polygon, int64_t n, const float *points, int64_t m, int8_t *out) {
    if (!polygon || !points || !out)
        return CK_ERR_NULL;
    if (n < 0 || m < 0)
        return CK_ERR_SIZE;
    for (int64_t j = 1; j < m; ++j)
        if (!(points[2 * j + 1] >= points[2 * j - 1]))
            return CK_ERR_RANGE;
    /* out holds the crossing count's parity (1 odd, 2 even) while the edges are applied, 0 once on an edge */
    for (int64_t j = 0; j < m; ++j)
        out[j] = n > 0 ? 2 : -1;
    for (int64_t i = 0; i < n; ++i) {
        const float *v0 = polygon + 2 * (i == 0 ? n - 1 : i - 1), *v = polygon + 2 * i;
        const float low = v0[1] < v[1] ? v0[1] : v[1], high = v0[1] < v[1] ? v[1] : v0[1];
        /* Points whose y lies outside the edge's closed y span: the edge neither crosses their ray nor holds
         * them, whatever its x. */
        const int64_t end = first_index(points + 1, m, high, 0);
        for (int64_t j = first_index(points + 1, m, low, 1); j < end; ++j) {
            if (out[j] == 0)
                continue;
            const float px = points[2 * j], py = points[2 * j + 1];
            if ((v0[1] <= py && v[1] <= py) || (v0[1] > py && v[1] > py) || (v0[0] < px && v[0] < px)) {
                if (py == v[1] && (px == v[0] || (py == v0[1] && ((v0[0] <= px && px <= v[0]) ||
                                                                  (v[0] <= px && px <= v0[0])))))
                    out[j] = 0;
                continue;
            }
            double dist = (double)(py - v0[1]) * (v[0] - v0[0]) - (double)(px - v0[0]) * (v[1] - v0[1]);
            if (dist == 0) {
                out[j] = 0;
                continue;
            }
            if (v[1] < v0[1])
                dist = -dist;
            if (dist > 0)
                out[j] = (int8_t)(3 - out[j]); /* one more crossing: parity flips */
        }
    }
    for (int64_t j = 0; j < m; ++j)
        if (out[j] > 0)
            out[j] = out[j] == 1 ? 1 : -1;
    return CK_OK;
}

/* ---- bicubic samples on image rows (cellctl.vision.subpixel) ---- */

#define CK_CUBIC_A (-0.75f) /* Keys' a, OpenCV's INTER_CUBIC */

/* One pixel of ck_patch_sample: the scalar rule, which the vector kernel below follows operation by operation. */
static inline void sample_pixel(double pa, double pb, double pc, float x, double dx, double dy, const float *row,
                                int width, float *out) {
    const float a = CK_CUBIC_A, limit = (float)width + 4.0f;
    float at = (float)((double)x - (pa + pb * dx + pc * dy)); /* as ck_patch_shift */
    at = at >= -4.0f ? (at <= limit ? at : limit) : -4.0f;    /* NaN: -4, column 0 */
    const int whole = (int)(at + 4.0f) - 4;                   /* floor: at + 4 >= 0 */
    const float t = at - (float)whole, t1 = t + 1.0f, u = 1.0f - t;
    const float w0 = ((a * t1 - 5.0f * a) * t1 + 8.0f * a) * t1 - 4.0f * a;
    const float w1 = ((a + 2.0f) * t - (a + 3.0f)) * t * t + 1.0f;
    const float w2 = ((a + 2.0f) * u - (a + 3.0f)) * u * u + 1.0f;
    const float w3 = 1.0f - w0 - w1 - w2;
    int c0 = whole - 1, c1 = whole, c2 = whole + 1, c3 = whole + 2;
    if (c0 < 0 || c3 >= width) {
        c0 = c0 < 0 ? 0 : (c0 >= width ? width - 1 : c0);
        c1 = c1 < 0 ? 0 : (c1 >= width ? width - 1 : c1);
        c2 = c2 < 0 ? 0 : (c2 >= width ? width - 1 : c2);
        c3 = c3 < 0 ? 0 : (c3 >= width ? width - 1 : c3);
    }
    for (int ch = 0; ch < 2; ++ch)
        out[ch] = row[2 * c0 + ch] * w0 + row[2 * c1 + ch] * w1 + row[2 * c2 + ch] * w2 + row[2 * c3 + ch] * w3;
}

/* Pixels [lo, hi) of one patch by the scalar rule. */
static void sample_run_scalar(double pa, double pb, double pc, const float *x, const double *dx, const double *dy,
                              const int32_t *rows, const float *image, int width, float *out, int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i)
        sample_pixel(pa, pb, pc, x[i], dx[i], dy[i], image + (int64_t)rows[i] * width * 2, width, out + 2 * i);
}

/* The AVX2 kernel exists only where the compiler targets x86: elsewhere (an ARM line PC) the scalar one runs. */
#if CK_HAVE_X86
/* Pixels [lo, hi) of one patch, four at a time in AVX2 (the rest, and pixels whose four columns reach past the
 * image's side, by sample_pixel). The same IEEE operations in the same order as sample_pixel, without fused
 * multiply-adds (the target has none): the same bits. The positions and weights of four pixels are computed in
 * vectors; each pixel's four columns of both channels are one 32-byte load, weighted, and summed as the scalar
 * rule sums them: ((c0 + c1) + c2) + c3 per channel. */
__attribute__((target("avx2"))) static void sample_run_avx2(double pa, double pb, double pc, const float *x,
                                                           const double *dx, const double *dy,
                                                           const int32_t *rows, const float *image, int width,
                                                           float *out, int64_t lo, int64_t hi) {
    const __m256d va = _mm256_set1_pd(pa), vb = _mm256_set1_pd(pb), vc = _mm256_set1_pd(pc);
    const __m128 a = _mm_set1_ps(CK_CUBIC_A), a5 = _mm_set1_ps(5.0f * CK_CUBIC_A), a8 = _mm_set1_ps(8.0f * CK_CUBIC_A),
                 a4 = _mm_set1_ps(4.0f * CK_CUBIC_A), a2 = _mm_set1_ps(CK_CUBIC_A + 2.0f),
                 a3 = _mm_set1_ps(CK_CUBIC_A + 3.0f), one = _mm_set1_ps(1.0f), four = _mm_set1_ps(4.0f),
                 low = _mm_set1_ps(-4.0f), limit = _mm_set1_ps((float)width + 4.0f);
    int64_t i = lo;
    for (; i + 4 <= hi; i += 4) {
        const __m256d shift = _mm256_add_pd(_mm256_add_pd(va, _mm256_mul_pd(vb, _mm256_loadu_pd(dx + i))),
                                            _mm256_mul_pd(vc, _mm256_loadu_pd(dy + i)));
        __m128 at = _mm256_cvtpd_ps(_mm256_sub_pd(_mm256_cvtps_pd(_mm_loadu_ps(x + i)), shift));
        at = _mm_blendv_ps(limit, at, _mm_cmp_ps(at, limit, _CMP_LE_OQ)); /* NaN: limit, then -4 below */
        at = _mm_blendv_ps(low, at, _mm_cmp_ps(at, low, _CMP_GE_OQ));
        const __m128i whole = _mm_sub_epi32(_mm_cvttps_epi32(_mm_add_ps(at, four)), _mm_set1_epi32(4));
        const __m128 t = _mm_sub_ps(at, _mm_cvtepi32_ps(whole)), t1 = _mm_add_ps(t, one), u = _mm_sub_ps(one, t);
        const __m128 w0 = _mm_sub_ps(
            _mm_mul_ps(_mm_add_ps(_mm_mul_ps(_mm_sub_ps(_mm_mul_ps(a, t1), a5), t1), a8), t1), a4);
        const __m128 w1 = _mm_add_ps(_mm_mul_ps(_mm_mul_ps(_mm_sub_ps(_mm_mul_ps(a2, t), a3), t), t), one);
        const __m128 w2 = _mm_add_ps(_mm_mul_ps(_mm_mul_ps(_mm_sub_ps(_mm_mul_ps(a2, u), a3), u), u), one);
        const __m128 w3 = _mm_sub_ps(_mm_sub_ps(_mm_sub_ps(one, w0), w1), w2);
        /* per pixel j: (w0, w0, w1, w1) and (w2, w2, w3, w3) */
        const __m128 p01lo = _mm_unpacklo_ps(w0, w1), p01hi = _mm_unpackhi_ps(w0, w1);
        const __m128 p23lo = _mm_unpacklo_ps(w2, w3), p23hi = _mm_unpackhi_ps(w2, w3);
        __m256 weights[4];
        weights[0] = _mm256_set_m128(_mm_shuffle_ps(p23lo, p23lo, 0x50), _mm_shuffle_ps(p01lo, p01lo, 0x50));
        weights[1] = _mm256_set_m128(_mm_shuffle_ps(p23lo, p23lo, 0xFA), _mm_shuffle_ps(p01lo, p01lo, 0xFA));
        weights[2] = _mm256_set_m128(_mm_shuffle_ps(p23hi, p23hi, 0x50), _mm_shuffle_ps(p01hi, p01hi, 0x50));
        weights[3] = _mm256_set_m128(_mm_shuffle_ps(p23hi, p23hi, 0xFA), _mm_shuffle_ps(p01hi, p01hi, 0xFA));
        int columns[4];
        _mm_storeu_si128((__m128i *)columns, whole);
        for (int j = 0; j < 4; ++j) {
            const int64_t k = i + j;
            const float *row = image + (int64_t)rows[k] * width * 2;
            if (columns[j] - 1 < 0 || columns[j] + 2 >= width) {
                sample_pixel(pa, pb, pc, x[k], dx[k], dy[k], row, width, out + 2 * k);
                continue;
            }
            const __m256 p = _mm256_mul_ps(_mm256_loadu_ps(row + 2 * (columns[j] - 1)), weights[j]);
            const __m128 near = _mm256_castps256_ps128(p), far = _mm256_extractf128_ps(p, 1);
            __m128 sum = _mm_add_ps(near, _mm_movehl_ps(near, near)); /* c0 + c1 */
            sum = _mm_add_ps(sum, far);                                /* + c2 */
            sum = _mm_add_ps(sum, _mm_movehl_ps(far, far));            /* + c3 */
            _mm_storel_pi((__m64 *)(out + 2 * k), sum);
        }
    }
    sample_run_scalar(pa, pb, pc, x, dx, dy, rows, image, width, out, i, hi);
}

static int have_avx2(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") ? 1 : 0;
}
#else
static int have_avx2(void) { return 0; }
#define sample_run_avx2 sample_run_scalar /* never called there: have_avx2() is 0 */
#endif

int ck_patch_sample(int64_t patches, const int64_t *starts, const double *params, const float *x, const double *dx,
                    const double *dy, const int32_t *rows, const float *image, int height, int width, float *out,
                    int simd, int threads) {
    if (!starts || !params || !x || !dx || !dy || !rows || !image || !out)
        return CK_ERR_NULL;
    if (height < 1 || width < 1 || simd < 0 || simd > 1)
        return CK_ERR_SIZE;
    int rc = check_patches(patches, starts, threads);
    if (rc != CK_OK)
        return rc;
    for (int64_t i = 0; i < starts[patches]; ++i)
        if (rows[i] < 0 || rows[i] >= height)
            return CK_ERR_RANGE;
    const int vector = simd && have_avx2();
#pragma omp parallel for schedule(static) num_threads(thread_count(threads)) \
    if (starts[patches] >= CK_PARALLEL_MIN)
    for (int64_t k = 0; k < patches; ++k) {
        const double pa = params[3 * k], pb = params[3 * k + 1], pc = params[3 * k + 2];
        if (vector)
            sample_run_avx2(pa, pb, pc, x, dx, dy, rows, image, width, out, starts[k], starts[k + 1]);
        else
            sample_run_scalar(pa, pb, pc, x, dx, dy, rows, image, width, out, starts[k], starts[k + 1]);
    }
    return CK_OK;
}

/* ---- points on the footprint's raster (cellctl.vision.footprint) ---- */

static int check_raster(const double *xy, int64_t n, int64_t stride, double cell, int64_t rows, int64_t cols) {
    if (!xy)
        return CK_ERR_NULL;
    if (n < 0 || stride < 2 || !(cell > 0.0) || rows < 0 || cols < 0 || (cols > 0 && rows > INT64_MAX / cols))
        return CK_ERR_SIZE;
    return CK_OK;
}

/* The flat cell of a point, or -1 outside the raster: the comparisons in double, so NaN and infinities
 * fall outside as numpy's clip-and-test finds them. */
static inline int64_t raster_cell(double x, double y, double x0, double y0, double cell, int64_t rows,
                                  int64_t cols) {
    const double col = floor((x - x0) / cell), row = floor((y - y0) / cell);
    if (!(col >= 0.0 && col < (double)cols && row >= 0.0 && row < (double)rows))
        return -1;
    return (int64_t)row * cols + (int64_t)col;
}

int ck_cell_counts(const double *xy, int64_t n, int64_t stride, double x0, double y0, double cell, int64_t rows,
                   int64_t cols, float *out) {
    int rc = check_raster(xy, n, stride, cell, rows, cols);
    if (rc != CK_OK)
        return rc;
    if (!out)
        return CK_ERR_NULL;
    if (n >= (int64_t)1 << 24)
        return CK_ERR_SIZE; /* a count must stay exact in float32 */
    for (int64_t k = 0; k < rows * cols; ++k)
        out[k] = 0.0f;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t c = raster_cell(xy[i * stride], xy[i * stride + 1], x0, y0, cell, rows, cols);
        if (c >= 0)
            out[c] += 1.0f;
    }
    return CK_OK;
}

int ck_cells_marked(const double *xy, int64_t n, int64_t stride, double x0, double y0, double cell,
                    const uint8_t *mask, int64_t rows, int64_t cols, uint8_t *out) {
    int rc = check_raster(xy, n, stride, cell, rows, cols);
    if (rc != CK_OK)
        return rc;
    if (!mask || !out)
        return CK_ERR_NULL;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t c = raster_cell(xy[i * stride], xy[i * stride + 1], x0, y0, cell, rows, cols);
        out[i] = (uint8_t)(c >= 0 && mask[c] != 0);
    }
    return CK_OK;
}

/* ---- binary morphology with a disc of centred runs (cellctl.vision.sole_region) ---- */

int ck_disc_dilate(const uint8_t *mask, int64_t rows, int64_t cols, int of_zero, const int32_t *half, int32_t reach,
                   int invert, uint8_t *out, int16_t *scratch) {
    if (!mask || !half || !out || !scratch)
        return CK_ERR_NULL;
    if (rows < 1 || cols < 1 || rows > CK_MAX_RASTER || cols > CK_MAX_RASTER || reach < 0 || reach > CK_MAX_RASTER ||
        (of_zero != 0 && of_zero != 1) || (invert != 0 && invert != 1))
        return CK_ERR_SIZE;
    for (int32_t k = 0; k <= 2 * reach; ++k)
        if (half[k] < 0 || half[k] > CK_MAX_RASTER)
            return CK_ERR_RANGE;
    /* Per row, each cell's distance along the row to the nearest source cell (`far` where the row has none):
     * a cell is in the dilation where, for some row offset d of the disc, the row r + d has a source cell
     * within the disc's run half[d + reach] of its column. Cells off the raster are never sources (OpenCV's
     * border for a dilation; for an erosion, done as the complement's dilation, they count as marked). */
    const int16_t far = INT16_MAX;
    const uint8_t source = of_zero ? 0 : 1;
    for (int64_t r = 0; r < rows; ++r) {
        const uint8_t *m = mask + r * cols;
        int16_t *h = scratch + r * cols;
        int32_t last = -1; /* column of the last source cell seen, -1: none yet */
        for (int64_t c = 0; c < cols; ++c) {
            if ((m[c] != 0) == source)
                last = (int32_t)c;
            h[c] = last < 0 ? far : (int16_t)(c - last);
        }
        last = -1;
        for (int64_t c = cols - 1; c >= 0; --c) {
            if ((m[c] != 0) == source)
                last = (int32_t)c;
            if (last >= 0 && last - c < h[c])
                h[c] = (int16_t)(last - c);
        }
    }
    const uint8_t hit = invert ? 0 : 1;
    for (int64_t r = 0; r < rows; ++r) {
        uint8_t *o = out + r * cols;
        for (int64_t c = 0; c < cols; ++c)
            o[c] = 0;
        const int64_t lo = r - reach < 0 ? -r : -(int64_t)reach, hi = r + reach >= rows ? rows - 1 - r : reach;
        for (int64_t d = lo; d <= hi; ++d) {
            const int16_t *h = scratch + (r + d) * cols;
            const int16_t run = (int16_t)half[d + reach];
            for (int64_t c = 0; c < cols; ++c)
                o[c] |= (uint8_t)(h[c] <= run);
        }
        for (int64_t c = 0; c < cols; ++c)
            o[c] = o[c] ? hit : (uint8_t)(1 - hit);
    }
    return CK_OK;
}
