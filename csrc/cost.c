/* Fused matching cost of one left pixel against all disparities:
 * C = rho(Hamming(census), lambda_c) + rho(BT, lambda_b), both looked up in
 * quantised tables.  Right pixels outside the image get the largest cost. */
#include <string.h>

#include "cost.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

static inline int bt_cost(int il, int ilmin, int ilmax, int ir, int irmin, int irmax)
{
    int a = il - irmax, b = irmin - il, c = ir - ilmax, d = ilmin - ir;
    int lr = a > b ? a : b, rl = c > d ? c : d;
    lr = lr > 0 ? lr : 0;
    rl = rl > 0 ? rl : 0;
    int bt = lr < rl ? lr : rl;
    return bt < CC_LUT - 1 ? bt : CC_LUT - 1;
}

static void cost_pixel_scalar(const cc_setup *s, const cc_frame *f, int x, int y, uint8_t *out)
{
    int w = f->width, h = f->height, nb = f->nbytes;
    size_t lo = (size_t)y * w + x;
    size_t ro = (size_t)y * f->rstride + f->pad + (w - 1 - x) + s->p.min_disparity;
    size_t lplane = (size_t)w * h, rplane = (size_t)f->rstride * h;
    int il = f->lint[lo], ilmin = f->lmin[lo], ilmax = f->lmax[lo];
    for (int k = 0; k < s->D; k++) {
        size_t r = ro + k;
        int ham = 0;
        for (int b = 0; b < nb; b++)
            ham += __builtin_popcount((unsigned)(f->lcen[b * lplane + lo] ^ f->rcen[b * rplane + r]));
        int bt = bt_cost(il, ilmin, ilmax, f->rint[r], f->rmin[r], f->rmax[r]);
        out[k] = (uint8_t)(s->lut_census[ham] + s->lut_bt[bt]);
    }
}

#if CC_HAVE_X86
#define AVX2 __attribute__((target("avx2")))

/* 64-entry byte table lookup for indices 0..63: pshufb on each 16-entry quarter. */
AVX2 static inline __m256i lut64(__m256i idx, const __m256i t[4])
{
    __m256i r = _mm256_shuffle_epi8(t[0], idx);
    r = _mm256_blendv_epi8(r, _mm256_shuffle_epi8(t[1], idx), _mm256_cmpgt_epi8(idx, _mm256_set1_epi8(15)));
    r = _mm256_blendv_epi8(r, _mm256_shuffle_epi8(t[2], idx), _mm256_cmpgt_epi8(idx, _mm256_set1_epi8(31)));
    r = _mm256_blendv_epi8(r, _mm256_shuffle_epi8(t[3], idx), _mm256_cmpgt_epi8(idx, _mm256_set1_epi8(47)));
    return r;
}

AVX2 static inline void load_lut(const uint8_t *table, __m256i t[4])
{
    for (int i = 0; i < 4; i++)
        t[i] = _mm256_broadcastsi128_si256(_mm_loadu_si128((const __m128i *)(table + 16 * i)));
}

/* One left pixel against all disparities; `nb` census planes (a constant at each call below, so the
 * planes' loop unrolls and the left pixel's bytes stay in registers). */
