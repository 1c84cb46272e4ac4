/* The change test's per-pixel work; see change_kernels.h. */
#include "change_kernels.h"

#include <math.h>
#include <omp.h>
#include <string.h>

/* Below this many pixels a call stays on one thread: waking the others costs more. */
#define CHK_PARALLEL_MIN 4096
/* Float planes chk_texture keeps in its scratch space besides the row sums. */
#define CHK_PLANES 7

/* numpy's maximum for values that are never NaN (checked on entry), as one instruction. */
static inline float max_f(float a, float b) { return a > b ? a : b; }

static int thread_count(int threads, int height, int width)
{
    if ((int64_t)height * width < CHK_PARALLEL_MIN)
        return 1;
    return threads > 0 ? threads : omp_get_max_threads();
}

/* OpenCV's borderInterpolate for BORDER_REFLECT_101 (gfedcb|abcdefgh|gfedcba). */
static inline int reflect101(int p, int n)
{
    if (n == 1)
        return 0;
    while ((unsigned)p >= (unsigned)n)
        p = p < 0 ? -p : 2 * n - 2 - p;
    return p;
}

static inline int at(int p, int n) { return (unsigned)p < (unsigned)n ? p : reflect101(p, n); }

/* What a row pass sums: a, a * a, or a * b (the float32 product numpy forms before cv2.blur sees it). */
enum source { SRC_A, SRC_SQUARE, SRC_PRODUCT };

static inline double source_at(const float *a, const float *b, enum source kind, int x)
{
    switch (kind) {
    case SRC_SQUARE:
        return (double)(a[x] * a[x]);
    case SRC_PRODUCT:
        return (double)(a[x] * b[x]);
    default:
        return (double)a[x];
    }
}

/* Rows summed side by side in the running loop: each row's sum is a serial chain of additions (OpenCV's
 * order), so a few independent rows keep the adder busy. */
#define CHK_ROWS 4

/*
 * CHK_ROWS rows (`n` of them used) of OpenCV's RowSum<float, double> over the border-extended row
 * S[i] = source[reflect(i - k / 2)]: sizes 3 and 5 summed directly, larger ones as a running sum
 * (s += S[i + k] - S[i]), each row in that order.
 */
static inline __attribute__((always_inline)) void row_block(const float *const *a, const float *const *b,
                                                            enum source kind, int n, int width, int k,
                                                            double *const *d)
{
    const int anchor = k / 2;
#define S(r, i) source_at(a[r], b[r], kind, at((i) - anchor, width))
    if (k == 3 || k == 5) {
        for (int r = 0; r < n; ++r)
            for (int i = 0; i < width; ++i)
                d[r][i] = k == 3 ? S(r, i) + S(r, i + 1) + S(r, i + 2)
                                 : S(r, i) + S(r, i + 1) + S(r, i + 2) + S(r, i + 3) + S(r, i + 4);
        return;
    }
    double s[CHK_ROWS] = {0};
    for (int r = 0; r < n; ++r) {
        for (int i = 0; i < k; ++i)
            s[r] += S(r, i);
        d[r][0] = s[r];
    }
    /* Where S[i] and S[i + k] both lie inside the row: no reflection. */
    const int first = anchor, last = width - 1 - k + anchor;
    if (n == CHK_ROWS) {
        for (int i = 0; i < width - 1; ++i) {
            if (i >= first && i <= last) {
                for (int r = 0; r < CHK_ROWS; ++r) {
                    s[r] += source_at(a[r], b[r], kind, i + k - anchor) - source_at(a[r], b[r], kind, i - anchor);
                    d[r][i + 1] = s[r];
                }
            } else {
                for (int r = 0; r < CHK_ROWS; ++r) {
                    s[r] += S(r, i + k) - S(r, i);
                    d[r][i + 1] = s[r];
                }
            }
        }
        return;
    }
    for (int r = 0; r < n; ++r)
        for (int i = 0; i < width - 1; ++i) {
            s[r] += S(r, i + k) - S(r, i);
            d[r][i + 1] = s[r];
        }
#undef S
}

/* The row pass of a box over a whole image (rows `stride` floats apart), into `rows` (height x width); a
 * worksharing loop inside the caller's parallel region. */
