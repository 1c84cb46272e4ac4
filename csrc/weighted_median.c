/* Colour-weighted median of a disparity map (as the joint weighted median
 * filters of cost-volume filtering stereo: Ma et al. 2013, Hosni et al. 2013).
 *
 * Each valid pixel q of the (2r+1)^2 window around p votes for its integer
 * disparity with weight w_colour(|I(p) - I(q)|) * w_space(|p - q|), both
 * round(256 * exp(-x / sigma)).  The output is the weighted median level;
 * when the centre itself is on that level it keeps its own sub-pixel value,
 * otherwise it gets the weighted mean of the votes on that level, so a
 * sub-pixel surface stays sub-pixel.  Integer arithmetic throughout: the
 * result does not depend on the thread count.  Cost: O(window) per pixel, the
 * histogram is cleared only over the levels the window touched. */
#include <math.h>
#include <string.h>

#include "weighted_median.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

static double rounded_weight(double x, float sigma)
{
    return floor(256.0 * exp(-x / (double)sigma) + 0.5);
}

void cc_wm_tables_init(cc_wm_tables *t, float sigma_colour, float sigma_space)
{
    for (int c = 0; c < CC_WM_COLOURS; c++)
        t->colour[c] = (uint16_t)rounded_weight(c, sigma_colour);
    for (int d2 = 0; d2 < CC_WM_SPACES; d2++)
        t->space[d2] = (uint16_t)rounded_weight(sqrt((double)d2), sigma_space);
    t->gather_pad[0] = t->gather_pad[1] = 0;
    memset(t->space_win, 0, sizeof t->space_win);
    memset(t->space_row, 0, sizeof t->space_row);
    for (int dy = -CC_MAX_WM_RADIUS; dy <= CC_MAX_WM_RADIUS; dy++)
        for (int dx = -CC_MAX_WM_RADIUS; dx <= CC_MAX_WM_RADIUS; dx++) {
            t->space_win[dy + CC_MAX_WM_RADIUS][dx + CC_MAX_WM_RADIUS] = t->space[dy * dy + dx * dx];
            t->space_row[dy + CC_MAX_WM_RADIUS][dx + CC_MAX_WM_RADIUS] = t->space[dy * dy + dx * dx];
        }
    /* The colour weights fall with the difference: the first zero ends them.  The planar kernel looks
     * indices up to 16 * tables - 1, which must hold a zero (every larger difference maps there). */
    int zero = 0;
    while (zero < CC_WM_COLOURS && t->colour[zero] != 0)
        zero++;
    t->colour_tables = zero / 16 + 1 <= 8 ? zero / 16 + 1 : 0;
    memset(t->colour_bytes, 0, sizeof t->colour_bytes);
    for (int c = 1; c < 128 && c < zero; c++)
        t->colour_bytes[c] = (uint8_t)t->colour[c]; /* colour[c] < 256 for c >= 1 */
}

int cc_wm_planar_usable(const cc_wm_tables *t, int use_avx2)
{
    /* colour[1] < 256 is what the byte table needs (sigma_colour not absurdly large) */
    return use_avx2 && t->colour_tables > 0 && t->colour[0] == 256 && t->colour[1] < 256;
}

/* The histogram, then the window buffers (32-byte aligned for the vector loads). */
static size_t hist_part_bytes(int levels) { return cc_round_up((size_t)levels * (sizeof(uint32_t) + sizeof(int64_t)), 32); }

size_t cc_wm_hist_bytes(int levels) { return hist_part_bytes(levels) + 2 * CC_WM_CHUNKS * 8 * sizeof(uint32_t); }

void cc_wm_hist_clear(cc_wm_hist *h, int levels)
{
    memset(h->weight, 0, sizeof(uint32_t) * (size_t)levels);
    memset(h->value, 0, sizeof(int64_t) * (size_t)levels);
}

cc_wm_hist cc_wm_hist_at(void *base, int levels)
{
    cc_wm_hist h;
    h.value = base;
    h.weight = (uint32_t *)((int64_t *)base + levels);
    h.win_weight = (uint32_t *)((uint8_t *)base + hist_part_bytes(levels));
    h.win_level = h.win_weight + CC_WM_CHUNKS * 8;
    h.guess = -1;
    return h;
}


