/* Semi-global aggregation (the paper's Eq. 15 and 16).
 *
 * Two full-size buffers: the aggregated volume S (2 bytes per cell) and the
 * matching cost C (1 byte per cell), which pass 1 computes and passes 2 and 3
 * read (recomputing it in each pass cost a fifth of the match's time at
 * 1280x1024x192).  Pass 1 runs the paths that come from above (S is
 * written), pass 2 the paths from below (S is added to), and pass 3 the two
 * horizontal paths per row, which completes S for the row while it is still in
 * cache and hands it to the disparity selection.  With 4 paths (the default)
 * passes 1 and 2 give each thread whole column stripes, which need no
 * synchronisation; with 8 paths the diagonals read the neighbouring columns,
 * so the threads split each row and meet at a barrier before the next
 * (passes.c).  Pass 3 splits rows.  Every cell is computed by the same integer
 * code whatever the thread count, so the result does not depend on it. */
#include <string.h>

#include "aggregate.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

void cc_p2_table(const cc_params *p, uint16_t table[256])
{
    for (int step = 0; step < 256; step++) {
        int p2 = p->p2_gamma == 0 ? p->p2 : p->p2 * p->p2_gamma / (p->p2_gamma + step);
        table[step] = (uint16_t)(p2 > p->p1 ? p2 : p->p1);
    }
}

/* One step along a path: L(p, d) = C(p, d) + min(L(p-r, d), L(p-r, d+-1) + P1,
 * min L(p-r) + P2) - min L(p-r); a path starts with L = C.  Writes L to out and
 * acc_out = (acc_in or 0) + L; returns min L.  prev and out have guard lanes
 * holding CC_PATH_INF at index -1 and from D on. */
static inline uint16_t path_step_scalar(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                                 uint16_t prev_min, int p2, uint16_t *out,
                                 const uint16_t *acc_in, uint16_t *acc_out)
{
    int D = s->D, p1 = s->p.p1;
    unsigned best = CC_PATH_INF;
    for (int d = 0; d < D; d++) {
        unsigned l = cost[d];
        if (prev) {
            unsigned m = prev[d];
            if (d > 0 && prev[d - 1] + (unsigned)p1 < m)
                m = prev[d - 1] + p1;
            if (d + 1 < D && prev[d + 1] + (unsigned)p1 < m)
                m = prev[d + 1] + p1;
            if (prev_min + (unsigned)p2 < m)
                m = prev_min + p2;
            l += m - prev_min;
        }
        out[d] = (uint16_t)l;
        acc_out[d] = (uint16_t)((acc_in ? acc_in[d] : 0) + l);
        best = l < best ? l : best;
    }
    for (int d = D; d < s->Dp; d++)
        out[d] = CC_PATH_INF;
    return (uint16_t)best;
}

#if CC_HAVE_X86
#define AVX2 __attribute__((target("avx2")))

/* One vector of 16 disparities k..k+15 of a path step; `tail` masks the lanes past the last disparity
 * (they never win). */
AVX2 static inline __m256i path_lanes_avx2(const uint8_t *cost, const uint16_t *prev, int k, __m256i vp1,
                                           __m256i vpm, __m256i vlim, __m256i tail)
{
    __m256i l = _mm256_cvtepu8_epi16(_mm_loadu_si128((const __m128i *)(cost + k)));
    if (prev) {
        __m256i m = _mm256_load_si256((const __m256i *)(prev + k));
        __m256i lo = _mm256_adds_epu16(_mm256_loadu_si256((const __m256i *)(prev + k - 1)), vp1);
        __m256i hi = _mm256_adds_epu16(_mm256_loadu_si256((const __m256i *)(prev + k + 1)), vp1);
        m = _mm256_min_epu16(_mm256_min_epu16(m, lo), _mm256_min_epu16(hi, vlim));
        l = _mm256_add_epi16(l, _mm256_sub_epi16(m, vpm));
    }
    return _mm256_or_si256(l, tail);
}

