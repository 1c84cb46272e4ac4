/* Winner-takes-all on an aggregated row: the left view with parabola
 * sub-pixel refinement and the uniqueness check (as OpenCV's StereoSGBM), and
 * the right view from the same volume, right pixel xr taking the best of
 * S(xr + d, d). */
#include "select.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

static int argmin_scalar(const uint16_t *c, int from, int D, unsigned best, int at)
{
    for (int k = from; k < D; k++)
        if (c[k] < best) {
            best = c[k];
            at = k;
        }
    return at;
}

#if CC_HAVE_X86
/* First index of the smallest value; real costs stay below 0x8000. */
__attribute__((target("avx2"))) static int argmin_avx2(const uint16_t *c, int D)
{
    int full = D / CC_LANES * CC_LANES;
    if (full == 0)
        return argmin_scalar(c, 0, D, 0x10000u, 0);
    __m256i m = _mm256_loadu_si256((const __m256i *)c);
    for (int k = CC_LANES; k < full; k += CC_LANES)
        m = _mm256_min_epu16(m, _mm256_loadu_si256((const __m256i *)(c + k)));
    __m128i h = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    unsigned best = (unsigned)_mm_cvtsi128_si32(_mm_minpos_epu16(h)) & 0xFFFFu;
    __m256i vb = _mm256_set1_epi16((short)best);
    int at = 0;
    for (int k = 0; k < full; k += CC_LANES) {
        unsigned mask = (unsigned)_mm256_movemask_epi8(
            _mm256_cmpeq_epi16(vb, _mm256_loadu_si256((const __m256i *)(c + k))));
        if (mask) {
            at = k + __builtin_ctz(mask) / 2;
            break;
        }
    }
    return argmin_scalar(c, full, D, best, at);
}
#endif

#if CC_HAVE_X86
/* The left view's choice at one pixel when D is NV full vectors (NV a constant at each call): the
 * costs are loaded once and kept; the argmin (first index of the smallest) and, for the uniqueness
 * check, the smallest cost more than one level away from it come from the same registers. */
__attribute__((target("avx2"))) static inline __attribute__((always_inline)) int select_pixel_avx2(
    const uint16_t *c, int nv, unsigned *second)
{
    __m256i v[CC_MAX_DISPARITIES / CC_LANES];
    v[0] = _mm256_loadu_si256((const __m256i *)c);
    __m256i m = v[0];
    for (int j = 1; j < nv; j++) {
        v[j] = _mm256_loadu_si256((const __m256i *)(c + CC_LANES * j));
        m = _mm256_min_epu16(m, v[j]);
    }
    __m128i h = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    const __m256i vb = _mm256_set1_epi16((short)_mm_cvtsi128_si32(_mm_minpos_epu16(h)));
    int k = 0;
    for (int j = 0; j < nv; j++) {
        unsigned mask = (unsigned)_mm256_movemask_epi8(_mm256_cmpeq_epi16(vb, v[j]));
        if (mask) {
            k = CC_LANES * j + __builtin_ctz(mask) / 2;
            break;
        }
    }
    if (second) {
        const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        const __m256i two = _mm256_set1_epi16(2);
        __m256i m2 = _mm256_set1_epi16(-1);
        for (int j = 0; j < nv; j++) {
            /* lanes k-1..k+1 are masked: (lane + 16 j - (k - 1)) as unsigned <= 2 */
            __m256i rel = _mm256_add_epi16(lane, _mm256_set1_epi16((short)(CC_LANES * j - k + 1)));
            __m256i near = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, two), rel);
            m2 = _mm256_min_epu16(m2, _mm256_or_si256(v[j], near));
        }
        __m128i h2 = _mm_min_epu16(_mm256_castsi256_si128(m2), _mm256_extracti128_si256(m2, 1));
        *second = (unsigned)_mm_cvtsi128_si32(_mm_minpos_epu16(h2)) & 0xFFFFu;
    }
    return k;
}
#endif

/* Smallest cost more than one level away from k (0xFFFF if there is none). */
static unsigned second_min_scalar(const uint16_t *c, int from, int D, int k, unsigned best)
{
    for (int j = from; j < D; j++)
        if ((j < k - 1 || j > k + 1) && c[j] < best)
            best = c[j];
    return best;
}