/* floor(a / b) for b > 0. */
static inline int64_t floor_div64(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

static inline int absdiff(int a, int b) { return a > b ? a - b : b - a; }

/* Votes of one window row into the histogram; returns their total weight.
 * `channels` is a constant at each call, so each guide layout gets its own
 * tight loop. */
static inline uint64_t vote_row(const cc_wm_tables *t, const uint8_t *gc, const uint8_t *grow,
                                const int16_t *row, const uint16_t *lrow, int x0, int x1, int x,
                                int dy2, int channels, cc_wm_hist *h, int *lo, int *hi)
{
    uint64_t total = 0;
    for (int xx = x0; xx <= x1; xx++) {
        const int b = lrow[xx];
        if (b == CC_WM_NO_LEVEL)
            continue;
        const uint8_t *q = grow + (size_t)xx * channels;
        int cd = channels == 1 ? 3 * absdiff(gc[0], q[0]) /* grey counts as three equal channels */
                               : absdiff(gc[0], q[0]) + absdiff(gc[1], q[1]) + absdiff(gc[2], q[2]);
        uint32_t wt = (uint32_t)t->colour[cd] * t->space[dy2 + (xx - x) * (xx - x)];
        h->weight[b] += wt;
        h->value[b] += (int64_t)wt * row[xx];
        total += wt;
        *lo = b < *lo ? b : *lo;
        *hi = b > *hi ? b : *hi;
    }
    return total;
}

/* Weights of one window row below and at level c; returns the row's total. */
static inline uint64_t split_row(const cc_wm_tables *t, const uint8_t *gc, const uint8_t *grow,
                                 const uint16_t *lrow, int x0, int x1, int x, int dy2, int channels,
                                 int c, uint64_t *below, uint64_t *at)
{
    uint64_t total = 0, lo = 0, eq = 0;
    for (int xx = x0; xx <= x1; xx++) {
        const int b = lrow[xx];
        if (b == CC_WM_NO_LEVEL)
            continue;
        const uint8_t *q = grow + (size_t)xx * channels;
        int cd = channels == 1 ? 3 * absdiff(gc[0], q[0])
                               : absdiff(gc[0], q[0]) + absdiff(gc[1], q[1]) + absdiff(gc[2], q[2]);
        uint64_t wt = (uint32_t)t->colour[cd] * t->space[dy2 + (xx - x) * (xx - x)];
        total += wt;
        lo += b < c ? wt : 0;
        eq += b == c ? wt : 0;
    }
    *below += lo;
    *at += eq;
    return total;
}

void cc_wm_pack_row(const cc_wm_image *g, int y, uint32_t *out)
{
    const uint8_t *row = g->data + (size_t)y * g->stride;
    for (int x = 0; x < g->width; x++) {
        const uint8_t *q = row + (size_t)x * g->channels;
        uint32_t b = q[0], gr = g->channels == 3 ? q[1] : q[0], r = g->channels == 3 ? q[2] : q[0];
        out[x] = b | gr << 8 | r << 16;
    }
}

#if CC_HAVE_X86
/* 16 interleaved BGR pixels at a time (48 bytes): each channel gathered from the three 16-byte
 * loads by byte shuffles.  Returns how many pixels it did. */
__attribute__((target("avx2"))) static int planes_row_avx2(const uint8_t *row, int width, uint8_t *b, uint8_t *g,
                                                           uint8_t *r)
{
    /* for channel c and load j: the bytes of load j that hold channel c, placed at their pixel's lane */
    static const int8_t pick[3][3][16] = {
        {{0, 3, 6, 9, 12, 15, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, -1, 2, 5, 8, 11, 14, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 1, 4, 7, 10, 13}},
        {{1, 4, 7, 10, 13, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, 0, 3, 6, 9, 12, 15, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 2, 5, 8, 11, 14}},
        {{2, 5, 8, 11, 14, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, 1, 4, 7, 10, 13, -1, -1, -1, -1, -1, -1},
         {-1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 3, 6, 9, 12, 15}}};
    __m128i sel[3][3];
    for (int c = 0; c < 3; c++)
        for (int j = 0; j < 3; j++)
            sel[c][j] = _mm_loadu_si128((const __m128i *)pick[c][j]);
    uint8_t *out[3] = {b, g, r};
    int x = 0;
    for (; x + 16 <= width; x += 16) {
        const uint8_t *q = row + 3 * (size_t)x;
        __m128i v[3] = {_mm_loadu_si128((const __m128i *)q), _mm_loadu_si128((const __m128i *)(q + 16)),
                        _mm_loadu_si128((const __m128i *)(q + 32))};
        for (int c = 0; c < 3; c++) {
            __m128i o = _mm_or_si128(_mm_or_si128(_mm_shuffle_epi8(v[0], sel[c][0]), _mm_shuffle_epi8(v[1], sel[c][1])),
                                     _mm_shuffle_epi8(v[2], sel[c][2]));
            _mm_storeu_si128((__m128i *)(out[c] + x), o);
        }
    }
    return x;
}
#endif

void cc_wm_planes_row(const cc_wm_image *g, int y, uint8_t *const planes[3])
{
    const uint8_t *row = g->data + (size_t)y * g->stride;
    const size_t o = (size_t)y * g->width;
    if (g->channels == 1) {
        memcpy(planes[0] + o, row, (size_t)g->width);
        return;
    }
    int x = 0;
#if CC_HAVE_X86
    if (g->use_avx2)
        x = planes_row_avx2(row, g->width, planes[0] + o, planes[1] + o, planes[2] + o);
#endif
    for (; x < g->width; x++)
        for (int c = 0; c < 3; c++)
            planes[c][o + x] = row[3 * x + c];
}

#if CC_HAVE_X86
#define AVX2 __attribute__((target("avx2")))

/* Votes of 8 neighbours xx..xx+7 of one window row, from the packed guide: the
 * same integer weights as the scalar loops (0 where there is no level or the
 * lane is past x1, i.e. where `pos` = xx + lane is not below `end` = x1 + 1);
 * their levels go to *levels.  `srow` is the row of space_win for this dy,
 * shifted so that srow[xx - x] is dx = xx - x.  Both weights are below 2^15
 * in 32-bit lanes, so one 16-bit multiply-add gives their product exactly. */
AVX2 static inline __m256i chunk_weights(const cc_wm_tables *t, __m256i centre, const uint32_t *prow,
                                         const uint16_t *lrow, const uint32_t *srow, int xx, int x, __m256i pos,
                                         __m256i end, __m256i *levels)
{
    const __m256i low16 = _mm256_set1_epi32(0xFFFF);
    __m256i q = _mm256_loadu_si256((const __m256i *)(prow + xx));
    __m256i lv = _mm256_cvtepu16_epi32(_mm_loadu_si128((const __m128i *)(lrow + xx)));
    __m256i ad = _mm256_sub_epi8(_mm256_max_epu8(q, centre), _mm256_min_epu8(q, centre));
    __m256i cd = _mm256_madd_epi16(_mm256_maddubs_epi16(ad, _mm256_set1_epi8(1)), _mm256_set1_epi16(1));
    __m256i cw = _mm256_and_si256(_mm256_i32gather_epi32((const int *)t->colour, cd, 2), low16);
    __m256i sw = _mm256_loadu_si256((const __m256i *)(srow + (xx - x)));
    __m256i keep = _mm256_andnot_si256(_mm256_cmpeq_epi32(lv, low16), _mm256_cmpgt_epi32(end, pos));
    *levels = lv;
    return _mm256_and_si256(_mm256_madd_epi16(cw, sw), keep);
}

/* The lane sums of a, b and c (each below 2^32 in total: at most 31 * 31 votes of at most 2^16). */
AVX2 static void hsum3(__m256i a, __m256i b, __m256i c, uint64_t out[3])
{
    __m256i ab = _mm256_hadd_epi32(a, b), cc = _mm256_hadd_epi32(c, c);
    __m256i s = _mm256_hadd_epi32(ab, cc); /* per half: a, b, c, c */
    __m128i t = _mm_add_epi32(_mm256_castsi256_si128(s), _mm256_extracti128_si256(s, 1));
    out[0] = (uint32_t)_mm_cvtsi128_si32(t);
    out[1] = (uint32_t)_mm_extract_epi32(t, 1);
    out[2] = (uint32_t)_mm_extract_epi32(t, 2);
}

AVX2 static uint64_t hsum32(__m256i v)
{
    uint32_t lanes[8];
    _mm256_storeu_si256((__m256i *)lanes, v);
    uint64_t s = 0;
    for (int k = 0; k < 8; k++)
        s += lanes[k];
    return s;
}

/* Lane-wise smallest (max = 0) or largest (max = 1) of v. */
AVX2 static uint32_t hext32(__m256i v, int max)
{
    uint32_t lanes[8];
    _mm256_storeu_si256((__m256i *)lanes, v);
    uint32_t r = lanes[0];
    for (int k = 1; k < 8; k++)
        r = max ? (lanes[k] > r ? lanes[k] : r) : (lanes[k] < r ? lanes[k] : r);
    return r;
}

/* Weight of the stored votes on levels <= b. */
AVX2 static uint64_t weight_up_to(const uint32_t *wb, const uint32_t *lb, int n, int b)
{
    const __m256i above = _mm256_set1_epi32(b);
    __m256i s = _mm256_setzero_si256();
    for (int i = 0; i < n; i++) {
        __m256i lv = _mm256_loadu_si256((const __m256i *)(lb + 8 * i));
        __m256i wt = _mm256_loadu_si256((const __m256i *)(wb + 8 * i));
        s = _mm256_add_epi32(s, _mm256_andnot_si256(_mm256_cmpgt_epi32(lv, above), wt));
    }
    return hsum32(s);
}

/* The rounded weighted mean of the stored votes on level b.  A vote's weight
 * times its value fits in int32 (2^16 * 2^15); the sums are kept in int64
 * lanes.  The map is read 8 values at a time except where that would read
 * past its end (the last row's last chunk); lanes past x1 have weight 0. */
AVX2 static int16_t level_mean(const cc_wm_image *g, const int16_t *map, const uint32_t *wb, const uint32_t *lb,
                               int b, int x0, int x1, int y0, int y1)
{
    const int w = g->width;
    const size_t end = (size_t)w * g->height;
    const __m256i vb = _mm256_set1_epi32(b);
    __m256i ws = _mm256_setzero_si256(), even = ws, odd = ws;
    int n = 0;
    for (int yy = y0; yy <= y1; yy++) {
        const size_t r = (size_t)yy * w;
        for (int xx = x0; xx <= x1; xx += 8, n++) {
            __m256i on = _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(lb + 8 * n)), vb);
            __m256i wt = _mm256_and_si256(on, _mm256_loadu_si256((const __m256i *)(wb + 8 * n)));
            __m256i mv;
            if (r + xx + 8 <= end) {
                mv = _mm256_cvtepi16_epi32(_mm_loadu_si128((const __m128i *)(map + r + xx)));
            } else {
                int32_t v[8] = {0};
                for (int k = 0; k <= x1 - xx && k < 8; k++)
                    v[k] = map[r + xx + k];
                mv = _mm256_loadu_si256((const __m256i *)v);
            }
            ws = _mm256_add_epi32(ws, wt);
            even = _mm256_add_epi64(even, _mm256_mul_epi32(wt, mv));
            odd = _mm256_add_epi64(odd, _mm256_mul_epi32(_mm256_srli_epi64(wt, 32), _mm256_srli_epi64(mv, 32)));
        }
    }
    int64_t lanes[4], vs = 0;
    _mm256_storeu_si256((__m256i *)lanes, _mm256_add_epi64(even, odd));
    for (int k = 0; k < 4; k++)
        vs += lanes[k];
    const int64_t wsum = (int64_t)hsum32(ws);
    return (int16_t)floor_div64(2 * vs + wsum, 2 * wsum);
}