static inline __attribute__((always_inline)) void row_sums_kind(const float *a, int64_t a_stride, const float *b,
                                                                int64_t b_stride, enum source kind, int height,
                                                                int width, int k, double *rows)
{
    const int blocks = (height + CHK_ROWS - 1) / CHK_ROWS;
#pragma omp for schedule(static)
    for (int block = 0; block < blocks; ++block) {
        const float *ra[CHK_ROWS], *rb[CHK_ROWS];
        double *rd[CHK_ROWS];
        const int y0 = block * CHK_ROWS, n = height - y0 < CHK_ROWS ? height - y0 : CHK_ROWS;
        for (int r = 0; r < CHK_ROWS; ++r) {
            const int y = y0 + (r < n ? r : 0);
            ra[r] = a + y * a_stride;
            rb[r] = b ? b + y * b_stride : ra[r];
            rd[r] = rows + (size_t)y * width;
        }
        row_block(ra, rb, kind, n, width, k, rd);
    }
}

static void row_sums(const float *a, int64_t a_stride, const float *b, int64_t b_stride, enum source kind,
                     int height, int width, int k, double *rows)
{
    switch (kind) {
    case SRC_SQUARE:
        row_sums_kind(a, a_stride, b, b_stride, SRC_SQUARE, height, width, k, rows);
        break;
    case SRC_PRODUCT:
        row_sums_kind(a, a_stride, b, b_stride, SRC_PRODUCT, height, width, k, rows);
        break;
    default:
        row_sums_kind(a, a_stride, b, b_stride, SRC_A, height, width, k, rows);
    }
}

/*
 * The column pass of OpenCV's ColumnSum<double, float>: per column a running sum down the whole height over
 * the border-extended rows (the first k - 1 summed from 0, then s = sum + newest; out = s * scale; sum = s -
 * oldest). Each thread of the caller's parallel region takes a range of columns, in OpenCV's order; a barrier
 * before (the row sums) and after (the result).
 */
static void column_sums(const double *rows, int height, int width, int k, float *dst, double *sum)
{
    const int anchor = k / 2;
    const double scale = 1. / (k * k);
    const int t = omp_get_thread_num(), n = omp_get_num_threads();
    const int c0 = (int)((int64_t)width * t / n), c1 = (int)((int64_t)width * (t + 1) / n);
    for (int c = c0; c < c1; ++c)
        sum[c] = 0;
    for (int j = 0; j < k - 1; ++j) {
        const double *r = rows + (size_t)at(j - anchor, height) * width;
        for (int c = c0; c < c1; ++c)
            sum[c] += r[c];
    }
    for (int y = 0; y < height; ++y) {
        const double *newest = rows + (size_t)at(y + k - 1 - anchor, height) * width;
        const double *oldest = rows + (size_t)at(y - anchor, height) * width;
        float *d = dst + (size_t)y * width;
        for (int c = c0; c < c1; ++c) {
            const double s = sum[c] + newest[c];
            d[c] = (float)(s * scale);
            sum[c] = s - oldest[c];
        }
    }
#pragma omp barrier
}

/* Scratch layout: row sums (height x width doubles), the column sums (width doubles), then the float planes. */
typedef struct {
    double *rows, *sum;
    float *plane[CHK_PLANES];
} workspace;

size_t chk_scratch_bytes(int height, int width)
{
    if (height < 1 || width < 1 || height > CHK_MAX_DIM || width > CHK_MAX_DIM)
        return 0;
    const size_t pixels = (size_t)height * width;
    return (pixels + (size_t)width) * sizeof(double) + CHK_PLANES * pixels * sizeof(float);
}

static workspace carve(void *scratch, int height, int width)
{
    const size_t pixels = (size_t)height * width;
    workspace w;
    w.rows = scratch;
    w.sum = w.rows + pixels;
    float *next = (float *)(w.sum + width);
    for (int i = 0; i < CHK_PLANES; ++i, next += pixels)
        w.plane[i] = next;
    return w;
}