AVX2 static inline void path_store_avx2(uint16_t *out, const uint16_t *acc_in, uint16_t *acc_out, int k,
                                        __m256i l, int stream)
{
    _mm256_store_si256((__m256i *)(out + k), l);
    __m256i a = acc_in ? _mm256_add_epi16(_mm256_load_si256((const __m256i *)(acc_in + k)), l) : l;
    if (stream)
        _mm256_stream_si256((__m256i *)(acc_out + k), a);
    else
        _mm256_store_si256((__m256i *)(acc_out + k), a);
}

/* The full vectors first, without any lane test; then the last, partial one (only when D is not a
 * multiple of 16), with its lanes past D - 1 set to CC_PATH_INF. */
AVX2 static inline uint16_t path_step_avx2_nt(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                                       uint16_t prev_min, int p2, uint16_t *out,
                                       const uint16_t *acc_in, uint16_t *acc_out, int stream)
{
    const int D = s->D, full = D & ~(CC_LANES - 1);
    const __m256i vp1 = _mm256_set1_epi16((short)s->p.p1);
    const __m256i vpm = _mm256_set1_epi16((short)prev_min);
    const __m256i vlim = _mm256_set1_epi16((short)(prev_min + p2));
    const __m256i none = _mm256_setzero_si256();
    __m256i best = _mm256_set1_epi16((short)CC_PATH_INF);
    for (int k = 0; k < full; k += CC_LANES) {
        __m256i l = path_lanes_avx2(cost, prev, k, vp1, vpm, vlim, none);
        path_store_avx2(out, acc_in, acc_out, k, l, stream);
        best = _mm256_min_epu16(best, l);
    }
    if (full < D) {
        const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        __m256i tail = _mm256_cmpgt_epi16(lane, _mm256_set1_epi16((short)(D - 1 - full)));
        __m256i l = path_lanes_avx2(cost, prev, full, vp1, vpm, vlim, tail);
        path_store_avx2(out, acc_in, acc_out, full, l, stream);
        best = _mm256_min_epu16(best, l);
    }
    __m128i b = _mm_min_epu16(_mm256_castsi256_si128(best), _mm256_extracti128_si256(best, 1));
    return (uint16_t)_mm_cvtsi128_si32(_mm_minpos_epu16(b));
}

AVX2 static inline uint16_t path_step_avx2(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                                    uint16_t prev_min, int p2, uint16_t *out,
                                    const uint16_t *acc_in, uint16_t *acc_out)
{
    return path_step_avx2_nt(s, cost, prev, prev_min, p2, out, acc_in, acc_out, 0);
}

/* Pass 1's steps (acc_in NULL) on a volume far larger than the caches: written with non-temporal
 * stores, which skip reading each line first (5-10 % of the match at 1280x1024x192, measured). */
AVX2 static inline uint16_t path_step_avx2_stream(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                                           uint16_t prev_min, int p2, uint16_t *out,
                                           const uint16_t *acc_in, uint16_t *acc_out)
{
    return path_step_avx2_nt(s, cost, prev, prev_min, p2, out, acc_in, acc_out, 1);
}
#endif

/* The row loops, written once as macros: each instance below gets its kernel
 * inlined and keeps the kernel's constants in registers across the row (a
 * call per pixel and path cost as much as a quarter of the step itself). */