/* Smallest and largest level of the stored votes of weight > 0 (a vote of weight 0 has no level). */
AVX2 static void level_bounds(const uint32_t *wb, const uint32_t *lb, int n, int *lo, int *hi)
{
    const __m256i zero = _mm256_setzero_si256();
    __m256i vmin = _mm256_set1_epi32(-1), vmax = zero;
    for (int i = 0; i < n; i++) {
        __m256i lv = _mm256_loadu_si256((const __m256i *)(lb + 8 * i));
        __m256i none = _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(wb + 8 * i)), zero);
        vmin = _mm256_min_epu32(vmin, _mm256_or_si256(lv, none));
        vmax = _mm256_max_epu32(vmax, _mm256_andnot_si256(none, lv));
    }
    *lo = (int)hext32(vmin, 0);
    *hi = (int)hext32(vmax, 1);
}

/* The weighted median at (x, y), as the scalar code defines it, in one pass
 * that computes every vote's weight once and keeps them (with their levels)
 * in the thread's window buffers.  Most pixels stop there: their own level
 * is the median.  Otherwise the median level is found by bisection on the
 * kept votes (no histogram, whose scattered read-modify-writes serialise on
 * the few levels a window holds), and one more pass over them sums the
 * values on that level. */
AVX2 static int16_t wm_pixel_avx2(const cc_wm_tables *t, const cc_wm_image *g, const int16_t *map,
                                  const uint16_t *level, int x, int y, int x0, int x1, int y0, int y1,
                                  const cc_wm_hist *h)
{
    const int w = g->width, c = level[(size_t)y * w + x];
    const uint32_t *packed = g->packed;
    const __m256i centre = _mm256_set1_epi32((int)packed[(size_t)y * w + x]);
    const __m256i vc = _mm256_set1_epi32(c), zero = _mm256_setzero_si256(), end = _mm256_set1_epi32(x1 + 1);
    const __m256i first = _mm256_add_epi32(_mm256_set1_epi32(x0), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
    __m256i tot = zero, below = zero, at = zero, lv;
    uint32_t *wb = h->win_weight, *lb = h->win_level;
    int n = 0;
    for (int yy = y0; yy <= y1; yy++) {
        const uint32_t *srow = t->space_win[yy - y + CC_MAX_WM_RADIUS] + CC_MAX_WM_RADIUS;
        const size_t r = (size_t)yy * w;
        __m256i pos = first;
        for (int xx = x0; xx <= x1; xx += 8, n++, pos = _mm256_add_epi32(pos, _mm256_set1_epi32(8))) {
            __m256i wt = chunk_weights(t, centre, packed + r, level + r, srow, xx, x, pos, end, &lv);
            _mm256_storeu_si256((__m256i *)(wb + 8 * n), wt);
            _mm256_storeu_si256((__m256i *)(lb + 8 * n), lv);
            tot = _mm256_add_epi32(tot, wt);
            below = _mm256_add_epi32(below, _mm256_and_si256(wt, _mm256_cmpgt_epi32(vc, lv)));
            at = _mm256_add_epi32(at, _mm256_and_si256(wt, _mm256_cmpeq_epi32(lv, vc)));
        }
    }
    uint64_t sums[3];
    hsum3(tot, below, at, sums);
    const uint64_t total = sums[0], lo_w = sums[1], at_w = sums[2];
    if (2 * lo_w < total && 2 * (lo_w + at_w) >= total)
        return map[(size_t)y * w + x];
    /* the first level whose cumulative weight reaches half the total: below c or above it */
    int lo, hi;
    level_bounds(wb, lb, n, &lo, &hi);
    if (2 * lo_w >= total)
        hi = c - 1;
    else
        lo = c + 1;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (2 * weight_up_to(wb, lb, n, mid) >= total)
            hi = mid;
        else
            lo = mid + 1;
    }
    return level_mean(g, map, wb, lb, lo, x0, x1, y0, y1);
}

