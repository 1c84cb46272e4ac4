/* Winner-takes-all on an aggregated row: the left view with parabola
 * sub-pixel refinement (as OpenCV's StereoSGBM), and the right view from the
 * same volume, right pixel xr taking the best of S(xr + d, d). */
#include "internal.h"

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

static inline int argmin(const cc_setup *s, const uint16_t *c)
{
#if CC_HAVE_X86
    if (s->use_avx2)
        return argmin_avx2(c, s->D);
#endif
    return argmin_scalar(c, 0, s->D, 0x10000u, 0);
}

void cc_select_row(const cc_setup *s, const uint16_t *row, int stride, int width,
                   int16_t *left_out, int16_t *right_out, uint16_t *tmp)
{
    const int D = s->D, dmin = s->p.min_disparity;
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int k = argmin(s, c);
        int d = (dmin + k) * CC_DISP_SCALE;
        if (s->p.subpixel && k > 0 && k < D - 1) {
            int a = c[k - 1], b = c[k + 1];
            int denom2 = a + b - 2 * (int)c[k];
            denom2 = denom2 > 1 ? denom2 : 1;
            d += ((a - b) * CC_DISP_SCALE + denom2) / (denom2 * 2);
        }
        left_out[x] = (int16_t)d;
    }
    /* Right view: candidates for xr arrive with increasing k, so a strict
     * comparison keeps the smallest disparity among equal costs. */
    for (int x = 0; x < width; x++) {
        tmp[x] = 0xFFFFu;
        right_out[x] = CC_INVALID;
    }
    for (int x = 0; x < width; x++) {
        const uint16_t *c = row + (size_t)x * stride;
        int k_lo = x - dmin - (width - 1), k_hi = x - dmin;
        k_lo = k_lo > 0 ? k_lo : 0;
        k_hi = k_hi < D - 1 ? k_hi : D - 1;
        for (int k = k_lo; k <= k_hi; k++) {
            int xr = x - dmin - k;
            if (c[k] < tmp[xr]) {
                tmp[xr] = c[k];
                right_out[xr] = (int16_t)((dmin + k) * CC_DISP_SCALE);
            }
        }
    }
}