#if CC_HAVE_X86
__attribute__((target("avx2"))) static unsigned second_min_avx2(const uint16_t *c, int D, int k)
{
    const int full = D / CC_LANES * CC_LANES;
    const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    __m256i m = _mm256_set1_epi16(-1);
    for (int j = 0; j < full; j += CC_LANES) {
        /* lanes k-1..k+1 are masked: (lane + j - (k - 1)) as unsigned <= 2 */
        __m256i rel = _mm256_add_epi16(lane, _mm256_set1_epi16((short)(j - k + 1)));
        __m256i near = _mm256_cmpeq_epi16(_mm256_min_epu16(rel, _mm256_set1_epi16(2)), rel);
        m = _mm256_min_epu16(m, _mm256_or_si256(_mm256_loadu_si256((const __m256i *)(c + j)), near));
    }
    __m128i h = _mm_min_epu16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    unsigned best = (unsigned)_mm_cvtsi128_si32(_mm_minpos_epu16(h)) & 0xFFFFu;
    return second_min_scalar(c, full, D, k, best);
}
#endif

static inline unsigned second_min(const cc_setup *s, const uint16_t *c, int k)
{
#if CC_HAVE_X86
    if (s->use_avx2)
        return second_min_avx2(c, s->D, k);
#endif
    return second_min_scalar(c, 0, s->D, k, 0xFFFFu);
}

static inline int argmin(const cc_setup *s, const uint16_t *c)
{
#if CC_HAVE_X86
    if (s->use_avx2)
        return argmin_avx2(c, s->D);
#endif
    return argmin_scalar(c, 0, s->D, 0x10000u, 0);
}

size_t cc_select_tmp_bytes(const cc_setup *s, int width)
{
    int dmin = s->p.min_disparity;
    return ((size_t)width + (size_t)(dmin < 0 ? -dmin : dmin) + (size_t)s->D + 64) * 2 * sizeof(uint16_t);
}

/* Right view: the best of S(xr + d, d).  Kept in mirrored order, slot
 * off + (width-1-xr), so the candidates of one left pixel x for consecutive d
 * fill consecutive slots.  Candidates for xr arrive with increasing d (outer
 * loop over x), so a strict comparison keeps the smallest d among equal costs. */
static void right_view_scalar(const cc_setup *s, const uint16_t *row, int stride, int width,
                              uint16_t *best, int16_t *disp, int off)
{
    const int dmin = s->p.min_disparity;
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int base = off + width - 1 - x + dmin;
        for (int k = 0; k < s->D; k++)
            if (c[k] < best[base + k]) {
                best[base + k] = c[k];
                disp[base + k] = (int16_t)((dmin + k) * CC_DISP_SCALE);
            }
    }
}

#if CC_HAVE_X86
__attribute__((target("avx2"))) static void right_view_avx2(const cc_setup *s, const uint16_t *row, int stride,
                                                           int width, uint16_t *best, int16_t *disp, int off)
{
    const int dmin = s->p.min_disparity, full = s->D / CC_LANES * CC_LANES;
    const __m256i lane16 = _mm256_setr_epi16(0, 16, 32, 48, 64, 80, 96, 112, 128, 144, 160, 176, 192, 208, 224, 240);
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int base = off + width - 1 - x + dmin;
        for (int k = 0; k < full; k += CC_LANES) {
            __m256i v = _mm256_loadu_si256((const __m256i *)(c + k));
            __m256i b = _mm256_loadu_si256((const __m256i *)(best + base + k));
            __m256i d = _mm256_loadu_si256((const __m256i *)(disp + base + k));
            /* v < b (unsigned) exactly when min(v, b) != b: then the slot takes v and this disparity */
            __m256i m = _mm256_min_epu16(v, b);
            __m256i dk = _mm256_add_epi16(_mm256_set1_epi16((short)((dmin + k) * CC_DISP_SCALE)), lane16);
            _mm256_storeu_si256((__m256i *)(best + base + k), m);
            _mm256_storeu_si256((__m256i *)(disp + base + k), _mm256_blendv_epi8(dk, d, _mm256_cmpeq_epi16(m, b)));
        }
        /* the remaining disparities of this pixel, in the same order as the scalar loop */
        for (int k = full; k < s->D; k++)
            if (c[k] < best[base + k]) {
                best[base + k] = c[k];
                disp[base + k] = (int16_t)((dmin + k) * CC_DISP_SCALE);
            }
    }
}
#endif