/* ---- The planar kernel: no gather. ----
 * The colour weights of one window row (at most 31 pixels) are looked up 32 at a time in 8-bit
 * lanes from the guide's planes: the summed channel difference saturates at 255 (every weight from
 * index 16 * N - 1 on is 0, so it is clamped there) and indexes N 16-entry byte tables (pshufb).
 * colour[0] = 256 does not fit a byte: it is the byte table's 0 plus a high byte of 1.  The 16-bit
 * colour weights then multiply the row's 16-bit space weights and sum in pairs (madd: both <= 256,
 * so every product and pair sum is exact), into the window's total, the weight below the centre's
 * level and the weight on it.  The weights are the scalar code's, integer for integer. */

/* The byte permutation that makes unpacklo/unpackhi of a 32-lane vector give lanes 0..15 and 16..31. */
#define PLANAR_ORDER 0xD8

AVX2 static inline __m256i absdiff_u8(__m256i a, __m256i b)
{
    return _mm256_or_si256(_mm256_subs_epu8(a, b), _mm256_subs_epu8(b, a));
}

AVX2 static inline __m256i hsum_epi32x(__m256i v) /* the 8 lanes' sum in every lane */
{
    v = _mm256_add_epi32(v, _mm256_shuffle_epi32(v, 0x4E));
    v = _mm256_add_epi32(v, _mm256_shuffle_epi32(v, 0xB1));
    return _mm256_add_epi32(v, _mm256_permute2x128_si256(v, v, 0x01));
}

/* The 16-bit colour weights of one window row, lanes 0..15 in lo and 16..31 in hi: `cen` the centre's
 * channels, `outside` 0xFF on the lanes past the window, `inval` 0xFF where the pixel has no level. */
AVX2 static inline __attribute__((always_inline)) void planar_colour_row(
    const uint8_t *const planes[3], int channels, size_t r, const __m256i cen[3], __m256i outside, __m256i inval,
    const __m256i *tabs, int ntab, __m256i *lo, __m256i *hi)
{
    __m256i cd;
    if (channels == 3) {
        __m256i d0 = absdiff_u8(_mm256_loadu_si256((const __m256i *)(planes[0] + r)), cen[0]);
        __m256i d1 = absdiff_u8(_mm256_loadu_si256((const __m256i *)(planes[1] + r)), cen[1]);
        __m256i d2 = absdiff_u8(_mm256_loadu_si256((const __m256i *)(planes[2] + r)), cen[2]);
        cd = _mm256_adds_epu8(_mm256_adds_epu8(d0, d1), d2);
    } else { /* grey counts as three equal channels */
        __m256i d = absdiff_u8(_mm256_loadu_si256((const __m256i *)(planes[0] + r)), cen[0]);
        cd = _mm256_adds_epu8(_mm256_adds_epu8(d, d), d);
    }
    __m256i idx = _mm256_min_epu8(_mm256_or_si256(_mm256_or_si256(cd, inval), outside),
                                  _mm256_set1_epi8((char)(16 * ntab - 1)));
    idx = _mm256_permute4x64_epi64(idx, PLANAR_ORDER);
    __m256i cw = _mm256_shuffle_epi8(tabs[0], idx);
    for (int i = 1; i < ntab; i++)
        cw = _mm256_blendv_epi8(cw, _mm256_shuffle_epi8(tabs[i], idx),
                                _mm256_cmpgt_epi8(idx, _mm256_set1_epi8((char)(16 * i - 1))));
    __m256i high = _mm256_and_si256(_mm256_cmpeq_epi8(idx, _mm256_setzero_si256()), _mm256_set1_epi8(1));
    *lo = _mm256_unpacklo_epi8(cw, high);
    *hi = _mm256_unpackhi_epi8(cw, high);
}

/* Weight of the kept votes on levels <= b (the stored colour weights times the space weights). */
AVX2 static uint64_t planar_weight_up_to(const cc_wm_tables *t, const uint16_t *cwb, const uint16_t *level, int w,
                                         int x, int y, int x0, int y0, int y1, int b)
{
    const __m256i vb = _mm256_set1_epi16((short)b);
    __m256i s = _mm256_setzero_si256();
    for (int yy = y0, n = 0; yy <= y1; yy++, n += 32) {
        const uint16_t *srow = t->space_row[yy - y + CC_MAX_WM_RADIUS] + (x0 - x + CC_MAX_WM_RADIUS);
        const uint16_t *lrow = level + (size_t)yy * w + x0;
        for (int k = 0; k < 32; k += 16) {
            __m256i above = _mm256_cmpgt_epi16(_mm256_loadu_si256((const __m256i *)(lrow + k)), vb);
            __m256i cw = _mm256_andnot_si256(above, _mm256_loadu_si256((const __m256i *)(cwb + n + k)));
            s = _mm256_add_epi32(s, _mm256_madd_epi16(cw, _mm256_loadu_si256((const __m256i *)(srow + k))));
        }
    }
    return (uint32_t)_mm256_cvtsi256_si32(hsum_epi32x(s));
}

/* Smallest and largest level of the votes with a weight (the stored colour weight is not 0). */
AVX2 static void planar_level_bounds(const uint16_t *cwb, const uint16_t *level, int w, int x0, int y0, int y1,
                                     int *lo, int *hi)
{
    const __m256i zero = _mm256_setzero_si256();
    __m256i vmin = _mm256_set1_epi16(-1), vmax = zero;
    for (int yy = y0, n = 0; yy <= y1; yy++, n += 32) {
        const uint16_t *lrow = level + (size_t)yy * w + x0;
        for (int k = 0; k < 32; k += 16) {
            __m256i lv = _mm256_loadu_si256((const __m256i *)(lrow + k));
            __m256i none = _mm256_cmpeq_epi16(_mm256_loadu_si256((const __m256i *)(cwb + n + k)), zero);
            vmin = _mm256_min_epu16(vmin, _mm256_or_si256(lv, none));
            vmax = _mm256_max_epu16(vmax, _mm256_andnot_si256(none, lv));
        }
    }
    __m128i mn = _mm_min_epu16(_mm256_castsi256_si128(vmin), _mm256_extracti128_si256(vmin, 1));
    __m128i mx = _mm_max_epu16(_mm256_castsi256_si128(vmax), _mm256_extracti128_si256(vmax, 1));
    *lo = _mm_cvtsi128_si32(_mm_minpos_epu16(mn)) & 0xFFFF;
    *hi = 0xFFFF - (_mm_cvtsi128_si32(_mm_minpos_epu16(_mm_xor_si128(mx, _mm_set1_epi16(-1)))) & 0xFFFF);
}