/* A box mean (see change_kernels.h), called by every thread of a parallel region. */
static void box(const workspace *w, const float *a, int64_t a_stride, const float *b, int64_t b_stride,
                enum source kind, int height, int width, int k, float *dst)
{
    row_sums(a, a_stride, b, b_stride, kind, height, width, k, w->rows); /* ends in a barrier */
    column_sums(w->rows, height, width, k, dst, w->sum);
}

/* The contiguous plane's box mean (dst may be the plane). */
static void box_plane(const workspace *w, const float *plane, int height, int width, int k, float *dst)
{
    box(w, plane, width, NULL, 0, SRC_A, height, width, k, dst);
}

static int check_image(const void *data, int64_t stride, int height, int width)
{
    if (!data)
        return CHK_ERR_NULL;
    if (height < 1 || width < 1 || height > CHK_MAX_DIM || width > CHK_MAX_DIM || stride < width)
        return CHK_ERR_SIZE;
    return CHK_OK;
}

static int check_window(int k) { return k >= 3 && k <= CHK_MAX_WINDOW; }

static int check_scratch(const void *scratch, size_t bytes, int height, int width)
{
    if (!scratch)
        return CHK_ERR_NULL;
    if ((uintptr_t)scratch % sizeof(double) != 0 || bytes < chk_scratch_bytes(height, width))
        return CHK_ERR_SIZE;
    return CHK_OK;
}

/* Whether every pixel is finite (the rules compare, and numpy's NaN rules are not the comparisons' here). */
static int finite_image(const float *image, int64_t stride, int height, int width, int threads)
{
    int bad = 0;
#pragma omp parallel for num_threads(threads) schedule(static) reduction(| : bad)
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x)
            bad |= !isfinite(image[y * stride + x]);
    return !bad;
}

int chk_box_mean(const float *src, int64_t src_stride, int height, int width, int k, float *dst, void *scratch,
                 size_t scratch_bytes, int threads)
{
    int rc = check_image(src, src_stride, height, width);
    if (rc != CHK_OK)
        return rc;
    if (!dst)
        return CHK_ERR_NULL;
    if ((rc = check_scratch(scratch, scratch_bytes, height, width)) != CHK_OK)
        return rc;
    if (!check_window(k) || threads < 0 || threads > 256)
        return CHK_ERR_SIZE;
    const workspace w = carve(scratch, height, width);
#pragma omp parallel num_threads(thread_count(threads, height, width))
    box(&w, src, src_stride, NULL, 0, SRC_A, height, width, k, dst);
    return CHK_OK;
}

static int check_params(const chk_texture_params *p)
{
    const double values[] = {p->gain,
                             p->offset,
                             p->gain_floor,
                             p->table_ncc,
                             p->min_texture_gain,
                             p->max_texture_gain,
                             p->unanimous,
                             p->gone_share,
                             p->min_textured_share,
                             p->textured_variance,
                             p->still_variance,
                             p->fit_variance,
                             p->scale_agreement,
                             p->max_shadow_factor,
                             p->max_carried_factor,
                             p->far_weight,
                             p->near_weight,
                             p->min_local_fit_share,
                             p->raised_local_fit_share};
    for (size_t i = 0; i < sizeof values / sizeof values[0]; ++i)
        if (!isfinite(values[i]))
            return CHK_ERR_VALUE;
    if (p->gain_floor <= 0)
        return CHK_ERR_VALUE;
    if (!check_window(p->ncc_window) || !check_window(p->illumination_window) ||
        !check_window(p->illumination_window / 2))
        return CHK_ERR_SIZE;
    return CHK_OK;
}

