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
    const __m256i ones = _mm256_set1_epi16(-1);
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int base = off + width - 1 - x + dmin;
        for (int k = 0; k < full; k += CC_LANES) {
            __m256i v = _mm256_loadu_si256((const __m256i *)(c + k));
            __m256i b = _mm256_loadu_si256((const __m256i *)(best + base + k));
            __m256i d = _mm256_loadu_si256((const __m256i *)(disp + base + k));
            /* v < b (unsigned) exactly when min(v, b) != b */
            __m256i lt = _mm256_xor_si256(_mm256_cmpeq_epi16(_mm256_min_epu16(v, b), b), ones);
            __m256i dk = _mm256_add_epi16(_mm256_set1_epi16((short)((dmin + k) * CC_DISP_SCALE)), lane16);
            _mm256_storeu_si256((__m256i *)(best + base + k), _mm256_blendv_epi8(b, v, lt));
            _mm256_storeu_si256((__m256i *)(disp + base + k), _mm256_blendv_epi8(d, dk, lt));
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

void cc_select_row(const cc_setup *s, const uint16_t *row, int stride, int width,
                   int16_t *left_out, int16_t *right_out, uint16_t *tmp)
{
    const int D = s->D, dmin = s->p.min_disparity;
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int k = argmin(s, c);
        /* Not unique: a cost more than one level away comes within the margin of the best. */
        if (s->p.uniqueness && (int64_t)second_min(s, c, k) * (100 - s->p.uniqueness) < (int64_t)c[k] * 100) {
            left_out[x] = CC_INVALID;
            continue;
        }
        int d = (dmin + k) * CC_DISP_SCALE;
        if (s->p.subpixel && k > 0 && k < D - 1) {
            int a = c[k - 1], b = c[k + 1];
            int denom2 = a + b - 2 * (int)c[k];
            denom2 = denom2 > 1 ? denom2 : 1;
            d += ((a - b) * CC_DISP_SCALE + denom2) / (denom2 * 2);
        }
        left_out[x] = (int16_t)d;
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