AVX2 static inline __attribute__((always_inline)) void cost_pixel_avx2(const cc_setup *s, const cc_frame *f, int x,
                                                                       int y, uint8_t *out, const __m256i tc[4],
                                                                       const __m256i tb[4], int nb)
{
    int w = f->width, h = f->height;
    size_t lo = (size_t)y * w + x;
    size_t ro = (size_t)y * f->rstride + f->pad + (w - 1 - x) + s->p.min_disparity;
    size_t lplane = (size_t)w * h, rplane = (size_t)f->rstride * h;
    const __m256i nibble = _mm256_set1_epi8(0x0f);
    const __m256i popcnt = _mm256_setr_epi8(0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
                                            0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4);
    __m256i lcen[8];
    for (int b = 0; b < nb; b++)
        lcen[b] = _mm256_set1_epi8((char)f->lcen[b * lplane + lo]);
    const __m256i il = _mm256_set1_epi8((char)f->lint[lo]);
    const __m256i ilmin = _mm256_set1_epi8((char)f->lmin[lo]);
    const __m256i ilmax = _mm256_set1_epi8((char)f->lmax[lo]);
    const __m256i cap = _mm256_set1_epi8(CC_LUT - 1);
    for (int k = 0; k < s->Dp; k += 32) {
        size_t r = ro + k;
        __m256i ham = _mm256_setzero_si256();
        for (int b = 0; b < nb; b++) {
            __m256i v = _mm256_xor_si256(lcen[b], _mm256_loadu_si256((const __m256i *)(f->rcen + b * rplane + r)));
            __m256i lo4 = _mm256_and_si256(v, nibble);
            __m256i hi4 = _mm256_and_si256(_mm256_srli_epi16(v, 4), nibble);
            ham = _mm256_add_epi8(ham, _mm256_add_epi8(_mm256_shuffle_epi8(popcnt, lo4),
                                                       _mm256_shuffle_epi8(popcnt, hi4)));
        }
        __m256i ir = _mm256_loadu_si256((const __m256i *)(f->rint + r));
        __m256i irmin = _mm256_loadu_si256((const __m256i *)(f->rmin + r));
        __m256i irmax = _mm256_loadu_si256((const __m256i *)(f->rmax + r));
        __m256i lr = _mm256_max_epu8(_mm256_subs_epu8(il, irmax), _mm256_subs_epu8(irmin, il));
        __m256i rl = _mm256_max_epu8(_mm256_subs_epu8(ir, ilmax), _mm256_subs_epu8(ilmin, ir));
        __m256i bt = _mm256_min_epu8(_mm256_min_epu8(lr, rl), cap);
        __m256i c = _mm256_add_epi8(lut64(ham, tc), lut64(bt, tb));
        _mm256_storeu_si256((__m256i *)(out + k), c);
    }
}

#define COST_SEGMENT_NB(nb)                                                                                  \
    AVX2 static void cost_segment_avx2_##nb(const cc_setup *s, const cc_frame *f, int x0, int x1, int y,     \
                                            uint8_t *out, size_t stride)                                     \
    {                                                                                                        \
        __m256i tc[4], tb[4];                                                                                \
        load_lut(s->lut_census, tc);                                                                         \
        load_lut(s->lut_bt, tb);                                                                             \
        for (int x = x0; x < x1; x++, out += stride)                                                         \
            cost_pixel_avx2(s, f, x, y, out, tc, tb, nb);                                                    \
    }
COST_SEGMENT_NB(1)
COST_SEGMENT_NB(2)
COST_SEGMENT_NB(3)
COST_SEGMENT_NB(4)
COST_SEGMENT_NB(5)
COST_SEGMENT_NB(6)
COST_SEGMENT_NB(7)
COST_SEGMENT_NB(8)

static void cost_segment_avx2(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, uint8_t *out,
                              size_t stride)
{
    static void (*const by_planes[8])(const cc_setup *, const cc_frame *, int, int, int, uint8_t *, size_t) = {
        cost_segment_avx2_1, cost_segment_avx2_2, cost_segment_avx2_3, cost_segment_avx2_4,
        cost_segment_avx2_5, cost_segment_avx2_6, cost_segment_avx2_7, cost_segment_avx2_8};
    by_planes[f->nbytes - 1](s, f, x0, x1, y, out, stride);
}


/* The same cost with AVX-512 BW/VL/VBMI/BITALG on 256-bit vectors: a byte popcount per census plane
 * (vpopcntb) instead of two nibble lookups, and each 64-entry rho table one two-register byte
 * permutation (vpermi2b) instead of four lookups and three blends.  The same integers. */
#define AVX512 __attribute__((target("avx2,avx512f,avx512bw,avx512vl,avx512vbmi,avx512bitalg")))