/* The rounded weighted mean of the values of the votes on level b (b is not the centre's level, so
 * every weight there is below 2^16: a product of a colour weight <= 256 and a space weight <= 244).
 * The weights' low and high bytes multiply the int16 values apart (madd): a lane gains at most
 * 4 * 255 * 2^15 per window row, so 31 rows stay within int32; summed in int64 at the end. */
AVX2 static int16_t planar_level_mean(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m,
                                      const uint16_t *cwb, int b, int x, int y, int x0, int y0, int y1)
{
    const int w = g->width;
    const size_t end = (size_t)w * g->height;
    const __m256i vb = _mm256_set1_epi16((short)b), low = _mm256_set1_epi16(0xFF);
    __m256i ws = _mm256_setzero_si256(), plo = ws, phi = ws;
    for (int yy = y0, n = 0; yy <= y1; yy++, n += 32) {
        const uint16_t *srow = t->space_row[yy - y + CC_MAX_WM_RADIUS] + (x0 - x + CC_MAX_WM_RADIUS);
        const size_t r = (size_t)yy * w + x0;
        int16_t tail[32];
        const int16_t *vrow = m->value + r;
        if (r + 32 > end) { /* the map has no slack: the last row's window is copied */
            memset(tail, 0, sizeof tail);
            memcpy(tail, vrow, sizeof(int16_t) * (end - r));
            vrow = tail;
        }
        for (int k = 0; k < 32; k += 16) {
            __m256i on = _mm256_cmpeq_epi16(_mm256_loadu_si256((const __m256i *)(m->level + r + k)), vb);
            __m256i cw = _mm256_and_si256(on, _mm256_loadu_si256((const __m256i *)(cwb + n + k)));
            __m256i sw = _mm256_loadu_si256((const __m256i *)(srow + k));
            __m256i u = _mm256_mullo_epi16(cw, sw); /* < 2^16 on level b: exact */
            __m256i v = _mm256_loadu_si256((const __m256i *)(vrow + k));
            ws = _mm256_add_epi32(ws, _mm256_madd_epi16(cw, sw));
            plo = _mm256_add_epi32(plo, _mm256_madd_epi16(_mm256_and_si256(u, low), v));
            phi = _mm256_add_epi32(phi, _mm256_madd_epi16(_mm256_srli_epi16(u, 8), v));
        }
    }
    int32_t l8[8], h8[8];
    _mm256_storeu_si256((__m256i *)l8, plo);
    _mm256_storeu_si256((__m256i *)h8, phi);
    int64_t vs = 0;
    for (int k = 0; k < 8; k++)
        vs += l8[k] + 256 * (int64_t)h8[k];
    const int64_t wsum = (uint32_t)_mm256_cvtsi256_si32(hsum_epi32x(ws));
    return (int16_t)floor_div64(2 * vs + wsum, 2 * wsum);
}

/* Weight of the kept votes below level b and on it (one pass over the stored colour weights). */
AVX2 static void planar_split(const cc_wm_tables *t, const uint16_t *cwb, const uint16_t *level, int w, int x, int y,
                              int x0, int y0, int y1, int b, uint64_t *below, uint64_t *at)
{
    const __m256i vb = _mm256_set1_epi16((short)b);
    __m256i sb = _mm256_setzero_si256(), sa = sb;
    for (int yy = y0, n = 0; yy <= y1; yy++, n += 32) {
        const uint16_t *srow = t->space_row[yy - y + CC_MAX_WM_RADIUS] + (x0 - x + CC_MAX_WM_RADIUS);
        const uint16_t *lrow = level + (size_t)yy * w + x0;
        for (int k = 0; k < 32; k += 16) {
            __m256i lv = _mm256_loadu_si256((const __m256i *)(lrow + k));
            __m256i cw = _mm256_loadu_si256((const __m256i *)(cwb + n + k));
            __m256i sw = _mm256_loadu_si256((const __m256i *)(srow + k));
            sb = _mm256_add_epi32(sb, _mm256_madd_epi16(_mm256_and_si256(cw, _mm256_cmpgt_epi16(vb, lv)), sw));
            sa = _mm256_add_epi32(sa, _mm256_madd_epi16(_mm256_and_si256(cw, _mm256_cmpeq_epi16(vb, lv)), sw));
        }
    }
    *below = (uint32_t)_mm256_cvtsi256_si32(hsum_epi32x(sb));
    *at = (uint32_t)_mm256_cvtsi256_si32(hsum_epi32x(sa));
}

/* The weighted median at (x, y) with ntab colour tables and `channels` guide planes (constants at
 * each call: one tight instance per case). */