/* The window statistics and each window's votes (ChangeTest._texture up to its first blurs of the votes). */
static void window_votes(const float *cur, int64_t cs, const float *ref, int64_t rs, int height, int width,
                         const chk_texture_params *p, const workspace *w)
{
    const int k = p->ncc_window;
    float *mean_c = w->plane[0], *mean_r = w->plane[1], *cc = w->plane[2], *rr = w->plane[3], *cr = w->plane[4];
    box(w, cur, cs, NULL, 0, SRC_A, height, width, k, mean_c);
    box(w, ref, rs, NULL, 0, SRC_A, height, width, k, mean_r);
    box(w, cur, cs, NULL, 0, SRC_SQUARE, height, width, k, cc);
    box(w, ref, rs, NULL, 0, SRC_SQUARE, height, width, k, rr);
    box(w, cur, cs, ref, rs, SRC_PRODUCT, height, width, k, cr);
    const float gain = (float)p->gain, offset = (float)p->offset, gain_floor = (float)p->gain_floor;
    const float eps = (float)1e-6, one = 1.0f;
    const float table_ncc = (float)p->table_ncc, min_gain = (float)p->min_texture_gain;
    const float max_gain = (float)p->max_texture_gain, textured_var = (float)p->textured_variance;
    const float still_var = (float)p->still_variance, fit_var = (float)p->fit_variance;
    const float agreement = (float)p->scale_agreement, max_shadow = (float)p->max_shadow_factor;
    /* Planes afterwards: 0 textured, 1 table-like, 2 fitted, 3 confident, 4 fit-eligible (0/1), 5 the
     * brightness ratio of the confident windows (0 elsewhere). */
    const int64_t pixels = (int64_t)height * width;
#pragma omp for schedule(static)
    for (int64_t i = 0; i < pixels; ++i) {
        const float mc = mean_c[i], mr = mean_r[i];
        const float var_c = cc[i] - mc * mc;
        const float var_r = rr[i] - mr * mr;
        float brightness = mr * gain;
        brightness = brightness + offset;
        brightness = mc / max_f(brightness, one);
        const float covariance = cr[i] - mc * mr;
        float unexplained = (covariance * covariance) / max_f(var_r, eps);
        unexplained = var_c - unexplained;
        const float ncc = covariance / sqrtf(max_f(var_c * var_r, eps));
        const float texture_gain = (covariance / max_f(var_r, eps)) / gain_floor;
        const int textured = var_r > textured_var;
        const int in_scale = (texture_gain > min_gain) & (texture_gain < max_gain);
        const int table_like = (ncc > table_ncc) & in_scale & textured;
        const int eligible = var_r > still_var;
        const int fitted = eligible & (unexplained < fit_var) & (texture_gain > min_gain) & in_scale &
                           (fabsf(texture_gain - brightness) < agreement * brightness) & (brightness < max_shadow);
        const int confident = (ncc > table_ncc) & fitted;
        w->plane[0][i] = (float)textured;
        w->plane[1][i] = (float)table_like;
        w->plane[2][i] = (float)fitted;
        w->plane[3][i] = (float)confident;
        w->plane[4][i] = (float)eligible;
        w->plane[5][i] = brightness * (float)confident;
    }
}

/* Still table, texture gone, and the still table's weight (plane 0) and weighted factor (plane 1) for the
 * illumination, from the boxed votes (share, plane 1 agree, plane 2 fit share). */
static void still_and_gone(const float *cur, int64_t cs, const float *ref, int64_t rs, int height, int width,
                           const chk_texture_params *p, const workspace *w, const float *share, uint8_t *still,
                           uint8_t *gone, float *illumination)
{
    const float gain = (float)p->gain, offset = (float)p->offset, one = 1.0f;
    const float min_share = (float)p->min_textured_share, gone_share = (float)p->gone_share;
    const float unanimous = (float)p->unanimous, min_gain = (float)p->min_texture_gain;
    const float max_carried = (float)p->max_carried_factor;
#pragma omp for schedule(static)
    for (int y = 0; y < height; ++y) {
        const float *c = cur + y * cs, *r = ref + y * rs;
        const size_t row = (size_t)y * width;
        for (int x = 0; x < width; ++x) {
            const size_t i = row + x;
            const float sh = share[i], agree = w->plane[1][i];
            const int enough = sh > min_share;
            gone[i] = (uint8_t)((agree < sh * gone_share) & enough);
            const int is_still = ((agree > sh * unanimous) & enough) | (w->plane[2][i] > unanimous);
            still[i] = (uint8_t)is_still;
            float predicted = r[x] * gain;
            predicted = predicted + offset;
            const float ratio = c[x] / max_f(predicted, one);
            const float weight = (float)(is_still & (ratio > min_gain) & (ratio < max_carried));
            w->plane[0][i] = weight;
            w->plane[1][i] = ratio * weight;
            illumination[i] = one;
        }
    }
}