/* The left view's disparity at one pixel from its costs c (k and the uniqueness test given). */
static inline int16_t left_disparity(const cc_setup *s, const uint16_t *c, int k, unsigned second)
{
    const int D = s->D;
    if (s->p.uniqueness && (int64_t)second * (100 - s->p.uniqueness) < (int64_t)c[k] * 100)
        return CC_INVALID; /* not unique: a cost more than one level away comes within the margin */
    int d = (s->p.min_disparity + k) * CC_DISP_SCALE;
    if (s->p.subpixel && k > 0 && k < D - 1) {
        int a = c[k - 1], b = c[k + 1];
        int denom2 = a + b - 2 * (int)c[k];
        denom2 = denom2 > 1 ? denom2 : 1;
        d += ((a - b) * CC_DISP_SCALE + denom2) / (denom2 * 2);
    }
    return (int16_t)d;
}

#if CC_HAVE_X86
/* The left view of a row with D = NV full vectors, NV a constant (one instance each). */
#define SELECT_LEFT_NV(nv)                                                                                    \
    __attribute__((target("avx2"))) static void select_left_##nv(const cc_setup *s, const uint16_t *row,    \
                                                                 int stride, int width, int16_t *out)       \
    {                                                                                                         \
        const int unique = s->p.uniqueness > 0;                                                               \
        for (int x = 0; x < width; x++) {                                                                     \
            const uint16_t *c = row + (size_t)x * stride;                                                     \
            unsigned second = 0xFFFFu;                                                                        \
            int k = select_pixel_avx2(c, nv, unique ? &second : NULL);                                        \
            out[x] = left_disparity(s, c, k, second);                                                         \
        }                                                                                                     \
    }
SELECT_LEFT_NV(1)
SELECT_LEFT_NV(2)
SELECT_LEFT_NV(3)
SELECT_LEFT_NV(4)
SELECT_LEFT_NV(5)
SELECT_LEFT_NV(6)
SELECT_LEFT_NV(7)
SELECT_LEFT_NV(8)
SELECT_LEFT_NV(9)
SELECT_LEFT_NV(10)
SELECT_LEFT_NV(11)
SELECT_LEFT_NV(12)
#define SELECT_MAX_NV 12
static void (*const select_left_by_nv[SELECT_MAX_NV])(const cc_setup *, const uint16_t *, int, int, int16_t *) = {
    select_left_1, select_left_2, select_left_3, select_left_4, select_left_5,  select_left_6,
    select_left_7, select_left_8, select_left_9, select_left_10, select_left_11, select_left_12};
#endif

void cc_select_row(const cc_setup *s, const uint16_t *row, int stride, int width,
                   int16_t *left_out, int16_t *right_out, uint16_t *tmp)
{
    const int D = s->D, dmin = s->p.min_disparity;
#if CC_HAVE_X86
    if (s->use_avx2 && D % CC_LANES == 0 && D / CC_LANES <= SELECT_MAX_NV)
        select_left_by_nv[D / CC_LANES - 1](s, row, stride, width, left_out);
    else
#endif
        for (int x = 0; x < width; x++) {
            const uint16_t *c = row + (size_t)x * stride;
            int k = argmin(s, c);
            left_out[x] = left_disparity(s, c, k, s->p.uniqueness ? second_min(s, c, k) : 0xFFFFu);
        }
    /* Mirrored scratch: slots for every x - d, in or out of the image. */
    const int off = (dmin < 0 ? -dmin : 0) + 16;
    const size_t slots = cc_select_tmp_bytes(s, width) / (2 * sizeof(uint16_t));
    uint16_t *best = tmp;
    int16_t *disp = (int16_t *)(tmp + slots);
    for (size_t i = 0; i < slots; i++) {
        best[i] = 0xFFFFu;
        disp[i] = CC_INVALID;
    }
#if CC_HAVE_X86
    if (s->use_avx2)
        right_view_avx2(s, row, stride, width, best, disp, off);
    else
#endif
        right_view_scalar(s, row, stride, width, best, disp, off);
    for (int xr = 0; xr < width; xr++)
        right_out[xr] = disp[off + width - 1 - xr];
}