AVX2 static inline __attribute__((always_inline)) int16_t wm_pixel_planar_n(
    const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int x, int y, int x0, int x1, int y0, int y1,
    cc_wm_hist *h, int ntab, int channels)
{
    const int w = g->width;
    const size_t o = (size_t)y * w + x;
    const int c = m->level[o];
    __m256i tabs[8], cen[3];
    for (int i = 0; i < ntab; i++)
        tabs[i] = _mm256_broadcastsi128_si256(_mm_loadu_si128((const __m128i *)(t->colour_bytes + 16 * i)));
    for (int i = 0; i < channels; i++)
        cen[i] = _mm256_set1_epi8((char)g->planes[i][o]);
    const __m256i lanes = _mm256_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20,
                                           21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31);
    const __m256i outside = _mm256_cmpgt_epi8(lanes, _mm256_set1_epi8((char)(x1 - x0)));
    const __m256i vc = _mm256_set1_epi16((short)c);
    __m256i tot = _mm256_setzero_si256(), below = tot, at = tot;
    uint16_t *cwb = (uint16_t *)h->win_weight;
    for (int yy = y0, n = 0; yy <= y1; yy++, n += 32) {
        const size_t r = (size_t)yy * w + x0;
        const uint16_t *srow = t->space_row[yy - y + CC_MAX_WM_RADIUS] + (x0 - x + CC_MAX_WM_RADIUS);
        __m256i cw[2];
        planar_colour_row(g->planes, channels, r, cen, outside,
                          _mm256_loadu_si256((const __m256i *)(m->invalid + r)), tabs, ntab, &cw[0], &cw[1]);
        for (int k = 0; k < 2; k++) {
            __m256i lv = _mm256_loadu_si256((const __m256i *)(m->level + r + 16 * k));
            __m256i sw = _mm256_loadu_si256((const __m256i *)(srow + 16 * k));
            _mm256_storeu_si256((__m256i *)(cwb + n + 16 * k), cw[k]);
            tot = _mm256_add_epi32(tot, _mm256_madd_epi16(cw[k], sw));
            below = _mm256_add_epi32(below, _mm256_madd_epi16(_mm256_and_si256(cw[k], _mm256_cmpgt_epi16(vc, lv)), sw));
            at = _mm256_add_epi32(at, _mm256_madd_epi16(_mm256_and_si256(cw[k], _mm256_cmpeq_epi16(vc, lv)), sw));
        }
    }
    uint64_t sums[3];
    hsum3(tot, below, at, sums);
    const uint64_t total = sums[0], lo_w = sums[1], at_w = sums[2];
    if (2 * lo_w < total && 2 * (lo_w + at_w) >= total) {
        h->guess = c;
        return m->value[o];
    }
    /* the first level whose cumulative weight reaches half the total: below c or above it */
    const int below_c = 2 * lo_w >= total; /* the median is below c, else above */
    int lo = below_c ? 0 : c + 1, hi = below_c ? c - 1 : CC_WM_NO_LEVEL - 1;
    /* the guess (usually the median level of the pixel before, often this one's): one pass to test it */
    const int guess = h->guess;
    if (guess >= lo && guess <= hi) {
        uint64_t below_g, at_g;
        planar_split(t, cwb, m->level, w, x, y, x0, y0, y1, guess, &below_g, &at_g);
        if (2 * below_g < total && 2 * (below_g + at_g) >= total)
            return planar_level_mean(t, g, m, cwb, guess, x, y, x0, y0, y1); /* h->guess stays */
        if (2 * below_g >= total)
            hi = guess - 1;
        else
            lo = guess + 1;
    }
    /* narrowed to the levels the window holds */
    int lv_lo, lv_hi;
    planar_level_bounds(cwb, m->level, w, x0, y0, y1, &lv_lo, &lv_hi);
    lo = lo > lv_lo ? lo : lv_lo;
    hi = hi < lv_hi ? hi : lv_hi;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (2 * planar_weight_up_to(t, cwb, m->level, w, x, y, x0, y0, y1, mid) >= total)
            hi = mid;
        else
            lo = mid + 1;
    }
    h->guess = lo;
    return planar_level_mean(t, g, m, cwb, lo, x, y, x0, y0, y1);
}

AVX2 static int16_t wm_pixel_planar(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int x, int y,
                                    int x0, int x1, int y0, int y1, cc_wm_hist *h)
{
    if (t->colour_tables <= 5)
        return g->channels == 3 ? wm_pixel_planar_n(t, g, m, x, y, x0, x1, y0, y1, h, 5, 3)
                                : wm_pixel_planar_n(t, g, m, x, y, x0, x1, y0, y1, h, 5, 1);
    return g->channels == 3 ? wm_pixel_planar_n(t, g, m, x, y, x0, x1, y0, y1, h, 8, 3)
                            : wm_pixel_planar_n(t, g, m, x, y, x0, x1, y0, y1, h, 8, 1);
}

/* ---- Whole rows: 32 centres at a time (the final weighted median, every pixel). ----
 * For each offset (dy, dx) of the window, the colour weights of the 32 centres' neighbours are one
 * byte lookup (planar_colour_row's, with the centres' own colours per lane); then, per centre, only
 * whether its own level is the median is decided, from two signed sums: S1 = 2 * below - total
 * (< 0) and S2 = 2 * (below + at) - total (>= 0).  A vote adds +-colour * space to each, two offsets
 * per madd (their signed colour weights interleaved, their space weights a constant pair).  A centre
 * whose level is not the median (about one in ten) gets the per-pixel kernel's search. */
#define BLOCK 32
#define BLOCK_OFFSETS 32 /* offsets whose colour weights are held at once (2 KiB) */
_Static_assert(BLOCK_OFFSETS * BLOCK * sizeof(uint16_t) <= CC_WM_CHUNKS * 8 * sizeof(uint32_t),
               "the row kernel's colour weights fit the thread's win_level buffer");
_Static_assert(CC_WM_SIDE * 32 * sizeof(uint16_t) <= CC_WM_CHUNKS * 8 * sizeof(uint32_t),
               "the planar kernel's colour weights fit the thread's win_weight buffer");

typedef struct wm_offset {
    int dy, dx, sw;
} wm_offset;

/* The signed weights of one offset pair for 16 centres into the S1/S2 accumulators (a: centres
 * 0-3 and 8-11 of the 16, b: 4-7 and 12-15, the order of unpacklo/unpackhi). */
AVX2 static inline void block_pair(__m256i cwa, __m256i cwb, __m256i lva, __m256i lvb, __m256i vc, __m256i vcm1,
                                   __m256i pair_sw, __m256i acc[4])
{
    __m256i nba = _mm256_cmpgt_epi16(lva, vcm1), nbb = _mm256_cmpgt_epi16(lvb, vcm1); /* not below */
    __m256i aba = _mm256_cmpgt_epi16(lva, vc), abb = _mm256_cmpgt_epi16(lvb, vc);     /* above */
    __m256i s1a = _mm256_sub_epi16(_mm256_xor_si256(cwa, nba), nba);
    __m256i s1b = _mm256_sub_epi16(_mm256_xor_si256(cwb, nbb), nbb);
    __m256i s2a = _mm256_sub_epi16(_mm256_xor_si256(cwa, aba), aba);
    __m256i s2b = _mm256_sub_epi16(_mm256_xor_si256(cwb, abb), abb);
    acc[0] = _mm256_add_epi32(acc[0], _mm256_madd_epi16(_mm256_unpacklo_epi16(s1a, s1b), pair_sw));
    acc[1] = _mm256_add_epi32(acc[1], _mm256_madd_epi16(_mm256_unpackhi_epi16(s1a, s1b), pair_sw));
    acc[2] = _mm256_add_epi32(acc[2], _mm256_madd_epi16(_mm256_unpacklo_epi16(s2a, s2b), pair_sw));
    acc[3] = _mm256_add_epi32(acc[3], _mm256_madd_epi16(_mm256_unpackhi_epi16(s2a, s2b), pair_sw));
}

