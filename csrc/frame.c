/* Per-image preparation: census bit strings and Birchfield-Tomasi bounds. */
#include <omp.h>
#include <string.h>

#include "frame.h"
#include "memory.h"

#if CC_HAVE_X86
#include <immintrin.h>
#define AVX2 __attribute__((target("avx2")))
#endif

static inline int clampi(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* The values the census compares in row y (clamped into the image): the pixel
 * itself (smooth 0) or the sum of its 3x3 neighbourhood (smooth 1), borders
 * replicated.  The sum keeps what 8-bit rounding loses: in flat regions the
 * raw comparisons are decided by +-1 grey-level noise and ties, which a gain
 * or exposure change between the cameras re-rolls; sums of nine pixels tie
 * far less and average the noise out. */
static void census_values(const uint8_t *img, int width, int height, int stride, int y, int smooth, uint16_t *out)
{
    y = clampi(y, 0, height - 1);
    const uint8_t *b = img + (size_t)y * stride;
    if (!smooth) {
        for (int x = 0; x < width; x++)
            out[x] = b[x];
        return;
    }
    const uint8_t *a = img + (size_t)clampi(y - 1, 0, height - 1) * stride;
    const uint8_t *c = img + (size_t)clampi(y + 1, 0, height - 1) * stride;
    for (int x = 0; x < width; x++) {
        int xm = x > 0 ? x - 1 : 0, xp = x < width - 1 ? x + 1 : width - 1;
        out[x] = (uint16_t)(a[xm] + a[x] + a[xp] + b[xm] + b[x] + b[xp] + c[xm] + c[x] + c[xp] +
                            (smooth == 2 ? 8 * b[x] : 0));
    }
}

/* Census of row y as byte planes (plane b holds bits 8b..8b+7), borders
 * replicated.  Binary (threshold 0): bit i is set when the centre is >= the
 * i-th neighbour of the window in raster order (the paper's Eq. 7).  Ternary
 * (threshold t > 0): neighbour i gives bit 2i (centre >= neighbour + t) and bit
 * 2i+1 (neighbour >= centre + t); a pair closer than t levels sets neither, so
 * the Hamming distance counts 1 between similar and ordered and 2 between
 * opposite orders.  In flat regions the binary bits are decided by ties and
 * +-1 noise that a gain between the cameras re-rolls; the dead band keeps them
 * out.  Each neighbour row is prepared with its border padding first so the
 * inner loop has no clamping and vectorises.  `work` holds CENSUS_WORK(width) values. */
#define CENSUS_WORK(width) (2 * (size_t)(width) + 8)
static void census_row_planes(const uint8_t *img, int width, int height, int stride, int cw, int ch, int smooth,
                              int threshold, int y, uint8_t *const *planes, int nbytes, uint16_t *work)
{
    int rx = cw / 2, ry = ch / 2;
    uint16_t *centre = work, *padded = work + width;
    census_values(img, width, height, stride, y, smooth, centre);
    for (int b = 0; b < nbytes; b++)
        memset(planes[b], 0, (size_t)width);
    int bit = 0;
    for (int dy = -ry; dy <= ry; dy++) {
        census_values(img, width, height, stride, y + dy, smooth, padded + rx);
        for (int i = 0; i < rx; i++) {
            padded[i] = padded[rx];
            padded[rx + width + i] = padded[rx + width - 1];
        }
        for (int dx = -rx; dx <= rx; dx++) {
            if (dx == 0 && dy == 0)
                continue;
            const uint16_t *nb = padded + rx + dx;
            uint8_t *plane = planes[bit >> 3];
            const uint8_t mask = (uint8_t)(1u << (bit & 7));
            if (!threshold) {
                for (int x = 0; x < width; x++)
                    plane[x] |= centre[x] >= nb[x] ? mask : 0;
                bit++;
                continue;
            }
            /* bits 2i and 2i+1 share a byte (bit is even); two loops of the binary loop's shape
             * vectorise (values <= 17 * 255, + threshold <= 255: no uint16 overflow) */
            const uint8_t mask2 = (uint8_t)(mask << 1);
            const uint16_t t = (uint16_t)threshold;
            for (int x = 0; x < width; x++)
                plane[x] |= centre[x] >= (uint16_t)(nb[x] + t) ? mask : 0;
            for (int x = 0; x < width; x++)
                plane[x] |= nb[x] >= (uint16_t)(centre[x] + t) ? mask2 : 0;
            bit += 2;
        }
    }
}

#if CC_HAVE_X86
/* census_row_planes for the pixels themselves (smooth 0), 32 pixels at a time in 8-bit lanes, each
 * plane built in a register: the same bits.  `work` holds CENSUS_AVX2_WORK(width, ch) bytes: the ch
 * window rows, each padded by rx replicated pixels on both sides.  Needs width >= 32; the last chunk
 * overlaps the one before (the same bytes are written again). */
#define CENSUS_AVX2_WORK(width, ch) ((size_t)(ch) * ((size_t)(width) + 8) + 32)
AVX2 static void census_row_planes_avx2(const uint8_t *img, int width, int height, int stride, int cw, int ch,
                                        int threshold, int y, uint8_t *const *planes, int nbytes, uint8_t *work)
{
    const int rx = cw / 2, ry = ch / 2;
    const size_t pw = (size_t)width + 2 * rx;
    int off[63]; /* each neighbour's offset in `work` from the centre row's first pixel, raster order */
    int n = 0;
    for (int i = 0; i < ch; i++) {
        const uint8_t *src = img + (size_t)clampi(y - ry + i, 0, height - 1) * stride;
        uint8_t *dst = work + (size_t)i * pw;
        memset(dst, src[0], (size_t)rx);
        memcpy(dst + rx, src, (size_t)width);
        memset(dst + rx + width, src[width - 1], (size_t)rx);
        for (int dx = -rx; dx <= rx; dx++)
            if (i != ry || dx != 0)
                off[n++] = (int)((size_t)(i - ry) * pw) + dx;
    }
    const uint8_t *centre = work + (size_t)ry * pw + rx;
    const int per_plane = threshold ? 4 : 8; /* neighbours per byte plane */
    const __m256i vt = _mm256_set1_epi8((char)(threshold > 0 ? threshold : 1));
    for (int x0 = 0; x0 < width; x0 += 32) {
        const int x = x0 + 32 <= width ? x0 : width - 32;
        const __m256i c = _mm256_loadu_si256((const __m256i *)(centre + x));
        for (int b = 0; b < nbytes; b++) {
            /* bits pushed from the plane's last neighbour down to its first: bit 0 ends lowest */
            __m256i acc = _mm256_setzero_si256();
            int last = (b + 1) * per_plane < n ? (b + 1) * per_plane : n;
            for (int i = last - 1; i >= b * per_plane; i--) {
                __m256i nb = _mm256_loadu_si256((const __m256i *)(centre + x + off[i]));
                if (!threshold) { /* centre >= neighbour */
                    __m256i ge = _mm256_cmpeq_epi8(_mm256_max_epu8(c, nb), c);
                    acc = _mm256_sub_epi8(_mm256_add_epi8(acc, acc), ge);
                    continue;
                }
                /* bit 2i+1: neighbour >= centre + t; bit 2i: centre >= neighbour + t (t >= 1) */
                __m256i up = _mm256_subs_epu8(nb, c), down = _mm256_subs_epu8(c, nb);
                __m256i ge_up = _mm256_cmpeq_epi8(_mm256_max_epu8(up, vt), up);
                __m256i ge_down = _mm256_cmpeq_epi8(_mm256_max_epu8(down, vt), down);
                acc = _mm256_sub_epi8(_mm256_add_epi8(acc, acc), ge_up);
                acc = _mm256_sub_epi8(_mm256_add_epi8(acc, acc), ge_down);
            }
            _mm256_storeu_si256((__m256i *)(planes[b] + x), acc);
        }
    }
}

/* dst[-x] = src[x] for x = 0..n-1 (dst points at the last byte of the reversed run). */
AVX2 static void reverse_copy_avx2(uint8_t *dst, const uint8_t *src, int n)
{
    const __m256i rev = _mm256_setr_epi8(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0,
                                         15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
    int x = 0;
    for (; x + 32 <= n; x += 32) {
        __m256i v = _mm256_shuffle_epi8(_mm256_loadu_si256((const __m256i *)(src + x)), rev);
        _mm256_storeu_si256((__m256i *)(dst - x - 31), _mm256_permute4x64_epi64(v, 0x4E));
    }
    for (; x < n; x++)
        dst[-x] = src[x];
}
#endif

static void reverse_copy(const cc_setup *s, uint8_t *dst, const uint8_t *src, int n)
{
#if CC_HAVE_X86
    if (s->use_avx2) {
        reverse_copy_avx2(dst, src, n);
        return;
    }
#endif
    for (int x = 0; x < n; x++)
        dst[-x] = src[x];
}

size_t cc_census_scratch_bytes(int width) { return 8 * (size_t)width + CENSUS_WORK(width) * sizeof(uint16_t); }

void cc_census_row(const uint8_t *img, int width, int height, int stride, int cw, int ch,
                   int y, uint64_t *out, uint8_t *scratch)
{
    int nbytes = (cw * ch - 1 + 7) / 8;
    nbytes = nbytes < 1 ? 1 : (nbytes > 8 ? 8 : nbytes); /* callers check the window (<= 9x7) */
    uint8_t *planes[8];
    for (int b = 0; b < nbytes; b++)
        planes[b] = scratch + (size_t)b * width;
    census_row_planes(img, width, height, stride, cw, ch, 0, 0, y, planes, nbytes,
                      (uint16_t *)(scratch + (size_t)8 * width));
    for (int x = 0; x < width; x++) {
        uint64_t v = 0;
        for (int b = 0; b < nbytes; b++)
            v |= (uint64_t)planes[b][x] << (8 * b);
        out[x] = v;
    }
}

/* The image the BT term compares, row y: raw intensities (cap 0), or as OpenCV's
 * StereoSGBM prefilter, the horizontal Sobel response clipped to [-cap, cap] and
 * shifted to 0..2cap.  BT on raw intensities breaks when the two cameras differ
 * in gain or exposure; the clipped derivative keeps only where the intensity
 * changes, which a gain or offset leaves (nearly) in place.  Borders replicated.
 * Written as the border pixels and a clamp-free interior loop, which the compiler
 * vectorises (an AVX2 instance below). */
static inline int sobel_x(const uint8_t *a, const uint8_t *b, const uint8_t *c, int xm, int xp)
{
    return (a[xp] - a[xm]) + 2 * (b[xp] - b[xm]) + (c[xp] - c[xm]);
}

static inline __attribute__((always_inline)) void bt_source_body(const uint8_t *img, int width, int height,
                                                                 int stride, int y, int cap, uint8_t *out)
{
    const uint8_t *b = img + (size_t)y * stride;
    if (cap == 0) {
        memcpy(out, b, (size_t)width);
        return;
    }
    const uint8_t *a = img + (size_t)clampi(y - 1, 0, height - 1) * stride;
    const uint8_t *c = img + (size_t)clampi(y + 1, 0, height - 1) * stride;
    const int last = width - 1;
    out[0] = (uint8_t)(clampi(sobel_x(a, b, c, 0, last > 0 ? 1 : 0), -cap, cap) + cap);
    for (int x = 1; x < last; x++)
        out[x] = (uint8_t)(clampi(sobel_x(a, b, c, x - 1, x + 1), -cap, cap) + cap);
    if (last > 0)
        out[last] = (uint8_t)(clampi(sobel_x(a, b, c, last - 1, last), -cap, cap) + cap);
}

/* BT bounds: min and max of the pixel and its two half-pixel neighbours,
 * (I(x) + I(x -+ 1)) / 2 rounded down, borders replicated. */
static inline int bt_lo(int v, int l, int r)
{
    int a = (v + l) >> 1, b = (v + r) >> 1, m = v < a ? v : a;
    return m < b ? m : b;
}
static inline int bt_hi(int v, int l, int r)
{
    int a = (v + l) >> 1, b = (v + r) >> 1, m = v > a ? v : a;
    return m > b ? m : b;
}

static inline __attribute__((always_inline)) void bt_bounds_body(const uint8_t *row, int width, uint8_t *lo,
                                                                 uint8_t *hi)
{
    const int last = width - 1;
    lo[0] = (uint8_t)bt_lo(row[0], row[0], row[last > 0 ? 1 : 0]);
    hi[0] = (uint8_t)bt_hi(row[0], row[0], row[last > 0 ? 1 : 0]);
    for (int x = 1; x < last; x++) {
        lo[x] = (uint8_t)bt_lo(row[x], row[x - 1], row[x + 1]);
        hi[x] = (uint8_t)bt_hi(row[x], row[x - 1], row[x + 1]);
    }
    if (last > 0) {
        lo[last] = (uint8_t)bt_lo(row[last], row[last - 1], row[last]);
        hi[last] = (uint8_t)bt_hi(row[last], row[last - 1], row[last]);
    }
}

static void bt_source_row_plain(const uint8_t *img, int width, int height, int stride, int y, int cap,
                                uint8_t *out)
{
    bt_source_body(img, width, height, stride, y, cap, out);
}
static void bt_bounds_row_plain(const uint8_t *row, int width, uint8_t *lo, uint8_t *hi)
{
    bt_bounds_body(row, width, lo, hi);
}
#if CC_HAVE_X86
AVX2 static void bt_source_row_avx2(const uint8_t *img, int width, int height, int stride, int y, int cap,
                                    uint8_t *out)
{
    bt_source_body(img, width, height, stride, y, cap, out);
}
AVX2 static void bt_bounds_row_avx2(const uint8_t *row, int width, uint8_t *lo, uint8_t *hi)
{
    bt_bounds_body(row, width, lo, hi);
}
#endif

static void bt_source_row(const cc_setup *s, const uint8_t *img, int width, int height, int stride, int y,
                          uint8_t *out)
{
#if CC_HAVE_X86
    if (s->use_avx2) {
        bt_source_row_avx2(img, width, height, stride, y, s->p.bt_prefilter, out);
        return;
    }
#endif
    bt_source_row_plain(img, width, height, stride, y, s->p.bt_prefilter, out);
}

static void bt_bounds_row(const cc_setup *s, const uint8_t *row, int width, uint8_t *lo, uint8_t *hi)
{
#if CC_HAVE_X86
    if (s->use_avx2) {
        bt_bounds_row_avx2(row, width, lo, hi);
        return;
    }
#endif
    bt_bounds_row_plain(row, width, lo, hi);
}

static int census_bits(const cc_params *p)
{
    return (p->census_width * p->census_height - 1) * (p->census_threshold ? 2 : 1);
}

static void frame_geometry(const cc_setup *s, int width, int *nbytes, int *pad, int *rstride)
{
    int dmin = s->p.min_disparity;
    *nbytes = (census_bits(&s->p) + 7) / 8;
    if (*nbytes < 1)
        *nbytes = 1;
    /* index pad + width-1-x + dmin + k must stay inside the row for every x
     * and every k < Dp + 32 (the vector loops read 32 lanes at a time). */
    *pad = (dmin < 0 ? -dmin : 0) + 32;
    *rstride = *pad + width + (dmin > 0 ? dmin : 0) + s->Dp + 64;
}

size_t cc_frame_bytes(const cc_setup *s, int width, int height)
{
    int nb, pad, rs;
    frame_geometry(s, width, &nb, &pad, &rs);
    return (size_t)height * ((size_t)width * (nb + 4) + (size_t)rs * (nb + 3));
}

int cc_frame_alloc(cc_frame *f, const cc_setup *s, int width, int height)
{
    memset(f, 0, sizeof *f);
    frame_geometry(s, width, &f->nbytes, &f->pad, &f->rstride);
    f->width = width;
    f->height = height;
    size_t lsize = (size_t)width * height, rsize = (size_t)f->rstride * height;
    f->lcen = cc_alloc(lsize * f->nbytes);
    f->lint = cc_alloc(lsize * 4);
    f->rcen = cc_alloc(rsize * f->nbytes);
    f->rint = cc_alloc(rsize * 3);
    if (!f->lcen || !f->lint || !f->rcen || !f->rint) {
        cc_frame_free(f);
        return CC_ERR_NOMEM;
    }
    f->lmin = f->lint + lsize;
    f->lmax = f->lmin + lsize;
    f->lgrey = f->lmax + lsize;
    f->rmin = f->rint + rsize;
    f->rmax = f->rmin + rsize;
    /* The padding of the mirrored rows is read but never used: keep it defined. */
    memset(f->rcen, 0, rsize * f->nbytes);
    memset(f->rint, 0, rsize * 3);
    return CC_OK;
}

void cc_frame_free(cc_frame *f)
{
    cc_free(f->lcen);
    cc_free(f->lint);
    cc_free(f->rcen);
    cc_free(f->rint);
    memset(f, 0, sizeof *f);
}

/* The census planes of row y (the frame's kernels: AVX2 for the pixels themselves when the row is
 * wide enough, else the portable loop).  `work`: FRAME_WORK(width) bytes. */
#define FRAME_WORK(width) (7 * ((size_t)(width) + 8) + 32 + CENSUS_WORK(width) * sizeof(uint16_t))
static void census_planes(const cc_setup *s, const uint8_t *img, int w, int h, int stride, int y,
                          uint8_t *const *planes, int nb, uint8_t *work)
{
    const cc_params *p = &s->p;
#if CC_HAVE_X86
    if (s->use_avx2 && p->census_smooth == 0 && w >= 32) {
        census_row_planes_avx2(img, w, h, stride, p->census_width, p->census_height, p->census_threshold, y,
                               planes, nb, work);
        return;
    }
#endif
    census_row_planes(img, w, h, stride, p->census_width, p->census_height, p->census_smooth,
                      p->census_threshold, y, planes, nb, (uint16_t *)work);
}

/* scratch: cc_frame_scratch_bytes(width) bytes of this thread. */
static void prepare_row(cc_frame *f, const cc_setup *s, const uint8_t *img, int stride,
                        int y, int mirrored, uint8_t *scratch)
{
    int w = f->width, h = f->height, nb = f->nbytes;
    uint8_t *row = scratch, *lo = scratch + w, *hi = scratch + 2 * (size_t)w, *mine = scratch + 3 * (size_t)w;
    uint8_t *work = scratch + 12 * (size_t)w;
    uint8_t *planes[8];
    for (int b = 0; b < nb; b++) /* the left image's planes go straight into the frame */
        planes[b] = mirrored ? mine + (size_t)b * w : f->lcen + ((size_t)b * h + y) * w;
    if (s->p.cost_mode != CC_COST_BT)
        census_planes(s, img, w, h, stride, y, planes, nb, work);
    else
        for (int b = 0; b < nb; b++)
            memset(planes[b], 0, (size_t)w);
    if (!mirrored) {
        size_t o = (size_t)y * w;
        memcpy(f->lgrey + o, img + (size_t)y * stride, (size_t)w);
        bt_source_row(s, img, w, h, stride, y, f->lint + o);
        bt_bounds_row(s, f->lint + o, w, f->lmin + o, f->lmax + o);
        return;
    }
    bt_source_row(s, img, w, h, stride, y, row);
    bt_bounds_row(s, row, w, lo, hi);
    size_t o = (size_t)y * f->rstride + f->pad + w - 1;
    for (int b = 0; b < nb; b++)
        reverse_copy(s, f->rcen + (size_t)b * f->rstride * h + o, planes[b], w);
    reverse_copy(s, f->rint + o, row, w);
    reverse_copy(s, f->rmin + o, lo, w);
    reverse_copy(s, f->rmax + o, hi, w);
}

/* Rounded to 64 bytes so that every thread's slice starts aligned for its uint64 row. */
size_t cc_frame_scratch_bytes(int width)
{
    return (12 * (size_t)width + FRAME_WORK(width) + 127) / 64 * 64;
}

/* scratch: one slice of `slice` bytes per thread. */
void cc_frame_prepare(cc_frame *f, const cc_setup *s, const uint8_t *left, int stride_left,
                      const uint8_t *right, int stride_right, int threads, uint8_t *scratch, size_t slice)
{
    int h = f->height;
#pragma omp parallel num_threads(threads)
    {
        uint8_t *mine = scratch + slice * (size_t)omp_get_thread_num();
#pragma omp for schedule(dynamic, 8)
        for (int i = 0; i < 2 * h; i++) {
            int y = i >> 1, mirrored = i & 1;
            prepare_row(f, s, mirrored ? right : left, mirrored ? stride_right : stride_left, y, mirrored, mine);
        }
    }
}
