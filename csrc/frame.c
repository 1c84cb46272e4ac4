/* Per-image preparation: census bit strings and Birchfield-Tomasi bounds. */
#include <omp.h>
#include <string.h>

#include "frame.h"
#include "memory.h"

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
 * changes, which a gain or offset leaves (nearly) in place.  Borders replicated. */
static void bt_source_row(const uint8_t *img, int width, int height, int stride, int y, int cap, uint8_t *out)
{
    const uint8_t *b = img + (size_t)y * stride;
    if (cap == 0) {
        memcpy(out, b, (size_t)width);
        return;
    }
    const uint8_t *a = img + (size_t)clampi(y - 1, 0, height - 1) * stride;
    const uint8_t *c = img + (size_t)clampi(y + 1, 0, height - 1) * stride;
    for (int x = 0; x < width; x++) {
        int xm = x > 0 ? x - 1 : 0, xp = x < width - 1 ? x + 1 : width - 1;
        int v = (a[xp] - a[xm]) + 2 * (b[xp] - b[xm]) + (c[xp] - c[xm]);
        out[x] = (uint8_t)(clampi(v, -cap, cap) + cap);
    }
}

/* BT bounds: min and max of the pixel and its two half-pixel neighbours,
 * (I(x) + I(x -+ 1)) / 2 rounded down, borders replicated. */
static void bt_bounds_row(const uint8_t *row, int width, uint8_t *lo, uint8_t *hi)
{
    for (int x = 0; x < width; x++) {
        int v = row[x];
        int a = (v + row[x > 0 ? x - 1 : 0]) >> 1;
        int b = (v + row[x < width - 1 ? x + 1 : width - 1]) >> 1;
        int mn = v < a ? v : a, mx = v > a ? v : a;
        mn = mn < b ? mn : b;
        mx = mx > b ? mx : b;
        lo[x] = (uint8_t)mn;
        hi[x] = (uint8_t)mx;
    }
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

/* scratch: cc_frame_scratch_bytes(width) bytes of this thread. */
static void prepare_row(cc_frame *f, const cc_setup *s, const uint8_t *img, int stride,
                        int y, int mirrored, uint8_t *scratch)
{
    int w = f->width, h = f->height, nb = f->nbytes;
    uint8_t *row = scratch, *lo = scratch + w, *hi = scratch + 2 * (size_t)w, *mine = scratch + 3 * (size_t)w;
    uint16_t *work = (uint16_t *)(scratch + 12 * (size_t)w);
    uint8_t *planes[8];
    for (int b = 0; b < nb; b++) /* the left image's planes go straight into the frame */
        planes[b] = mirrored ? mine + (size_t)b * w : f->lcen + ((size_t)b * h + y) * w;
    if (s->p.cost_mode != CC_COST_BT)
        census_row_planes(img, w, h, stride, s->p.census_width, s->p.census_height, s->p.census_smooth,
                          s->p.census_threshold, y, planes, nb, work);
    else
        for (int b = 0; b < nb; b++)
            memset(planes[b], 0, (size_t)w);
    bt_source_row(img, w, h, stride, y, s->p.bt_prefilter, row);
    if (!mirrored) {
        size_t o = (size_t)y * w;
        memcpy(f->lgrey + o, img + (size_t)y * stride, (size_t)w);
        bt_bounds_row(row, w, f->lmin + o, f->lmax + o);
        memcpy(f->lint + o, row, (size_t)w);
        return;
    }
    bt_bounds_row(row, w, lo, hi);
    size_t o = (size_t)y * f->rstride + f->pad + w - 1;
    for (int b = 0; b < nb; b++) {
        uint8_t *plane = f->rcen + (size_t)b * f->rstride * h + o;
        for (int x = 0; x < w; x++)
            plane[-x] = planes[b][x];
    }
    for (int x = 0; x < w; x++) {
        f->rint[o - x] = row[x];
        f->rmin[o - x] = lo[x];
        f->rmax[o - x] = hi[x];
    }
}

/* Rounded to 64 bytes so that every thread's slice starts aligned for its uint64 row. */
size_t cc_frame_scratch_bytes(int width)
{
    return (12 * (size_t)width + CENSUS_WORK(width) * sizeof(uint16_t) + 127) / 64 * 64;
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
