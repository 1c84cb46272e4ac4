/* Left-right consistency check, background fill and median filter. */
#include <string.h>

#include "internal.h"

static inline int floor_div16(int v) { return v >= 0 ? v / 16 : -((-v + 15) / 16); }

static void lr_check_row(const cc_params *p, const int16_t *left, const int16_t *right, int width,
                         int16_t *out)
{
    for (int x = 0; x < width; x++) {
        int d = left[x];
        if (d == CC_INVALID || p->lr_max_diff < 0) {
            out[x] = (int16_t)d;
            continue;
        }
        int xr = x - floor_div16(d + CC_DISP_SCALE / 2);
        int ok = xr >= 0 && xr < width && right[xr] != CC_INVALID &&
                 (right[xr] > d ? right[xr] - d : d - right[xr]) <= p->lr_max_diff;
        out[x] = ok ? (int16_t)d : (int16_t)CC_INVALID;
    }
}

/* Occlusion by the image border: a pixel whose surface, judged by the nearest
 * kept disparity on its inner side, would be seen outside the other image
 * cannot have a real match; whatever it matched consistently is wrong.  Only
 * runs when the left-right check does (it works on its output). */
static void border_occlusion_row(int16_t *row, int width)
{
    int ref = CC_INVALID;
    for (int x = width - 1; x >= 0; x--) { /* left border: x - d < 0 */
        if (row[x] == CC_INVALID)
            continue;
        if (ref != CC_INVALID && x - floor_div16(ref + CC_DISP_SCALE / 2) < 0)
            row[x] = CC_INVALID;
        else
            ref = row[x];
    }
    ref = CC_INVALID;
    for (int x = 0; x < width; x++) { /* right border: x - d >= width */
        if (row[x] == CC_INVALID)
            continue;
        if (ref != CC_INVALID && x - floor_div16(ref + CC_DISP_SCALE / 2) >= width)
            row[x] = CC_INVALID;
        else
            ref = row[x];
    }
}

/* Invalid pixels are mostly occlusions, which belong to the farther surface:
 * take the smaller of the nearest valid disparities to the left and right. */
static void fill_row(const int16_t *in, int width, int16_t *out)
{
    int last = CC_INVALID;
    for (int x = 0; x < width; x++) {
        if (in[x] != CC_INVALID)
            last = in[x];
        out[x] = in[x] != CC_INVALID ? in[x] : (int16_t)last;
    }
    last = CC_INVALID;
    for (int x = width - 1; x >= 0; x--) {
        if (in[x] != CC_INVALID) {
            last = in[x];
            continue;
        }
        if (last != CC_INVALID && (out[x] == CC_INVALID || last < out[x]))
            out[x] = (int16_t)last;
    }
}

/* Median of the valid pixels of the window (clipped at the border); an
 * invalid pixel stays invalid, so the filter never invents a measurement. */
static void median_row(const int16_t *in, int width, int height, int y, int size, int16_t *out)
{
    int r = size / 2;
    int y0 = y - r < 0 ? 0 : y - r, y1 = y + r >= height ? height - 1 : y + r;
    for (int x = 0; x < width; x++) {
        if (in[(size_t)y * width + x] == CC_INVALID) {
            out[x] = CC_INVALID;
            continue;
        }
        int x0 = x - r < 0 ? 0 : x - r, x1 = x + r >= width ? width - 1 : x + r;
        int16_t v[25];
        int n = 0;
        for (int yy = y0; yy <= y1; yy++)
            for (int xx = x0; xx <= x1; xx++) {
                int16_t a = in[(size_t)yy * width + xx];
                if (a == CC_INVALID)
                    continue;
                int i = n++;
                while (i > 0 && v[i - 1] > a) {
                    v[i] = v[i - 1];
                    i--;
                }
                v[i] = a;
            }
        out[x] = v[(n - 1) / 2];
    }
}

void cc_postprocess_maps(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                         int width, int height, int16_t *checked, int16_t *filled,
                         int16_t *disp, int threads)
{
#pragma omp parallel num_threads(threads)
    {
#pragma omp for schedule(static)
        for (int y = 0; y < height; y++) {
            size_t o = (size_t)y * width;
            lr_check_row(p, raw_left + o, raw_right + o, width, checked + o);
            if (p->lr_max_diff >= 0)
                border_occlusion_row(checked + o, width);
            if (p->fill_mode == CC_FILL_BACKGROUND)
                fill_row(checked + o, width, filled + o);
            else
                memcpy(filled + o, checked + o, sizeof(int16_t) * width);
        }
#pragma omp for schedule(static)
        for (int y = 0; y < height; y++) {
            if (p->median)
                median_row(filled, width, height, y, p->median, disp + (size_t)y * width);
            else
                memcpy(disp + (size_t)y * width, filled + (size_t)y * width, sizeof(int16_t) * width);
        }
    }
}
