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

#include "internal.h"

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
}

size_t cc_wm_hist_bytes(int levels) { return (size_t)levels * (sizeof(uint32_t) + sizeof(int64_t)); }

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
    return h;
}

static inline int floor_div16(int v) { return v >= 0 ? v / 16 : -((-v + 15) / 16); }

/* floor(a / b) for b > 0. */
static inline int64_t floor_div64(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

int cc_wm_level(int v, int dmin, int levels)
{
    if (v == CC_INVALID)
        return CC_WM_NO_LEVEL;
    int b = floor_div16(v + CC_DISP_SCALE / 2) - dmin;
    return b < 0 ? 0 : (b >= levels ? levels - 1 : b);
}

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

int16_t cc_wm_pixel(const cc_wm_tables *t, const cc_wm_image *g, const int16_t *map,
                    const uint16_t *level, int x, int y, int radius, cc_wm_hist *h)
{
    const int w = g->width, hgt = g->height, ch = g->channels;
    const size_t o = (size_t)y * w + x;
    if (level[o] == CC_WM_NO_LEVEL)
        return CC_INVALID;
    const uint8_t *gc = g->data + (size_t)y * g->stride + (size_t)x * ch;
    int y0 = y - radius < 0 ? 0 : y - radius, y1 = y + radius >= hgt ? hgt - 1 : y + radius;
    int x0 = x - radius < 0 ? 0 : x - radius, x1 = x + radius >= w ? w - 1 : x + radius;
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