AVX512 static inline __attribute__((always_inline)) void cost_pixel_avx512(const cc_setup *s, const cc_frame *f,
                                                                           int x, int y, uint8_t *out,
                                                                           const __m256i tc[2],
                                                                           const __m256i tb[2], int nb)
{
    int w = f->width, h = f->height;
    size_t lo = (size_t)y * w + x;
    size_t ro = (size_t)y * f->rstride + f->pad + (w - 1 - x) + s->p.min_disparity;
    size_t lplane = (size_t)w * h, rplane = (size_t)f->rstride * h;
    __m256i lcen[8];
    for (int b = 0; b < nb; b++)
        lcen[b] = _mm256_set1_epi8((char)f->lcen[b * lplane + lo]);
    const __m256i il = _mm256_set1_epi8((char)f->lint[lo]);
    const __m256i ilmin = _mm256_set1_epi8((char)f->lmin[lo]);
    const __m256i ilmax = _mm256_set1_epi8((char)f->lmax[lo]);
    const __m256i cap = _mm256_set1_epi8(CC_LUT - 1);
    for (int k = 0; k < s->Dp; k += 32) {
        size_t r = ro + k;
        __m256i ham = _mm256_setzero_si256();
        for (int b = 0; b < nb; b++)
            ham = _mm256_add_epi8(ham, _mm256_popcnt_epi8(_mm256_xor_si256(
                                           lcen[b], _mm256_loadu_si256((const __m256i *)(f->rcen + b * rplane + r)))));
        __m256i ir = _mm256_loadu_si256((const __m256i *)(f->rint + r));
        __m256i irmin = _mm256_loadu_si256((const __m256i *)(f->rmin + r));
        __m256i irmax = _mm256_loadu_si256((const __m256i *)(f->rmax + r));
        __m256i lr = _mm256_max_epu8(_mm256_subs_epu8(il, irmax), _mm256_subs_epu8(irmin, il));
        __m256i rl = _mm256_max_epu8(_mm256_subs_epu8(ir, ilmax), _mm256_subs_epu8(ilmin, ir));
        __m256i bt = _mm256_min_epu8(_mm256_min_epu8(lr, rl), cap);
        /* indices 0..63: bit 5 picks the table's upper 32 bytes (ham <= 62 for any window) */
        __m256i c = _mm256_add_epi8(_mm256_permutex2var_epi8(tc[0], ham, tc[1]),
                                    _mm256_permutex2var_epi8(tb[0], bt, tb[1]));
        _mm256_storeu_si256((__m256i *)(out + k), c);
    }
}

#define COST_SEGMENT_512_NB(nb)                                                                              \
    AVX512 static void cost_segment_avx512_##nb(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, \
                                                uint8_t *out, size_t stride)                                 \
    {                                                                                                        \
        const __m256i tc[2] = {_mm256_loadu_si256((const __m256i *)s->lut_census),                          \
                               _mm256_loadu_si256((const __m256i *)(s->lut_census + 32))};                   \
        const __m256i tb[2] = {_mm256_loadu_si256((const __m256i *)s->lut_bt),                              \
                               _mm256_loadu_si256((const __m256i *)(s->lut_bt + 32))};                       \
        for (int x = x0; x < x1; x++, out += stride)                                                         \
            cost_pixel_avx512(s, f, x, y, out, tc, tb, nb);                                                  \
    }
COST_SEGMENT_512_NB(1)
COST_SEGMENT_512_NB(2)
COST_SEGMENT_512_NB(3)
COST_SEGMENT_512_NB(4)
COST_SEGMENT_512_NB(5)
COST_SEGMENT_512_NB(6)
COST_SEGMENT_512_NB(7)
COST_SEGMENT_512_NB(8)

static void cost_segment_avx512(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, uint8_t *out,
                                size_t stride)
{
    static void (*const by_planes[8])(const cc_setup *, const cc_frame *, int, int, int, uint8_t *, size_t) = {
        cost_segment_avx512_1, cost_segment_avx512_2, cost_segment_avx512_3, cost_segment_avx512_4,
        cost_segment_avx512_5, cost_segment_avx512_6, cost_segment_avx512_7, cost_segment_avx512_8};
    by_planes[f->nbytes - 1](s, f, x0, x1, y, out, stride);
}
#endif

/* Disparities whose right pixel x - d falls outside the image get the largest cost. */
static void outside_costs(const cc_setup *s, int width, int x, uint8_t *out)
{
    int dmin = s->p.min_disparity;
    int k_lo = x - dmin - (width - 1), k_hi = x - dmin;
    if (k_lo > 0)
        memset(out, s->cmax, (size_t)(k_lo < s->D ? k_lo : s->D));
    int from = k_hi + 1 < 0 ? 0 : k_hi + 1;
    if (from < s->D)
        memset(out + from, s->cmax, (size_t)(s->D - from));
}

void cc_cost_segment(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, uint8_t *out, size_t stride)
{
#if CC_HAVE_X86
    if (s->use_avx512)
        cost_segment_avx512(s, f, x0, x1, y, out, stride);
    else if (s->use_avx2)
        cost_segment_avx2(s, f, x0, x1, y, out, stride);
    else
#endif
        for (int x = x0; x < x1; x++)
            cost_pixel_scalar(s, f, x, y, out + (size_t)(x - x0) * stride);
    int w = f->width, dmin = s->p.min_disparity;
    /* only pixels near the borders have disparities pointing outside */
    for (int x = x0; x < x1; x++)
        if (x - dmin - (s->D - 1) < 0 || x - dmin > w - 1)
            outside_costs(s, w, x, out + (size_t)(x - x0) * stride);
}
