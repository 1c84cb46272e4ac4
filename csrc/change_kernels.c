/* The change test's per-pixel work; see change_kernels.h. */
#include "change_kernels.h"

#include <math.h>
#include <omp.h>
#include <string.h>

/* Below this many pixels a call stays on one thread: waking the others costs more. */
#define CHK_PARALLEL_MIN 4096
/* Float planes chk_texture and chk_residual keep in their scratch space besides the row sums. */
#define CHK_PLANES 15

/* The vectorised loops twice, for AVX2 and for any x86-64 (chosen when the module loads): the same IEEE
 * operations in the same order, so the same results, with twice the lanes. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CHK_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define CHK_CLONES
#endif

/* numpy's maximum for values that are never NaN (checked on entry), as one instruction. */
static inline float max_f(float a, float b) { return a > b ? a : b; }

/* cond ? a : b on the floats' bits. GCC keeps a float ?: whose operands come from divisions as a branch (it may
 * not trap where C would not have evaluated them), which stops a loop's vectorisation; the same values. */
static inline float select_f(int cond, float a, float b)
{
    uint32_t bits_a, bits_b;
    memcpy(&bits_a, &a, sizeof bits_a);
    memcpy(&bits_b, &b, sizeof bits_b);
    const uint32_t mask = (uint32_t)-(int32_t)(cond != 0), bits = (bits_a & mask) | (bits_b & ~mask);
    float out;
    memcpy(&out, &bits, sizeof out);
    return out;
}

/* The value, unknown to the optimiser: x / max(p, 1) is otherwise split into two branches (x / p or x, one
 * being a division by 1), which keeps the loop from being vectorised. */
static inline float opaque(float value)
{
    volatile float hidden = value;
    return hidden;
}

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

/* What a box sums: a, a * a, or a * b (the float32 product numpy forms before cv2.blur sees it). */
enum source { SRC_A, SRC_SQUARE, SRC_PRODUCT };

/* One box mean to compute: its source image(s), window and destination (contiguous height x width, never the
 * source: the border rows are read again at the end). */
typedef struct {
    const float *a, *b;
    int64_t a_stride, b_stride;
    enum source kind;
    int k;
    float *dst;
} box_job;

/* The source row y extended by reflection, e[i] = source[reflect(i - k / 2)], i < width + k - 1. */
static void extended_row(const box_job *job, int y, int width, float *restrict e)
{
    const int anchor = job->k / 2, n = width + job->k - 1;
    const float *restrict a = job->a + y * job->a_stride;
    const float *restrict b = job->b ? job->b + y * job->b_stride : a;
    float *restrict mid = e + anchor;
    switch (job->kind) {
    case SRC_SQUARE:
        for (int x = 0; x < width; ++x)
            mid[x] = a[x] * a[x];
        break;
    case SRC_PRODUCT:
        for (int x = 0; x < width; ++x)
            mid[x] = a[x] * b[x];
        break;
    default:
        memcpy(mid, a, (size_t)width * sizeof(float));
    }
    for (int i = 0; i < anchor; ++i)
        e[i] = mid[at(i - anchor, width)];
    for (int i = anchor + width; i < n; ++i)
        e[i] = mid[at(i - anchor, width)];
}

/* OpenCV's RowSum<float, double> over an extended row: sizes 3 and 5 summed directly, larger ones as a running
 * sum (s += e[i + k] - e[i]), in that order. */
static void row_sum(const float *restrict e, int width, int k, double *restrict d)
{
    if (k == 3) {
        for (int i = 0; i < width; ++i)
            d[i] = (double)e[i] + (double)e[i + 1] + (double)e[i + 2];
        return;
    }
    if (k == 5) {
        for (int i = 0; i < width; ++i)
            d[i] = (double)e[i] + (double)e[i + 1] + (double)e[i + 2] + (double)e[i + 3] + (double)e[i + 4];
        return;
    }
    double s = 0;
    for (int i = 0; i < k; ++i)
        s += (double)e[i];
    d[0] = s;
    for (int i = 0; i < width - 1; ++i) {
        s += (double)e[i + k] - (double)e[i];
        d[i + 1] = s;
    }
}