#define VERTICAL_ROW(suffix, attr, kernel)                                                                    \
    attr static void vertical_##suffix(const cc_setup *s, const cc_path_rows *r, int x0, int x1, int dx)     \
    {                                                                                                         \
        /* the row's pointers in locals: the stores below may not be taken to change them */                 \
        const int Dp = s->Dp, w = r->width, p2c = s->p.p2;                                                    \
        const size_t cs = r->cs, vs = r->vs;                                                                  \
        const uint8_t *const cost = r->cost, *const grey = r->grey, *const prev_grey = r->prev_grey;          \
        const uint16_t *const prev_row = r->prev, *const prev_mins = r->prev_min, *const acc_in = r->acc_in;  \
        uint16_t *const out = r->out, *const out_min = r->out_min, *const acc_out = r->acc_out;               \
        for (int x = x0; x < x1; x++) {                                                                       \
            const int px = x + dx;                                                                            \
            const uint16_t *prev = NULL;                                                                      \
            uint16_t prev_min = 0;                                                                            \
            int p2 = p2c;                                                                                     \
            if (prev_row && px >= 0 && px < w) {                                                              \
                prev = prev_row + (size_t)px * vs + CC_GUARD;                                                 \
                prev_min = prev_mins[px];                                                                     \
                p2 = cc_p2_for_step(s, grey[x], prev_grey[px]);                                               \
            }                                                                                                 \
            uint16_t *acc = acc_out + (size_t)x * Dp;                                                         \
            out_min[x] = kernel(s, cost + (size_t)x * cs, prev, prev_min, p2, out + (size_t)x * vs + CC_GUARD,\
                                acc_in ? acc : NULL, acc);                                                    \
        }                                                                                                     \
    }
#define HORIZONTAL_ROW(suffix, attr, kernel)                                                                  \
    attr static void horizontal_##suffix(const cc_setup *s, const cc_path_rows *r, uint16_t *hpath[2])       \
    {                                                                                                         \
        const int w = r->width, Dp = s->Dp, p2c = s->p.p2;                                                    \
        const size_t cs = r->cs;                                                                              \
        const uint8_t *const cost = r->cost, *const grey = r->grey;                                           \
        const uint16_t *const acc_in = r->acc_in;                                                             \
        uint16_t *const acc_out = r->acc_out, *const path[2] = {hpath[0] + CC_GUARD, hpath[1] + CC_GUARD};    \
        uint16_t prev_min = 0;                                                                                \
        for (int x = 0; x < w; x++) { /* left to right: S = volume + L */                                    \
            const uint16_t *prev = x > 0 ? path[(x - 1) & 1] : NULL;                                          \
            int p2 = x > 0 ? cc_p2_for_step(s, grey[x], grey[x - 1]) : p2c;                                   \
            prev_min = kernel(s, cost + (size_t)x * cs, prev, prev_min, p2, path[x & 1],                      \
                              acc_in + (size_t)x * Dp, acc_out + (size_t)x * Dp);                             \
        }                                                                                                     \
        for (int x = w - 1; x >= 0; x--) { /* right to left: S += L */                                       \
            const uint16_t *prev = x < w - 1 ? path[(x + 1) & 1] : NULL;                                      \
            int p2 = x < w - 1 ? cc_p2_for_step(s, grey[x], grey[x + 1]) : p2c;                               \
            prev_min = kernel(s, cost + (size_t)x * cs, prev, prev_min, p2, path[x & 1],                      \
                              acc_out + (size_t)x * Dp, acc_out + (size_t)x * Dp);                            \
        }                                                                                                     \
    }

VERTICAL_ROW(scalar, , path_step_scalar)
HORIZONTAL_ROW(scalar, , path_step_scalar)
#if CC_HAVE_X86
VERTICAL_ROW(avx2, AVX2, path_step_avx2)
VERTICAL_ROW(avx2_stream, AVX2, path_step_avx2_stream)
HORIZONTAL_ROW(avx2, AVX2, path_step_avx2)
#endif

void cc_path_vertical_row(const cc_setup *s, const cc_path_rows *r, int x0, int x1, int dx)
{
#if CC_HAVE_X86
    if (s->use_avx2 && r->stream) {
        vertical_avx2_stream(s, r, x0, x1, dx);
        _mm_sfence();
        return;
    }
    if (s->use_avx2) {
        vertical_avx2(s, r, x0, x1, dx);
        return;
    }
#endif
    vertical_scalar(s, r, x0, x1, dx);
}

void cc_path_horizontal_row(const cc_setup *s, const cc_path_rows *r, uint16_t *hpath[2])
{
#if CC_HAVE_X86
    if (s->use_avx2) {
        horizontal_avx2(s, r, hpath);
        return;
    }
#endif
    horizontal_scalar(s, r, hpath);
}