/* The illumination factor carried from the still table (the whole window, then its half where the still
 * table is near: the later one wins), then the local shadow fit's where it speaks. */
static void carried_illumination(int height, int width, const chk_texture_params *p, const workspace *w,
                                 const uint8_t *raised, int64_t raised_stride, float *illumination)
{
    const int sizes[2] = {p->illumination_window, p->illumination_window / 2};
    const float least[2] = {(float)p->far_weight, (float)p->near_weight};
    float *weights = w->plane[2], *weighted = w->plane[6];
    const int64_t pixels = (int64_t)height * width;
    for (int s = 0; s < 2; ++s) {
        box_plane(w, w->plane[0], height, width, sizes[s], weights);
        box_plane(w, w->plane[1], height, width, sizes[s], weighted);
#pragma omp for schedule(static)
        for (int64_t i = 0; i < pixels; ++i)
            if (weights[i] >= least[s])
                illumination[i] = weighted[i] / weights[i];
    }
    if (!p->local_shadow_fit)
        return;
    const float min_fit = (float)p->min_local_fit_share, raised_fit = (float)p->raised_local_fit_share;
    const float *weight_fit = w->plane[3], *eligible = w->plane[4], *factor = w->plane[5];
#pragma omp for schedule(static)
    for (int y = 0; y < height; ++y) {
        const size_t row = (size_t)y * width;
        for (int x = 0; x < width; ++x) {
            const size_t i = row + x;
            int local = weight_fit[i] >= min_fit;
            if (raised)
                local &= !raised[y * raised_stride + x] | (weight_fit[i] >= raised_fit * eligible[i]);
            if (local)
                illumination[i] = factor[i] / weight_fit[i];
        }
    }
}

int chk_texture(const float *current, int64_t current_stride, const float *reference, int64_t reference_stride,
                const uint8_t *raised, int64_t raised_stride, int height, int width, const chk_texture_params *p,
                uint8_t *still, uint8_t *gone, float *illumination, float *share, void *scratch,
                size_t scratch_bytes, int threads)
{
    int rc;
    if ((rc = check_image(current, current_stride, height, width)) != CHK_OK ||
        (rc = check_image(reference, reference_stride, height, width)) != CHK_OK)
        return rc;
    if (raised && (rc = check_image(raised, raised_stride, height, width)) != CHK_OK)
        return rc;
    if (!p || !still || !gone || !illumination || !share)
        return CHK_ERR_NULL;
    if ((rc = check_scratch(scratch, scratch_bytes, height, width)) != CHK_OK)
        return rc;
    if (threads < 0 || threads > 256)
        return CHK_ERR_SIZE;
    if ((rc = check_params(p)) != CHK_OK)
        return rc;
    threads = thread_count(threads, height, width);
    if (!finite_image(current, current_stride, height, width, threads) ||
        !finite_image(reference, reference_stride, height, width, threads))
        return CHK_ERR_VALUE;

    const workspace w = carve(scratch, height, width);
    const int k = p->ncc_window;
    /* One parallel region: every step is a worksharing loop or a column range per thread, with a barrier. */
#pragma omp parallel num_threads(threads)
    {
        window_votes(current, current_stride, reference, reference_stride, height, width, p, &w);
        box_plane(&w, w.plane[0], height, width, k, share);
        box_plane(&w, w.plane[1], height, width, k, w.plane[1]); /* agree */
        box_plane(&w, w.plane[2], height, width, k, w.plane[2]); /* fit share */
        if (p->local_shadow_fit) {
            box_plane(&w, w.plane[3], height, width, k, w.plane[3]); /* weight of the fits */
            if (raised)
                box_plane(&w, w.plane[4], height, width, k, w.plane[4]); /* eligible */
            box_plane(&w, w.plane[5], height, width, k, w.plane[5]);     /* their factor */
        }
        still_and_gone(current, current_stride, reference, reference_stride, height, width, p, &w, share, still,
                       gone, illumination);
        carried_illumination(height, width, p, &w, raised, raised_stride, illumination);
    }
    return CHK_OK;
}