/* Two rows' running sums side by side (the same order in each): each is a serial chain of additions, two keep
 * the adder busy. */
static void row_sum2(const float *restrict e0, const float *restrict e1, int width, int k, double *restrict d0,
                     double *restrict d1)
{
    if (k < 7) {
        row_sum(e0, width, k, d0);
        row_sum(e1, width, k, d1);
        return;
    }
    double s0 = 0, s1 = 0;
    for (int i = 0; i < k; ++i) {
        s0 += (double)e0[i];
        s1 += (double)e1[i];
    }
    d0[0] = s0;
    d1[0] = s1;
    for (int i = 0; i < width - 1; ++i) {
        s0 += (double)e0[i + k] - (double)e0[i];
        s1 += (double)e1[i + k] - (double)e1[i];
        d0[i + 1] = s0;
        d1[i + 1] = s1;
    }
}

/* Doubles of one thread's scratch for boxes up to k x k on rows of `width`: a ring of k + 1 row sums, the
 * column sums, and two extended rows (floats). */
static size_t thread_doubles(int width, int k) { return (size_t)(k + 2) * width + (size_t)width + k + 1; }

/* The row sums of extended rows j and j + 1 (the latter only if it exists) into their ring slots. */
static void ring_rows(const box_job *job, int j, int last, int height, int width, double *ring, float *e0, float *e1)
{
    const int k = job->k, anchor = k / 2, slots = k + 1;
    double *d0 = ring + (size_t)(j % slots) * width;
    extended_row(job, at(j - anchor, height), width, e0);
    if (j + 1 > last) {
        row_sum(e0, width, k, d0);
        return;
    }
    extended_row(job, at(j + 1 - anchor, height), width, e1);
    row_sum2(e0, e1, width, k, d0, ring + (size_t)((j + 1) % slots) * width);
}

/*
 * One box mean, streamed down the image on one thread: the row sums of the extended rows a column sum needs
 * are kept in a ring (two computed at a time), and OpenCV's ColumnSum<double, float> runs over them (the first
 * k - 1 rows summed from 0, then per row s = sum + newest; out = s / (k * k) as a float; sum = s - oldest).
 * The same operations in the same order as cv2.blur, in cache.
 */
CHK_CLONES static void box_stream(const box_job *job, int height, int width, double *scratch)
{
    const int k = job->k, slots = k + 1, last = height + k - 2; /* extended rows 0..last */
    const double scale = 1. / (k * k);
    double *ring = scratch, *restrict sum = scratch + (size_t)slots * width;
    float *e0 = (float *)(sum + width), *e1 = e0 + width + k;
    for (int c = 0; c < width; ++c)
        sum[c] = 0;
    int next = 0; /* the next extended row to compute */
    for (int j = 0; j < k - 1; ++j) {
        if (j >= next) {
            ring_rows(job, j, k - 2, height, width, ring, e0, e1);
            next = j + 2;
        }
        const double *restrict row = ring + (size_t)(j % slots) * width;
        for (int c = 0; c < width; ++c)
            sum[c] += row[c];
    }
    for (int y = 0; y < height; ++y) {
        const int j = y + k - 1;
        if (j >= next) {
            ring_rows(job, j, last, height, width, ring, e0, e1);
            next = j + 2;
        }
        const double *restrict newest = ring + (size_t)(j % slots) * width;
        const double *restrict oldest = ring + (size_t)(y % slots) * width;
        float *restrict d = job->dst + (size_t)y * width;
        for (int c = 0; c < width; ++c) {
            const double s = sum[c] + newest[c];
            d[c] = (float)(s * scale);
            sum[c] = s - oldest[c];
        }
    }
}

/* Scratch layout: per thread its box scratch (thread_doubles), then the float planes. */
typedef struct {
    double *boxes;
    size_t per_thread;
    float *plane[CHK_PLANES];
} workspace;