/* S1 and S2 (without the centre's own vote) of the 32 centres x..x+31 of row y into s1[32], s2[32];
 * every neighbour column is inside the image (rows outside have space weight 0). */
AVX2 static inline __attribute__((always_inline)) void block_sums(
    const cc_wm_image *g, const cc_wm_map *m, const wm_offset *off, int noff, int x, int y, uint16_t *buf,
    const __m256i *tabs, int ntab, int channels, int32_t s1[BLOCK], int32_t s2[BLOCK])
{
    const int w = g->width, hgt = g->height;
    const size_t o = (size_t)y * w + x;
    __m256i cen[3];
    for (int i = 0; i < channels; i++)
        cen[i] = _mm256_loadu_si256((const __m256i *)(g->planes[i] + o));
    __m256i acc[2][4];
    for (int hf = 0; hf < 2; hf++)
        for (int k = 0; k < 4; k++)
            acc[hf][k] = _mm256_setzero_si256();
    const __m256i one = _mm256_set1_epi16(1);
    for (int first = 0; first < noff; first += BLOCK_OFFSETS) {
        const int count = noff - first < BLOCK_OFFSETS ? noff - first : BLOCK_OFFSETS;
        for (int i = 0; i < count; i++) {
            const wm_offset *q = off + first + i;
            int yy = y + q->dy;
            yy = yy < 0 ? 0 : (yy >= hgt ? hgt - 1 : yy); /* rows outside: weight 0 below */
            const size_t r = (size_t)yy * w + x + q->dx;
            __m256i lo, hi;
            planar_colour_row(g->planes, channels, r, cen, _mm256_setzero_si256(),
                              _mm256_loadu_si256((const __m256i *)(m->invalid + r)), tabs, ntab, &lo, &hi);
            _mm256_storeu_si256((__m256i *)(buf + 32 * i), lo);
            _mm256_storeu_si256((__m256i *)(buf + 32 * i + 16), hi);
        }
        for (int hf = 0; hf < 2; hf++) {
            const __m256i vc = _mm256_loadu_si256((const __m256i *)(m->level + o + 16 * hf));
            const __m256i vcm1 = _mm256_sub_epi16(vc, one);
            for (int i = 0; i < count; i += 2) { /* noff and BLOCK_OFFSETS are even */
                const wm_offset *qa = off + first + i, *qb = qa + 1;
                int ya = y + qa->dy, yb = y + qb->dy;
                int swa = ya >= 0 && ya < hgt ? qa->sw : 0, swb = yb >= 0 && yb < hgt ? qb->sw : 0;
                ya = ya < 0 ? 0 : (ya >= hgt ? hgt - 1 : ya);
                yb = yb < 0 ? 0 : (yb >= hgt ? hgt - 1 : yb);
                const __m256i pair_sw = _mm256_set1_epi32(swa | swb << 16);
                __m256i cwa = _mm256_loadu_si256((const __m256i *)(buf + 32 * i + 16 * hf));
                __m256i cwb = _mm256_loadu_si256((const __m256i *)(buf + 32 * (i + 1) + 16 * hf));
                __m256i lva = _mm256_loadu_si256((const __m256i *)(m->level + (size_t)ya * w + x + qa->dx + 16 * hf));
                __m256i lvb = _mm256_loadu_si256((const __m256i *)(m->level + (size_t)yb * w + x + qb->dx + 16 * hf));
                block_pair(cwa, cwb, lva, lvb, vc, vcm1, pair_sw, acc[hf]);
            }
        }
    }
    /* lanes back to centres: acc[.][0] holds centres 0-3 (low half) and 8-11 (high half), [1] 4-7 and 12-15 */
    for (int hf = 0; hf < 2; hf++) {
        int32_t v[4][8];
        for (int k = 0; k < 4; k++)
            _mm256_storeu_si256((__m256i *)v[k], acc[hf][k]);
        for (int j = 0; j < 4; j++) {
            const int c0 = 16 * hf + j;
            s1[c0] = v[0][j];
            s1[c0 + 8] = v[0][4 + j];
            s1[c0 + 4] = v[1][j];
            s1[c0 + 12] = v[1][4 + j];
            s2[c0] = v[2][j];
            s2[c0 + 8] = v[2][4 + j];
            s2[c0 + 4] = v[3][j];
            s2[c0 + 12] = v[3][4 + j];
        }
    }
}

AVX2 static inline __attribute__((always_inline)) void wm_row_blocks_n(
    const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int y, int radius, cc_wm_hist *h, int16_t *out,
    const wm_offset *off, int noff, int ntab, int channels)
{
    const int w = g->width, hgt = g->height;
    __m256i tabs[8];
    for (int i = 0; i < ntab; i++)
        tabs[i] = _mm256_broadcastsi128_si256(_mm_loadu_si128((const __m128i *)(t->colour_bytes + 16 * i)));
    uint16_t *buf = (uint16_t *)h->win_level;
    const int last = w - radius - BLOCK; /* the last block's first centre: every column inside */
    for (int bx = radius;; bx += BLOCK) {
        const int x = bx < last ? bx : last;
        /* every window of the block on one level (a run through all its rows): the centres keep their values */
        if (m->run) {
            const int y0 = y - radius < 0 ? 0 : y - radius, y1 = y + radius >= hgt ? hgt - 1 : y + radius;
            const int c = m->level[(size_t)y * w + x];
            int flat = c != CC_WM_NO_LEVEL;
            for (int yy = y0; flat && yy <= y1; yy++) {
                const size_t q = (size_t)yy * w + x - radius;
                flat = m->level[q] == c && m->run[q] >= BLOCK + 2 * radius;
            }
            if (flat) {
                memcpy(out + x, m->value + (size_t)y * w + x, sizeof(int16_t) * BLOCK);
                h->guess = c;
                if (x == last)
                    break;
                continue;
            }
        }
        int32_t s1[BLOCK], s2[BLOCK];
        block_sums(g, m, off, noff, x, y, buf, tabs, ntab, channels, s1, s2);
        for (int j = 0; j < BLOCK; j++) {
            const size_t o = (size_t)y * w + x + j;
            const int c = m->level[o];
            /* the centre's own vote: on its level, weight 256 * 256 */
            if (c == CC_WM_NO_LEVEL) {
                out[x + j] = CC_INVALID;
                h->guess = -1;
            } else if (s1[j] - 65536 < 0 && s2[j] + 65536 >= 0) {
                out[x + j] = m->value[o];
                h->guess = c;
            } else {
                int y0 = y - radius < 0 ? 0 : y - radius, y1 = y + radius >= hgt ? hgt - 1 : y + radius;
                out[x + j] = wm_pixel_planar(t, g, m, x + j, y, x + j - radius, x + j + radius, y0, y1, h);
            }
        }
        if (x == last)
            break;
    }
}


