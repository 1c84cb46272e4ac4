/* Left-right consistency check, fills, median and colour-weighted median. */
#include <omp.h>
#include <string.h>

#include "params.h"
#include "postprocess.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

static void lr_check_row(const cc_params *p, const int16_t *left, const int16_t *right, int width,
                         int16_t *out)
{
    for (int x = 0; x < width; x++) {
        int d = left[x];
        if (d == CC_INVALID || p->lr_max_diff < 0) {
            out[x] = (int16_t)d;
            continue;
        }
        int xr = x - cc_whole_px(d);
        int ok = xr >= 0 && xr < width && right[xr] != CC_INVALID &&
                 (right[xr] > d ? right[xr] - d : d - right[xr]) <= p->lr_max_diff;
        out[x] = ok ? (int16_t)d : (int16_t)CC_INVALID;
    }
}

/* Occlusion by the image border: a pixel whose surface, judged by the nearest
 * kept disparity on its inner side, would be seen outside the other image
 * cannot have a real match; whatever it matched consistently is wrong.  Only
 * runs when the left-right check does (it works on its output). */
static void border_occlusion_row(int16_t *row, int width)
{
    int ref = CC_INVALID;
    for (int x = width - 1; x >= 0; x--) { /* left border: x - d < 0 */
        if (row[x] == CC_INVALID)
            continue;
        if (ref != CC_INVALID && x - cc_whole_px(ref) < 0)
            row[x] = CC_INVALID;
        else
            ref = row[x];
    }
    ref = CC_INVALID;
    for (int x = 0; x < width; x++) { /* right border: x - d >= width */
        if (row[x] == CC_INVALID)
            continue;
        if (ref != CC_INVALID && x - cc_whole_px(ref) >= width)
            row[x] = CC_INVALID;
        else
            ref = row[x];
    }
}