static int resolved_threads(int threads) { return threads > 0 ? threads : omp_get_max_threads(); }

size_t chk_scratch_bytes(int height, int width, int window, int threads)
{
    if (height < 1 || width < 1 || height > CHK_MAX_DIM || width > CHK_MAX_DIM || window < 3 ||
        window > CHK_MAX_WINDOW || threads < 0 || threads > 256)
        return 0;
    const size_t pixels = (size_t)height * width;
    return (size_t)resolved_threads(threads) * thread_doubles(width, window) * sizeof(double) +
           CHK_PLANES * pixels * sizeof(float);
}

static workspace carve(void *scratch, int height, int width, int window, int threads)
{
    const size_t pixels = (size_t)height * width;
    workspace w;
    w.boxes = scratch;
    w.per_thread = thread_doubles(width, window);
    float *next = (float *)(w.boxes + (size_t)threads * w.per_thread);
    for (int i = 0; i < CHK_PLANES; ++i, next += pixels)
        w.plane[i] = next;
    return w;
}

/* The jobs' boxes, shared out among the threads of the caller's parallel region (a barrier at the end). */
static void boxes(const workspace *w, const box_job *jobs, int count, int height, int width)
{
#pragma omp for schedule(dynamic, 1)
    for (int i = 0; i < count; ++i)
        box_stream(&jobs[i], height, width, w->boxes + (size_t)omp_get_thread_num() * w->per_thread);
}