AVX2 static void wm_row_blocks(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int y, int radius,
                               cc_wm_hist *h, int16_t *out, const wm_offset *off, int noff)
{
    if (t->colour_tables <= 5) {
        if (g->channels == 3)
            wm_row_blocks_n(t, g, m, y, radius, h, out, off, noff, 5, 3);
        else
            wm_row_blocks_n(t, g, m, y, radius, h, out, off, noff, 5, 1);
    } else if (g->channels == 3)
        wm_row_blocks_n(t, g, m, y, radius, h, out, off, noff, 8, 3);
    else
        wm_row_blocks_n(t, g, m, y, radius, h, out, off, noff, 8, 1);
}
#endif

/* Whether the centre's own level c is the weighted median (the first level
 * whose cumulative weight reaches half the total).  Most pixels are: then the
 * output is the centre's value and no histogram is needed. */
static int centre_is_median(const cc_wm_tables *t, const cc_wm_image *g, const uint16_t *level,
                            const uint8_t *gc, int x, int y, int x0, int x1, int y0, int y1, int c)
{
    const int w = g->width, ch = g->channels;
    uint64_t total = 0, below = 0, at = 0;
    for (int yy = y0; yy <= y1; yy++) {
        const uint8_t *grow = g->data + (size_t)yy * g->stride;
        const uint16_t *lrow = level + (size_t)yy * w;
        const int dy2 = (yy - y) * (yy - y);
        total += ch == 3 ? split_row(t, gc, grow, lrow, x0, x1, x, dy2, 3, c, &below, &at)
                         : split_row(t, gc, grow, lrow, x0, x1, x, dy2, 1, c, &below, &at);
    }
    return 2 * below < total && 2 * (below + at) >= total;
}

/* noinline: the dispatcher below stays small for the vector kernel. */
__attribute__((noinline)) static int16_t wm_pixel_scalar(const cc_wm_tables *t, const cc_wm_image *g,
                                                         const int16_t *map, const uint16_t *level, int x, int y,
                                                         int x0, int x1, int y0, int y1, cc_wm_hist *h)
{
    const int w = g->width, ch = g->channels;
    const size_t o = (size_t)y * w + x;
    const uint8_t *gc = g->data + (size_t)y * g->stride + (size_t)x * ch;
    if (centre_is_median(t, g, level, gc, x, y, x0, x1, y0, y1, level[o]))
        return map[o];
    int lo = INT32_MAX, hi = -1;
    uint64_t total = 0;
    for (int yy = y0; yy <= y1; yy++) {
        const size_t r = (size_t)yy * w;
        const uint8_t *grow = g->data + (size_t)yy * g->stride;
        const int dy2 = (yy - y) * (yy - y);
        if (ch == 3)
            total += vote_row(t, gc, grow, map + r, level + r, x0, x1, x, dy2, 3, h, &lo, &hi);
        else
            total += vote_row(t, gc, grow, map + r, level + r, x0, x1, x, dy2, 1, h, &lo, &hi);
    }
    /* The centre votes for itself with weight 256 * 256, so total > 0. */
    int b = lo;
    uint64_t acc = 0;
    for (; b <= hi; b++) {
        acc += h->weight[b];
        if (2 * acc >= total)
            break;
    }
    int16_t out = map[o];
    if (level[o] != b) {
        int64_t ws = h->weight[b];
        out = (int16_t)floor_div64(2 * h->value[b] + ws, 2 * ws);
    }
    memset(h->weight + lo, 0, sizeof(uint32_t) * (size_t)(hi - lo + 1));
    memset(h->value + lo, 0, sizeof(int64_t) * (size_t)(hi - lo + 1));
    return out;
}

/* Whether every pixel of the window has level c: then all the weight is on c and the centre is the
 * median, whatever the weights. */
static int window_on_level(const uint16_t *level, const uint16_t *run, int w, int c, int x0, int x1, int y0, int y1)
{
    for (int yy = y0; yy <= y1; yy++) {
        const size_t q = (size_t)yy * w + x0;
        if (level[q] != c || run[q] <= x1 - x0)
            return 0;
    }
    return 1;
}

int16_t cc_wm_pixel(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int x, int y, int radius,
                    cc_wm_hist *h)
{
    const int w = g->width, hgt = g->height, c = m->level[(size_t)y * w + x];
    if (c == CC_WM_NO_LEVEL)
        return CC_INVALID;
    int y0 = y - radius < 0 ? 0 : y - radius, y1 = y + radius >= hgt ? hgt - 1 : y + radius;
    int x0 = x - radius < 0 ? 0 : x - radius, x1 = x + radius >= w ? w - 1 : x + radius;
    if (m->run && window_on_level(m->level, m->run, w, c, x0, x1, y0, y1))
        return m->value[(size_t)y * w + x];
#if CC_HAVE_X86
    if (g->use_avx2 && g->planes[0] && m->invalid)
        return wm_pixel_planar(t, g, m, x, y, x0, x1, y0, y1, h);
    if (g->use_avx2 && g->packed)
        return wm_pixel_avx2(t, g, m->value, m->level, x, y, x0, x1, y0, y1, h);
#endif
    return wm_pixel_scalar(t, g, m->value, m->level, x, y, x0, x1, y0, y1, h);
}

void cc_wm_row(const cc_wm_tables *t, const cc_wm_image *g, const cc_wm_map *m, int y, int radius, cc_wm_hist *h,
               int16_t *out)
{
    const int w = g->width;
    int done_from = w, done_to = w; /* centres [done_from, done_to) computed by the blocks */
    h->guess = -1;
#if CC_HAVE_X86
    if (g->use_avx2 && g->planes[0] && m->invalid && radius > 0 && w - 2 * radius >= BLOCK) {
        wm_offset off[CC_WM_SIDE * CC_WM_SIDE];
        int noff = 0;
        for (int dy = -radius; dy <= radius; dy++)
            for (int dx = -radius; dx <= radius; dx++)
                if (dy || dx)
                    off[noff++] = (wm_offset){dy, dx, t->space[dy * dy + dx * dx]};
        wm_row_blocks(t, g, m, y, radius, h, out, off, noff);
        done_from = radius;
        done_to = w - radius;
    }
#endif
    for (int x = 0; x < w; x++)
        if (x < done_from || x >= done_to)
            out[x] = cc_wm_pixel(t, g, m, x, y, radius, h);
}
