/* Per-image preparation: census bit strings and Birchfield-Tomasi bounds. */
#include <omp.h>
#include <string.h>

#include "internal.h"

static inline int clampi(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }

/* Census of one row with replicated borders; bit i is set when the centre is
 * >= the i-th neighbour of the window in raster order (the paper's Eq. 7). */
void cc_census_row(const uint8_t *img, int width, int height, int stride, int cw, int ch,
                   int y, uint64_t *out)
{
    int rx = cw / 2, ry = ch / 2;
    const uint8_t *centre = img + (size_t)y * stride;
    for (int x = 0; x < width; x++)
        out[x] = 0;
    int bit = 0;
    for (int dy = -ry; dy <= ry; dy++) {
        const uint8_t *row = img + (size_t)clampi(y + dy, 0, height - 1) * stride;
        for (int dx = -rx; dx <= rx; dx++) {
            if (dx == 0 && dy == 0)
                continue;
            for (int x = 0; x < width; x++) {
                uint64_t ge = centre[x] >= row[clampi(x + dx, 0, width - 1)];
                out[x] |= ge << bit;
            }
            bit++;
        }
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

static int census_bits(const cc_params *p) { return p->census_width * p->census_height - 1; }

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
    return (size_t)height * ((size_t)width * (nb + 3) + (size_t)rs * (nb + 3));
}

int cc_frame_alloc(cc_frame *f, const cc_setup *s, int width, int height)
{
    memset(f, 0, sizeof *f);
    frame_geometry(s, width, &f->nbytes, &f->pad, &f->rstride);
    f->width = width;
    f->height = height;
    size_t lsize = (size_t)width * height, rsize = (size_t)f->rstride * height;
    f->lcen = cc_alloc(lsize * f->nbytes);
    f->lint = cc_alloc(lsize * 3);
    f->rcen = cc_alloc(rsize * f->nbytes);
    f->rint = cc_alloc(rsize * 3);
    if (!f->lcen || !f->lint || !f->rcen || !f->rint) {
        cc_frame_free(f);
        return CC_ERR_NOMEM;
    }
    f->lmin = f->lint + lsize;
    f->lmax = f->lmin + lsize;
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

static void prepare_row(cc_frame *f, const cc_setup *s, const uint8_t *img, int stride,
                        int y, int mirrored, uint64_t *census, uint8_t *lo, uint8_t *hi)
{
    int w = f->width, h = f->height;
    const uint8_t *row = img + (size_t)y * stride;
    if (s->p.cost_mode != CC_COST_BT)
        cc_census_row(img, w, h, stride, s->p.census_width, s->p.census_height, y, census);
    else
        memset(census, 0, sizeof(uint64_t) * w);
    bt_bounds_row(row, w, lo, hi);
    if (!mirrored) {
        size_t o = (size_t)y * w;
        for (int b = 0; b < f->nbytes; b++)
            for (int x = 0; x < w; x++)
                f->lcen[(size_t)b * w * h + o + x] = (uint8_t)(census[x] >> (8 * b));
        memcpy(f->lint + o, row, w);
        memcpy(f->lmin + o, lo, w);
        memcpy(f->lmax + o, hi, w);
        return;
    }
    size_t o = (size_t)y * f->rstride + f->pad + w - 1;
    for (int b = 0; b < f->nbytes; b++) {
        uint8_t *plane = f->rcen + (size_t)b * f->rstride * h + o;
        for (int x = 0; x < w; x++)
            plane[-x] = (uint8_t)(census[x] >> (8 * b));
    }
    for (int x = 0; x < w; x++) {
        f->rint[o - x] = row[x];
        f->rmin[o - x] = lo[x];
        f->rmax[o - x] = hi[x];
    }
}

/* Rounded to 64 bytes so that every thread's slice starts aligned for its uint64 row. */
size_t cc_frame_scratch_bytes(int width) { return ((size_t)width * (sizeof(uint64_t) + 2) + 127) / 64 * 64; }

/* scratch: threads * cc_frame_scratch_bytes(width) bytes, one slice per thread. */
void cc_frame_prepare(cc_frame *f, const cc_setup *s, const uint8_t *left, int stride_left,
                      const uint8_t *right, int stride_right, int threads, uint8_t *scratch)
{
    int w = f->width, h = f->height;
#pragma omp parallel num_threads(threads)
    {
        uint8_t *mine = scratch + cc_frame_scratch_bytes(w) * (size_t)omp_get_thread_num();
        uint64_t *census = (uint64_t *)mine;
        uint8_t *lo = mine + sizeof(uint64_t) * w;
#pragma omp for schedule(static)
        for (int i = 0; i < 2 * h; i++) {
            int y = i >> 1, mirrored = i & 1;
            prepare_row(f, s, mirrored ? right : left, mirrored ? stride_right : stride_left,
                        y, mirrored, census, lo, lo + w);
        }
    }
}