static box_job plane_job(const float *plane, int width, int k, float *dst)
{
    return (box_job){plane, NULL, width, 0, SRC_A, k, dst};
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

static int check_scratch(const void *scratch, size_t bytes, int height, int width, int window, int threads)
{
    if (!scratch)
        return CHK_ERR_NULL;
    if ((uintptr_t)scratch % sizeof(double) != 0 || bytes < chk_scratch_bytes(height, width, window, threads))
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
                 size_t scratch_bytes)
{
    int rc = check_image(src, src_stride, height, width);
    if (rc != CHK_OK)
        return rc;
    if (!dst)
        return CHK_ERR_NULL;
    if (!check_window(k))
        return CHK_ERR_SIZE;
    if ((rc = check_scratch(scratch, scratch_bytes, height, width, k, 1)) != CHK_OK)
        return rc;
    const box_job job = {src, NULL, src_stride, 0, SRC_A, k, dst};
    box_stream(&job, height, width, scratch);
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

/* One row of the window votes from the window sums (mean_c ... cr), into 0/1 planes: textured, table-like,
 * fitted, confident, fit-eligible, and the brightness ratio of the confident windows (0 elsewhere). A function
 * of its own so that the loop is vectorised (restrict rows, no OpenMP data in the loop). */
CHK_CLONES static void window_votes_row(const chk_texture_params *p, int width, const float *restrict mcs,
                             const float *restrict mrs, const float *restrict ccs, const float *restrict rrs,
                             const float *restrict crs, float *restrict textured_out, float *restrict table_like_out,
                             float *restrict fitted_out, float *restrict confident_out, float *restrict eligible_out,
                             float *restrict factor_out)
{
    const float gain = (float)p->gain, offset = (float)p->offset, gain_floor = (float)p->gain_floor;
    const float eps = (float)1e-6, one = opaque(1.0f);
    const float table_ncc = (float)p->table_ncc, min_gain = (float)p->min_texture_gain;
    const float max_gain = (float)p->max_texture_gain, textured_var = (float)p->textured_variance;
    const float still_var = (float)p->still_variance, fit_var = (float)p->fit_variance;
    const float agreement = (float)p->scale_agreement, max_shadow = (float)p->max_shadow_factor;
#pragma omp simd
    for (int i = 0; i < width; ++i) {
        const float mc = mcs[i], mr = mrs[i];
        const float var_c = ccs[i] - mc * mc;
        const float var_r = rrs[i] - mr * mr;
        float brightness = mr * gain;
        brightness = brightness + offset;
        brightness = mc / max_f(brightness, one);
        const float covariance = crs[i] - mc * mr;
        float unexplained = (covariance * covariance) / max_f(var_r, eps);
        unexplained = var_c - unexplained;
        const float ncc = covariance / sqrtf(max_f(var_c * var_r, eps));
        const float texture_gain = (covariance / max_f(var_r, eps)) / gain_floor;
        /* Integer masks and-ed bitwise, stored as 0/1 floats: branch-free, so the loop is vectorised. */
        const int textured = var_r > textured_var;
        const int in_scale = (texture_gain > min_gain) & (texture_gain < max_gain);
        const int correlated = ncc > table_ncc;
        const int eligible = var_r > still_var;
        const int fitted = eligible & (unexplained < fit_var) & (texture_gain > min_gain) & in_scale &
                           (fabsf(texture_gain - brightness) < agreement * brightness) & (brightness < max_shadow);
        const int confident = correlated & fitted;
        textured_out[i] = (float)textured;
        table_like_out[i] = (float)(correlated & in_scale & textured);
        fitted_out[i] = (float)fitted;
        confident_out[i] = (float)confident;
        eligible_out[i] = (float)eligible;
        factor_out[i] = brightness * (float)confident;
    }
}

/* The window statistics and each window's votes (ChangeTest._texture up to its first blurs of the votes). */
static void window_votes(const float *cur, int64_t cs, const float *ref, int64_t rs, int height, int width,
                         const chk_texture_params *p, const workspace *w)
{
    const int k = p->ncc_window;
    float *mean_c = w->plane[0], *mean_r = w->plane[1], *cc = w->plane[2], *rr = w->plane[3], *cr = w->plane[4];
    const box_job jobs[] = {
        {cur, NULL, cs, 0, SRC_A, k, mean_c},   {ref, NULL, rs, 0, SRC_A, k, mean_r},
        {cur, NULL, cs, 0, SRC_SQUARE, k, cc},  {ref, NULL, rs, 0, SRC_SQUARE, k, rr},
        {cur, ref, cs, rs, SRC_PRODUCT, k, cr},
    };
    boxes(w, jobs, (int)(sizeof jobs / sizeof jobs[0]), height, width);
    /* The votes into planes 5-10 (not over the sums: the row function's rows are restrict). */
#pragma omp for schedule(static)
    for (int y = 0; y < height; ++y) {
        const size_t row = (size_t)y * width;
        window_votes_row(p, width, mean_c + row, mean_r + row, cc + row, rr + row, cr + row, w->plane[5] + row,
                         w->plane[6] + row, w->plane[7] + row, w->plane[8] + row, w->plane[9] + row,
                         w->plane[10] + row);
    }
}

/* One row of still table, texture gone, and the still table's weight and weighted factor for the
 * illumination (vectorised as window_votes_row). */
CHK_CLONES static void still_and_gone_row(const chk_texture_params *p, int width, const float *restrict c,
                               const float *restrict r, const float *restrict share, const float *restrict agree,
                               const float *restrict fit_share, uint8_t *restrict still, uint8_t *restrict gone,
                               float *restrict weight_out, float *restrict weighted_out, float *restrict illumination)
{
    const float gain = (float)p->gain, offset = (float)p->offset, one = opaque(1.0f);
    const float min_share = (float)p->min_textured_share, gone_share = (float)p->gone_share;
    const float unanimous = (float)p->unanimous, min_gain = (float)p->min_texture_gain;
    const float max_carried = (float)p->max_carried_factor;
#pragma omp simd
    for (int x = 0; x < width; ++x) {
        const float sh = share[x], ag = agree[x];
        const int enough = sh > min_share;
        gone[x] = (uint8_t)((ag < sh * gone_share) & enough);
        const int is_still = ((ag > sh * unanimous) & enough) | (fit_share[x] > unanimous);
        still[x] = (uint8_t)is_still;
        const float scaled = r[x] * gain;
        const float predicted = scaled + offset;
        const float ratio = c[x] / max_f(predicted, one);
        const float weight = (float)(is_still & (ratio > min_gain) & (ratio < max_carried));
        weight_out[x] = weight;
        weighted_out[x] = ratio * weight;
        illumination[x] = 1.0f;
    }
}

/* Still table, texture gone, and the still table's weight (plane 0) and weighted factor (plane 6) for the
 * illumination, from the boxed votes (share, plane 1 agree, plane 2 fit share). */
/* Still table, texture gone, and the still table's weight (plane 5) and weighted factor (plane 6) for the
 * illumination, from the boxed votes (share, plane 0 agree, plane 1 fit share). */
static void still_and_gone(const float *cur, int64_t cs, const float *ref, int64_t rs, int height, int width,
                           const chk_texture_params *p, const workspace *w, const float *share, uint8_t *still,
                           uint8_t *gone, float *illumination)
{
#pragma omp for schedule(static)
    for (int y = 0; y < height; ++y) {
        const size_t row = (size_t)y * width;
        still_and_gone_row(p, width, cur + y * cs, ref + y * rs, share + row, w->plane[0] + row, w->plane[1] + row,
                           still + row, gone + row, w->plane[5] + row, w->plane[6] + row, illumination + row);
    }
}

/* illumination = weighted / weights where weights >= least (a select: the division is done everywhere). */
static void carried_row(int width, const float *restrict weights, const float *restrict weighted, float least,
                        float *restrict illumination)
{
#pragma omp simd
    for (int x = 0; x < width; ++x) {
        const float carried = weighted[x] / weights[x];
        illumination[x] = weights[x] >= least ? carried : illumination[x];
    }
}

/* The local shadow fit's factor where it speaks (see chk_texture_params). */
static void local_fit_row(int width, const float *restrict weight_fit, const float *restrict eligible,
                          const float *restrict factor, const uint8_t *restrict raised, float min_fit,
                          float raised_fit, float *restrict illumination)
{
#pragma omp simd
    for (int x = 0; x < width; ++x) {
        int local = weight_fit[x] >= min_fit;
        if (raised)
            local &= (raised[x] == 0) | (weight_fit[x] >= raised_fit * eligible[x]);
        const float fit = factor[x] / weight_fit[x];
        illumination[x] = local ? fit : illumination[x];
    }
}

/* The illumination factor carried from the still table (the whole window, then its half where the still
 * table is near: the later one wins), then the local shadow fit's where it speaks (planes 2-4). */
static void carried_illumination(int height, int width, const chk_texture_params *p, const workspace *w,
                                 const uint8_t *raised, int64_t raised_stride, float *illumination)
{
    const int whole = p->illumination_window, half = p->illumination_window / 2;
    const box_job jobs[] = {plane_job(w->plane[5], width, whole, w->plane[7]),
                            plane_job(w->plane[6], width, whole, w->plane[8]),
                            plane_job(w->plane[5], width, half, w->plane[9]),
                            plane_job(w->plane[6], width, half, w->plane[10])};
    boxes(w, jobs, 4, height, width);
    const float far = (float)p->far_weight, near = (float)p->near_weight;
    const float min_fit = (float)p->min_local_fit_share, raised_fit = (float)p->raised_local_fit_share;
#pragma omp for schedule(static)
    for (int y = 0; y < height; ++y) {
        const size_t row = (size_t)y * width;
        carried_row(width, w->plane[7] + row, w->plane[8] + row, far, illumination + row);
        carried_row(width, w->plane[9] + row, w->plane[10] + row, near, illumination + row);
        if (p->local_shadow_fit)
            local_fit_row(width, w->plane[2] + row, w->plane[3] + row, w->plane[4] + row,
                          raised ? raised + y * raised_stride : NULL, min_fit, raised_fit, illumination + row);
    }
}

/* The widest box chk_texture computes. */
static int widest(const chk_texture_params *p)
{
    return p->illumination_window > p->ncc_window ? p->illumination_window : p->ncc_window;
}

size_t chk_texture_scratch_bytes(int height, int width, const chk_texture_params *p, int threads)
{
    if (!p || check_params(p) != CHK_OK)
        return 0;
    return chk_scratch_bytes(height, width, widest(p), thread_count(threads, height, width));
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
    if (threads < 0 || threads > 256)
        return CHK_ERR_SIZE;
    if ((rc = check_params(p)) != CHK_OK)
        return rc;
    threads = thread_count(threads, height, width);
    if ((rc = check_scratch(scratch, scratch_bytes, height, width, widest(p), threads)) != CHK_OK)
        return rc;
    if (!finite_image(current, current_stride, height, width, threads) ||
        !finite_image(reference, reference_stride, height, width, threads))
        return CHK_ERR_VALUE;

    const workspace w = carve(scratch, height, width, widest(p), threads);
    const int k = p->ncc_window;
    /* The votes' boxes (planes 5-10 into share, 0 agree, 1 fit share, 2 fits' weight, 4 their factor, 3 the
     * fit-eligible windows). */
    const box_job votes[] = {plane_job(w.plane[5], width, k, share),     plane_job(w.plane[6], width, k, w.plane[0]),
                             plane_job(w.plane[7], width, k, w.plane[1]), plane_job(w.plane[8], width, k, w.plane[2]),
                             plane_job(w.plane[10], width, k, w.plane[4]), plane_job(w.plane[9], width, k, w.plane[3])};
    /* The fits' boxes only for the local shadow fit, their eligible windows only on raised pixels. */
    const int vote_boxes = !p->local_shadow_fit ? 3 : raised ? 6 : 5;
    /* One parallel region: every step is a worksharing loop (boxes shared out whole), with a barrier. */
#pragma omp parallel num_threads(threads)
    {
        window_votes(current, current_stride, reference, reference_stride, height, width, p, &w);
        boxes(&w, votes, vote_boxes, height, width);
        still_and_gone(current, current_stride, reference, reference_stride, height, width, p, &w, share, still,
                       gone, illumination);
        carried_illumination(height, width, p, &w, raised, raised_stride, illumination);
    }
    return CHK_OK;
}

/* chk_residual's planes: the sources of the pixel test's window sums (on the clear pixels, |residual| above floor;
 * 0 elsewhere), each followed by its box mean, and the raw test with its mean and the faint-gone candidates. */
enum {
    RP_MAGNITUDE,             /* |residual| */
    RP_MAGNITUDE_MEAN,
    RP_CLEAR,                 /* 0/1 */
    RP_CLEAR_MEAN,
    RP_RESIDUAL,              /* the signed residual: its sum's sign is the change that dominates a window */
    RP_RESIDUAL_MEAN,
    RP_BRIGHTER,              /* 0/1: residual above floor */
    RP_BRIGHTER_MEAN,
    RP_BRIGHTER_CURRENT,      /* the current value of the brighter ones */
    RP_BRIGHTER_CURRENT_MEAN,
    RP_CURRENT,               /* the current value of all clear ones */
    RP_CURRENT_MEAN,
    RP_RAW,                   /* the pixel test, 0/1 */
    RP_RAW_MEAN,
    RP_FAINT_GONE,            /* uint8_t: texture gone where the change is faint */
    RP_COUNT
};

/* The window sums the pixel test reads: the even planes from RP_MAGNITUDE to RP_CURRENT, each into the next. */
#define RP_SUMS 6
_Static_assert(RP_COUNT <= CHK_PLANES, "chk_residual's planes fit the workspace");
_Static_assert(RP_CURRENT_MEAN == 2 * RP_SUMS - 1, "each window sum's source is followed by its mean");

/* The planes of `w` from the start of row `row` (height x width planes). */
static void row_planes(const workspace *w, size_t row, float *planes[CHK_PLANES])
{
    for (int i = 0; i < CHK_PLANES; ++i)
        planes[i] = w->plane[i] + row;
}

/* One row of the residual against the table as lit now and the sources of the pixel test's window sums. */
CHK_CLONES static void residual_row(const chk_residual_params *p, int width, const float *restrict c,
                                    const float *restrict r, const float *restrict illumination,
                                    float *restrict residual, float *const *restrict plane)
{
    float *restrict clear_magnitude = plane[RP_MAGNITUDE], *restrict clear = plane[RP_CLEAR];
    float *restrict clear_residual = plane[RP_RESIDUAL], *restrict brighter = plane[RP_BRIGHTER];
    float *restrict brighter_current = plane[RP_BRIGHTER_CURRENT], *restrict clear_current = plane[RP_CURRENT];
    const float gain = (float)p->gain, offset = (float)p->offset, one = opaque(1.0f);
    const float floor = (float)p->floor;
#pragma omp simd
    for (int x = 0; x < width; ++x) {
        const float scaled = r[x] * gain;
        const float predicted = scaled + offset;
        const float plain = c[x] - predicted;
        const float shadowed = predicted * (illumination[x] - one);
        const float res = plain - shadowed;
        residual[x] = res;
        const float magnitude = fabsf(res);
        const float is_clear = (float)(magnitude > floor);
        clear_magnitude[x] = magnitude * is_clear;
        clear[x] = is_clear;
        clear_residual[x] = res * is_clear;
        const float is_brighter = (float)(res > floor);
        brighter[x] = is_brighter;
        brighter_current[x] = c[x] * is_brighter;
        clear_current[x] = c[x] * is_clear;
    }
}

/* One row of the pixel test (raw as 0/1) and the faint-contrast texture vote's candidates, from the window
 * means of residual_row's planes (`mean`: the row's planes, RP_*_MEAN read). */
CHK_CLONES static void pixel_test_row(const chk_residual_params *p, int width, const float *restrict c,
                                      const float *restrict residual, float *const *restrict mean,
                                      const uint8_t *restrict gone, float *restrict raw, uint8_t *restrict faint_gone)
{
    const float floor = (float)p->floor, faint_limit = (float)p->faint_contrast, eps = (float)1e-6;
    const float half = 0.5f;
    const float *restrict contrast_sum = mean[RP_MAGNITUDE_MEAN], *restrict clear_share = mean[RP_CLEAR_MEAN];
    const float *restrict clear_sum = mean[RP_RESIDUAL_MEAN], *restrict brighter_share = mean[RP_BRIGHTER_MEAN];
    const float *restrict brighter_current = mean[RP_BRIGHTER_CURRENT_MEAN];
    const float *restrict clear_current = mean[RP_CURRENT_MEAN];
    /* Branch-free (every load and both sides computed, then selected: select_f), so the loop vectorises. */
#pragma omp simd
    for (int x = 0; x < width; ++x) {
        const float all_share = clear_share[x], bright_share = brighter_share[x];
        const float all_current = clear_current[x], bright_current = brighter_current[x];
        const float res = residual[x], lit = c[x] - res;
        const float contrast = contrast_sum[x] / max_f(all_share, eps);
        /* The change that dominates the window (brighter or darker than the table) and its brightness. */
        const int brighter = clear_sum[x] >= 0.0f;
        const float dark_share = all_share - bright_share, dark_current = all_current - bright_current;
        const float share = select_f(brighter, bright_share, dark_share);
        const float current = select_f(brighter, bright_current, dark_current);
        const float change = current / max_f(share, eps);
        const int same = (brighter & (res > 0.0f)) | (!brighter & (res < 0.0f));
        const float own = fabsf(change - lit);
        const float half_contrast = select_f(same, own, contrast) * half;
        raw[x] = (float)(fabsf(res) > max_f(floor, half_contrast));
        faint_gone[x] = (uint8_t)((gone[x] != 0) & (contrast < faint_limit));
    }
}

/* One row of the final pixel test: raw, or texture gone where the change is faint or inside a changed region. */
static void changed_row(const chk_residual_params *p, int width, const float *restrict raw,
                        const float *restrict raw_share, const uint8_t *restrict gone,
                        const uint8_t *restrict faint_gone, uint8_t *restrict out)
{
    const float inside_share = (float)p->gone_inside;
    for (int x = 0; x < width; ++x) {
        const int inside = (raw_share[x] > inside_share) & (gone[x] != 0);
        out[x] = (uint8_t)((raw[x] != 0.0f) | faint_gone[x] | inside);
    }
}

static int check_residual_params(const chk_residual_params *p)
{
    const double values[] = {p->gain, p->offset, p->floor, p->faint_contrast, p->gone_inside};
    for (size_t i = 0; i < sizeof values / sizeof values[0]; ++i)
        if (!isfinite(values[i]))
            return CHK_ERR_VALUE;
    if (!check_window(p->contrast_window) || !check_window(p->gone_window))
        return CHK_ERR_SIZE;
    return CHK_OK;
}

static int residual_window(const chk_residual_params *p)
{
    return p->contrast_window > p->gone_window ? p->contrast_window : p->gone_window;
}

size_t chk_residual_scratch_bytes(int height, int width, const chk_residual_params *p, int threads)
{
    if (!p || check_residual_params(p) != CHK_OK)
        return 0;
    return chk_scratch_bytes(height, width, residual_window(p), thread_count(threads, height, width));
}

int chk_residual(const float *current, int64_t current_stride, const float *reference, int64_t reference_stride,
                 const float *illumination, const uint8_t *gone, int height, int width, const chk_residual_params *p,
                 float *residual, uint8_t *raw, void *scratch, size_t scratch_bytes, int threads)
{
    int rc;
    if ((rc = check_image(current, current_stride, height, width)) != CHK_OK ||
        (rc = check_image(reference, reference_stride, height, width)) != CHK_OK)
        return rc;
    if (!p || !illumination || !gone || !residual || !raw)
        return CHK_ERR_NULL;
    if (threads < 0 || threads > 256)
        return CHK_ERR_SIZE;
    if ((rc = check_residual_params(p)) != CHK_OK)
        return rc;
    threads = thread_count(threads, height, width);
    if ((rc = check_scratch(scratch, scratch_bytes, height, width, residual_window(p), threads)) != CHK_OK)
        return rc;
    if (!finite_image(current, current_stride, height, width, threads) ||
        !finite_image(reference, reference_stride, height, width, threads) ||
        !finite_image(illumination, width, height, width, threads))
        return CHK_ERR_VALUE;

    const workspace w = carve(scratch, height, width, residual_window(p), threads);
    box_job contrast[RP_SUMS];
    for (int i = 0; i < RP_SUMS; ++i)
        contrast[i] = plane_job(w.plane[2 * i], width, p->contrast_window, w.plane[2 * i + 1]);
    const box_job inside = plane_job(w.plane[RP_RAW], width, p->gone_window, w.plane[RP_RAW_MEAN]);
    uint8_t *faint_gone = (uint8_t *)w.plane[RP_FAINT_GONE];
#pragma omp parallel num_threads(threads)
    {
#pragma omp for schedule(static)
        for (int y = 0; y < height; ++y) {
            const size_t row = (size_t)y * width;
            float *planes[CHK_PLANES];
            row_planes(&w, row, planes);
            residual_row(p, width, current + y * current_stride, reference + y * reference_stride,
                         illumination + row, residual + row, planes);
        }
        boxes(&w, contrast, RP_SUMS, height, width);
#pragma omp for schedule(static)
        for (int y = 0; y < height; ++y) {
            const size_t row = (size_t)y * width;
            float *planes[CHK_PLANES];
            row_planes(&w, row, planes);
            pixel_test_row(p, width, current + y * current_stride, residual + row, planes, gone + row,
                           w.plane[RP_RAW] + row, faint_gone + row);
        }
        boxes(&w, &inside, 1, height, width);
#pragma omp for schedule(static)
        for (int y = 0; y < height; ++y) {
            const size_t row = (size_t)y * width;
            changed_row(p, width, w.plane[RP_RAW] + row, w.plane[RP_RAW_MEAN] + row, gone + row, faint_gone + row,
                        raw + row);
        }
    }
    return CHK_OK;
}