/* floor(a / b) for b > 0. */
static inline int64_t floor_div64(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

/* Invalid pixels are mostly occlusions, which belong to the farther surface:
 * take the smaller of the nearest valid disparities to the left and right.
 * When those two differ by at most fill_interpolate px they are taken to lie
 * on one surface (a hole in an untextured, possibly slanted region rather
 * than an occlusion), and the run between them follows the straight line
 * from one to the other, rounded half up. */
static void fill_row(const cc_params *p, const int16_t *in, int width, int16_t *out)
{
    const int span = p->fill_interpolate * CC_DISP_SCALE;
    int xl = -1;
    for (int x = 0; x < width; x++) {
        if (in[x] != CC_INVALID) {
            out[x] = in[x];
            xl = x;
            continue;
        }
        int xr = x;
        while (xr < width && in[xr] == CC_INVALID)
            xr++;
        for (int i = x; i < xr; i++) {
            if (xl < 0 || xr == width) {
                out[i] = xl < 0 ? (xr == width ? (int16_t)CC_INVALID : in[xr]) : in[xl];
                continue;
            }
            int l = in[xl], r = in[xr];
            if (span > 0 && (l > r ? l - r : r - l) <= span)
                out[i] = (int16_t)(l + floor_div64(2 * (int64_t)(r - l) * (i - xl) + (xr - xl), 2 * (int64_t)(xr - xl)));
            else
                out[i] = (int16_t)(l < r ? l : r);
        }
        x = xr - 1;
    }
}

/* Border-occluded strips.  Left of the first kept pixel of a row (x < the
 * largest disparity) the right camera may not see the surface at all, and
 * the background fill would hold the edge value at a constant level while a
 * slanted surface keeps sloping across the strip.  The strip is instead
 * extrapolated along a line d = a + b * u fitted to the kept pixels of the
 * next border_fit columns, u counted from the strip's edge, pooled over rows
 * y - BORDER_ROWS .. y + BORDER_ROWS and only from pixels within BORDER_SAME
 * of the edge value (the same surface).  Mirrored for the right border when
 * the range has negative disparities.  Integer arithmetic: the slope in
 * 1/(16 * 256) px per px, clamped to BORDER_MAX_SLOPE. */
#define BORDER_ROWS 2
#define BORDER_SAME (2 * CC_DISP_SCALE)
#define BORDER_FRAC 256
#define BORDER_MAX_SLOPE (CC_DISP_SCALE * BORDER_FRAC / 4) /* 1/4 px per px */

/* Fills out[x] for the strip pixels x0 <= x < x1 of row y, whose edge is the
 * kept pixel `edge`; side = +1 for the left border, -1 for the right.  Returns
 * 0 (and writes nothing) when the fit has fewer than border_fit points or no
 * spread in u. */
static int border_strip(const cc_params *p, const int16_t *checked, int width, int height, int y,
                        int edge, int side, int x0, int x1, int16_t *out)
{
    const int K = p->border_fit, d0 = checked[(size_t)y * width + edge];
    int64_t n = 0, su = 0, suu = 0, sv = 0, suv = 0;
    int r0 = y - BORDER_ROWS < 0 ? 0 : y - BORDER_ROWS;
    int r1 = y + BORDER_ROWS >= height ? height - 1 : y + BORDER_ROWS;
    for (int yy = r0; yy <= r1; yy++) {
        const int16_t *row = checked + (size_t)yy * width;
        for (int u = 0; u < K; u++) {
            int x = edge + side * u;
            if (x < 0 || x >= width)
                break;
            int v = row[x];
            if (v == CC_INVALID || (v > d0 ? v - d0 : d0 - v) > BORDER_SAME)
                continue;
            n++;
            su += u;
            suu += (int64_t)u * u;
            sv += v;
            suv += (int64_t)u * v;
        }
    }
    int64_t den = n * suu - su * su;
    if (n < K || den <= 0)
        return 0;
    int64_t b = floor_div64(2 * BORDER_FRAC * (n * suv - su * sv) + den, 2 * den);
    b = b > BORDER_MAX_SLOPE ? BORDER_MAX_SLOPE : (b < -BORDER_MAX_SLOPE ? -BORDER_MAX_SLOPE : b);
    int64_t a = floor_div64(2 * (BORDER_FRAC * sv - b * su) + n, 2 * n);
    const int lo = p->min_disparity * CC_DISP_SCALE;
    const int hi = (p->min_disparity + p->num_disparities - 1) * CC_DISP_SCALE;
    for (int x = x0; x < x1; x++) {
        int64_t v = floor_div64(2 * (a + b * side * (x - edge)) + BORDER_FRAC, 2 * BORDER_FRAC);
        out[x] = (int16_t)(v < lo ? lo : (v > hi ? hi : v));
    }
    return 1;
}

/* Extrapolates the border-occluded strips of row y into out (a full row) and
 * returns the strips' extent: [0, *left_end) and [*right_begin, width) were
 * written, the pixels between were not. */
static void border_fit_row(const cc_params *p, const int16_t *checked, int width, int height, int y,
                           int16_t *out, int *left_end, int *right_begin)
{
    const int16_t *row = checked + (size_t)y * width;
    const int dmin = p->min_disparity, dmax = dmin + p->num_disparities - 1;
    *left_end = 0;
    *right_begin = width;
    if (p->border_fit == 0)
        return;
    int first = 0, last = width - 1;
    while (first < width && row[first] == CC_INVALID)
        first++;
    if (first == width)
        return;
    while (row[last] == CC_INVALID)
        last--;
    /* x can be border-occluded only if x - d < 0 (x < dmax) or x - d >= width (x >= width + dmin) */
    int left_len = first < dmax ? first : dmax;
    if (left_len > 0 && border_strip(p, checked, width, height, y, first, 1, 0, left_len, out))
        *left_end = left_len;
    int right_len = width - 1 - last < -dmin ? width - 1 - last : -dmin;
    if (right_len > 0 && border_strip(p, checked, width, height, y, last, -1, width - right_len, width, out))
        *right_begin = width - right_len;
}

#define SORT2(a, b)                        \
    do {                                   \
        int16_t lo_ = a < b ? a : b;       \
        b = a < b ? b : a;                 \
        a = lo_;                           \
    } while (0)

/* A full 3 x 3 window without invalid pixels (the common case): its median by
 * a branchless exchange network instead of the insertion sort below.  Returns
 * 0, leaving the window to the general code, when a pixel is invalid. */
static inline int median9_full(const int16_t *in, int width, int x0, int y0, int16_t *out)
{
    int16_t p[9];
    int bad = 0;
    for (int i = 0; i < 9; i++) {
        p[i] = in[(size_t)(y0 + i / 3) * width + x0 + i % 3];
        bad |= p[i] == CC_INVALID;
    }
    if (bad)
        return 0;
    SORT2(p[1], p[2]); SORT2(p[4], p[5]); SORT2(p[7], p[8]);
    SORT2(p[0], p[1]); SORT2(p[3], p[4]); SORT2(p[6], p[7]);
    SORT2(p[1], p[2]); SORT2(p[4], p[5]); SORT2(p[7], p[8]);
    SORT2(p[0], p[3]); SORT2(p[5], p[8]); SORT2(p[4], p[7]);
    SORT2(p[3], p[6]); SORT2(p[1], p[4]); SORT2(p[2], p[5]);
    SORT2(p[4], p[7]); SORT2(p[4], p[2]); SORT2(p[6], p[4]);
    SORT2(p[4], p[2]);
    *out = p[4];
    return 1;
}

#if CC_HAVE_X86
#define VSORT2(a, b)                           \
    do {                                       \
        __m256i lo_ = _mm256_min_epi16(a, b);  \
        b = _mm256_max_epi16(a, b);            \
        a = lo_;                               \
    } while (0)

/* median9_full on 16 pixels x..x+15 of row y (all nine neighbours inside the image): the same
 * exchange network, lane by lane.  Returns a bit per pixel (two per lane, movemask of 16-bit lanes)
 * whose window holds an invalid pixel: those are left to the general code. */
__attribute__((target("avx2"))) static unsigned median9_16(const int16_t *in, int width, int x, int y, int16_t *out)
{
    __m256i p[9];
    for (int i = 0; i < 9; i++)
        p[i] = _mm256_loadu_si256((const __m256i *)(in + (size_t)(y - 1 + i / 3) * width + x - 1 + i % 3));
    __m256i lowest = p[0];
    for (int i = 1; i < 9; i++)
        lowest = _mm256_min_epi16(lowest, p[i]);
    VSORT2(p[1], p[2]); VSORT2(p[4], p[5]); VSORT2(p[7], p[8]);
    VSORT2(p[0], p[1]); VSORT2(p[3], p[4]); VSORT2(p[6], p[7]);
    VSORT2(p[1], p[2]); VSORT2(p[4], p[5]); VSORT2(p[7], p[8]);
    VSORT2(p[0], p[3]); VSORT2(p[5], p[8]); VSORT2(p[4], p[7]);
    VSORT2(p[3], p[6]); VSORT2(p[1], p[4]); VSORT2(p[2], p[5]);
    VSORT2(p[4], p[7]); VSORT2(p[4], p[2]); VSORT2(p[6], p[4]);
    VSORT2(p[4], p[2]);
    _mm256_storeu_si256((__m256i *)(out + x), p[4]);
    /* CC_INVALID is the smallest int16: a window holds one exactly when its minimum is it */
    return (unsigned)_mm256_movemask_epi8(_mm256_cmpeq_epi16(lowest, _mm256_set1_epi16(CC_INVALID)));
}
#endif

static void median_row_general(const int16_t *in, int width, int height, int y, int size, int x_from, int x_to,
                               int16_t *out);

/* Median of the valid pixels of the window (clipped at the border); an
 * invalid pixel stays invalid, so the filter never invents a measurement.
 * The 3 x 3 filter of an inner row runs 16 pixels at a time with AVX2. */
static void median_row(const int16_t *in, int width, int height, int y, int size, int use_avx2, int16_t *out)
{
#if CC_HAVE_X86
    if (use_avx2 && size == 3 && y > 0 && y < height - 1 && width - 2 >= 16) {
        const int last = width - 1 - 16; /* the last chunk's first pixel: x + 16 <= width - 1 */
        for (int x0 = 1;; x0 += 16) {
            const int x = x0 < last ? x0 : last;
            unsigned bad = median9_16(in, width, x, y, out);
            while (bad) { /* windows with an invalid pixel: the general code, pixel by pixel */
                int lane = __builtin_ctz(bad) / 2;
                median_row_general(in, width, height, y, size, x + lane, x + lane + 1, out);
                bad &= ~(3u << (2 * lane));
            }
            if (x == last)
                break;
        }
        median_row_general(in, width, height, y, size, 0, 1, out);
        median_row_general(in, width, height, y, size, width - 1, width, out);
        return;
    }
#endif
    median_row_general(in, width, height, y, size, 0, width, out);
}

static void median_row_general(const int16_t *in, int width, int height, int y, int size, int x_from, int x_to,
                               int16_t *out)
{
    int r = size / 2;
    int y0 = y - r < 0 ? 0 : y - r, y1 = y + r >= height ? height - 1 : y + r;
    for (int x = x_from; x < x_to; x++) {
        if (in[(size_t)y * width + x] == CC_INVALID) {
            out[x] = CC_INVALID;
            continue;
        }
        int x0 = x - r < 0 ? 0 : x - r, x1 = x + r >= width ? width - 1 : x + r;
        if (size == 3 && x1 - x0 == 2 && y1 - y0 == 2 && median9_full(in, width, x0, y0, out + x))
            continue;
        int16_t v[25];
        int n = 0;
        for (int yy = y0; yy <= y1; yy++)
            for (int xx = x0; xx <= x1; xx++) {
                int16_t a = in[(size_t)yy * width + xx];
                if (a == CC_INVALID)
                    continue;
                int i = n++;
                while (i > 0 && v[i - 1] > a) {
                    v[i] = v[i - 1];
                    i--;
                }
                v[i] = a;
            }
        out[x] = v[(n - 1) / 2];
    }
}


/* The post-processing's scratch, in this order: a map; the levels (32 entries of slack for the vector
 * loads); the packed guide (8 px of slack); the level runs; the guide's planes (3, each with 32 bytes of
 * slack); the no-level bytes (32 of slack); a histogram per thread. */
#define LEVEL_SLACK 32
static size_t plane_bytes(size_t n) { return cc_round_up(n + 32, 64); }

size_t cc_postprocess_scratch_bytes(const cc_params *p, int width, int height, int threads)
{
    size_t n = (size_t)width * height;
    return cc_round_up(n * sizeof(int16_t), 64) + cc_round_up((n + LEVEL_SLACK) * sizeof(uint16_t), 64) +
           cc_round_up((n + 8) * sizeof(uint32_t), 64) + cc_round_up(n * sizeof(uint16_t), 64) +
           4 * plane_bytes(n) + cc_round_up(cc_wm_hist_bytes(p->num_disparities), 64) * (size_t)threads;
}

#if CC_HAVE_X86
/* cc_wm_level of 16 values at a time: floor((v + 8) / 16) as (v >> 4) + ((v & 15) + 8 >> 4), which
 * cannot overflow 16 bits, less dmin, clamped to 0..levels-1; CC_WM_NO_LEVEL where v is CC_INVALID.
 * Returns how many pixels it did (a multiple of 16); the caller does the rest. */
__attribute__((target("avx2"))) static int levels_avx2(const int16_t *in, int width, int dmin, int levels,
                                                        uint16_t *out)
{
    const __m256i vdmin = _mm256_set1_epi16((short)dmin), top = _mm256_set1_epi16((short)(levels - 1));
    const __m256i fifteen = _mm256_set1_epi16(15), eight = _mm256_set1_epi16(8), zero = _mm256_setzero_si256();
    const __m256i invalid = _mm256_set1_epi16(CC_INVALID);
    int x = 0;
    for (; x + 16 <= width; x += 16) {
        __m256i v = _mm256_loadu_si256((const __m256i *)(in + x));
        __m256i whole = _mm256_add_epi16(_mm256_srai_epi16(v, 4),
                                         _mm256_srli_epi16(_mm256_add_epi16(_mm256_and_si256(v, fifteen), eight), 4));
        __m256i b = _mm256_min_epi16(_mm256_max_epi16(_mm256_sub_epi16(whole, vdmin), zero), top);
        _mm256_storeu_si256((__m256i *)(out + x), _mm256_or_si256(b, _mm256_cmpeq_epi16(v, invalid)));
    }
    return x;
}
#endif

/* Levels of a row for the weighted medians, their runs (cc_wm_pixel), and 0xFF where a pixel has none. */
static void levels_row(const cc_params *p, const int16_t *in, int width, int use_avx2, uint16_t *out,
                       uint16_t *run, uint8_t *invalid)
{
    int x = 0;
#if CC_HAVE_X86
    if (use_avx2)
        x = levels_avx2(in, width, p->min_disparity, p->num_disparities, out);
#endif
    for (; x < width; x++)
        out[x] = (uint16_t)cc_wm_level(in[x], p->min_disparity, p->num_disparities);
    for (x = 0; x < width; x++)
        invalid[x] = out[x] == CC_WM_NO_LEVEL ? 0xFF : 0;
    run[width - 1] = 1;
    for (int x = width - 2; x >= 0; x--)
        run[x] = out[x] == out[x + 1] && run[x + 1] < UINT16_MAX ? (uint16_t)(run[x + 1] + 1) : 1;
}

/* Stages, each over all rows before the next starts (the windows read
 * neighbouring rows): check + border + background fill; the border strips'
 * line fit and the weighted fill of the other pixels the check rejected; the
 * median; the weighted median. */
void cc_postprocess_maps(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                         const cc_wm_image *guide, int width, int height, int16_t *checked,
                         int16_t *filled, int16_t *disp, void *scratch, int threads)
{
    const int weighted_fill = p->fill_mode == CC_FILL_WEIGHTED, wmedian = p->weighted_median > 0;

    const size_t n = (size_t)width * height, map_bytes = cc_round_up(n * sizeof(int16_t), 64);
    const size_t hist_stride = cc_round_up(cc_wm_hist_bytes(p->num_disparities), 64);
    int16_t *tmp = scratch;
    uint16_t *level = (uint16_t *)((uint8_t *)scratch + map_bytes);
    uint32_t *packed = (uint32_t *)((uint8_t *)level + cc_round_up((n + LEVEL_SLACK) * sizeof(uint16_t), 64));
    uint16_t *run = (uint16_t *)((uint8_t *)packed + cc_round_up((n + 8) * sizeof(uint32_t), 64));
    uint8_t *planes[3], *invalid;
    planes[0] = (uint8_t *)run + cc_round_up(n * sizeof(uint16_t), 64);
    planes[1] = planes[0] + plane_bytes(n);
    planes[2] = planes[1] + plane_bytes(n);
    invalid = planes[2] + plane_bytes(n);
    uint8_t *hist_base = invalid + plane_bytes(n);
    cc_wm_tables tables;
    if (weighted_fill || wmedian)
        cc_wm_tables_init(&tables, p->wm_sigma_colour, p->wm_sigma_space);
    cc_wm_image g = *guide;
    g.use_avx2 = p->simd != CC_SIMD_SCALAR && cc_cpu_has_avx2();
    /* the planar kernel when it can run (AVX2, colour weights ending early), else the packed one */
    const int planar = (weighted_fill || wmedian) && cc_wm_planar_usable(&tables, g.use_avx2);
    g.packed = planar ? NULL : packed;
    for (int c = 0; c < 3; c++)
        g.planes[c] = planar && c < (g.channels == 3 ? 3 : 1) ? planes[c] : NULL;
    memset(level + n, 0xFF, LEVEL_SLACK * sizeof(uint16_t));
    memset(packed + n, 0, 8 * sizeof(uint32_t));
    for (int c = 0; c < 3; c++)
        memset(planes[c] + n, 0, 32);
    memset(invalid + n, 0xFF, 32);
    int16_t *fill_out = weighted_fill ? tmp : filled;
    int16_t *median_out = wmedian ? tmp : disp;
    const int16_t *wm_in = p->median ? tmp : filled;
    const cc_wm_map fill_map = {.value = tmp, .level = level, .run = run, .invalid = planar ? invalid : NULL};
    const cc_wm_map wm_map = {.value = wm_in, .level = level, .run = run, .invalid = planar ? invalid : NULL};
#pragma omp parallel num_threads(threads)
    {
        cc_wm_hist h = cc_wm_hist_at(hist_base + hist_stride * (size_t)omp_get_thread_num(), p->num_disparities);
        if (weighted_fill || wmedian)
            cc_wm_hist_clear(&h, p->num_disparities);
#pragma omp for schedule(dynamic, 8)
        for (int y = 0; y < height; y++) {
            size_t o = (size_t)y * width;
            lr_check_row(p, raw_left + o, raw_right + o, width, checked + o);
            if (p->lr_max_diff >= 0)
                border_occlusion_row(checked + o, width);
            if (p->fill_mode != CC_FILL_NONE)
                fill_row(p, checked + o, width, fill_out + o);
            else
                memcpy(fill_out + o, checked + o, sizeof(int16_t) * width);
            if (weighted_fill)
                levels_row(p, tmp + o, width, g.use_avx2, level + o, run + o, invalid + o);
            if (planar)
                cc_wm_planes_row(&g, y, planes);
            else if (weighted_fill || wmedian)
                cc_wm_pack_row(&g, y, packed + o);
        }
        if (p->fill_mode != CC_FILL_NONE) { /* border strips, then (weighted) the rejected pixels */
#pragma omp for schedule(dynamic, 4)
            for (int y = 0; y < height; y++) {
                int left_end, right_begin;
                border_fit_row(p, checked, width, height, y, filled + (size_t)y * width, &left_end, &right_begin);
                if (!weighted_fill)
                    continue;
                h.guess = -1; /* the kernel's guess: the median level of the fill pixel just before */
                for (int x = left_end; x < right_begin; x++) {
                    size_t o = (size_t)y * width + x;
                    if (checked[o] == CC_INVALID) {
                        filled[o] = cc_wm_pixel(&tables, &g, &fill_map, x, y, p->fill_radius, &h);
                    } else {
                        filled[o] = tmp[o];
                        h.guess = -1;
                    }
                }
            }
        }
#pragma omp for schedule(dynamic, 8)
        for (int y = 0; y < height; y++) {
            size_t o = (size_t)y * width;
            if (p->median)
                median_row(filled, width, height, y, p->median, g.use_avx2, median_out + o);
            else if (!wmedian)
                memcpy(disp + o, filled + o, sizeof(int16_t) * width);
            if (wmedian) /* levels of the weighted median's input, complete for this row */
                levels_row(p, p->median ? median_out + o : filled + o, width, g.use_avx2, level + o, run + o,
                           invalid + o);
        }
        if (wmedian) {
#pragma omp for schedule(dynamic, 4)
            for (int y = 0; y < height; y++)
                cc_wm_row(&tables, &g, &wm_map, y, p->weighted_median, &h, disp + (size_t)y * width);
        }
    }
}
