/* The three aggregation passes over the image (see aggregate.c for the plan). */
#include <omp.h>
#include <string.h>

#include "internal.h"

static inline int intensity(const cc_frame *f, int x, int y) { return f->lint[(size_t)y * f->width + x]; }

/* Paths from the previous row: straight, and for 8 paths also from x-1 and x+1. */
static const int path_dx[3] = {0, -1, 1};

void cc_pass_vertical(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int downward)
{
    const int w = f->width, h = f->height, Dp = s->Dp;
    const int npaths = s->p.paths == 8 ? 3 : 1;
    const size_t vs = ws->vstride;
#pragma omp parallel num_threads(ws->threads)
    {
        cc_thread_scratch t = cc_thread_scratch_at(s, ws, omp_get_thread_num());
        uint8_t *cost = t.cost_row; /* one pixel's worth is enough here */
        int cur = 0;
        for (int i = 0; i < h; i++) {
            const int y = downward ? i : h - 1 - i, py = downward ? y - 1 : y + 1;
#pragma omp for schedule(static)
            for (int x = 0; x < w; x++) {
                cc_cost_pixel(s, f, x, y, cost);
                uint16_t *acc = ws->volume + ((size_t)y * w + x) * Dp;
                for (int j = 0; j < npaths; j++) {
                    uint16_t *rows = ws->vpath + (size_t)j * 2 * w * vs;
                    uint16_t *mins = ws->vmin + (size_t)j * 2 * w;
                    uint16_t *prow = rows + (size_t)(cur ^ 1) * w * vs, *crow = rows + (size_t)cur * w * vs;
                    uint16_t *pmin = mins + (size_t)(cur ^ 1) * w, *cmin = mins + (size_t)cur * w;
                    const int px = x + path_dx[j];
                    const uint16_t *prev = NULL;
                    uint16_t prev_min = 0;
                    int p2 = s->p.p2;
                    if (i > 0 && px >= 0 && px < w) {
                        prev = prow + (size_t)px * vs + CC_GUARD;
                        prev_min = pmin[px];
                        p2 = cc_p2_for_step(&s->p, intensity(f, x, y), intensity(f, px, py));
                    }
                    const uint16_t *acc_in = (downward && j == 0) ? NULL : acc;
                    cmin[x] = cc_path_step(s, cost, prev, prev_min, p2, crow + (size_t)x * vs + CC_GUARD, acc_in, acc);
                }
            }
            cur ^= 1;
        }
    }
}

static void horizontal_paths(const cc_setup *s, const cc_frame *f, const cc_thread_scratch *t,
                             const uint16_t *volume_row, int y)
{
    const int w = f->width, Dp = s->Dp;
    uint16_t prev_min = 0;
    for (int x = 0; x < w; x++) { /* left to right: S = volume + L */
        const uint16_t *prev = x > 0 ? t->hpath[(x - 1) & 1] + CC_GUARD : NULL;
        int p2 = x > 0 ? cc_p2_for_step(&s->p, intensity(f, x, y), intensity(f, x - 1, y)) : s->p.p2;
        prev_min = cc_path_step(s, t->cost_row + (size_t)x * Dp, prev, prev_min, p2,
                                t->hpath[x & 1] + CC_GUARD, volume_row + (size_t)x * Dp,
                                t->sum_row + (size_t)x * Dp);
    }
    for (int x = w - 1; x >= 0; x--) { /* right to left: S += L */
        const uint16_t *prev = x < w - 1 ? t->hpath[(x + 1) & 1] + CC_GUARD : NULL;
        int p2 = x < w - 1 ? cc_p2_for_step(&s->p, intensity(f, x, y), intensity(f, x + 1, y)) : s->p.p2;
        prev_min = cc_path_step(s, t->cost_row + (size_t)x * Dp, prev, prev_min, p2,
                                t->hpath[x & 1] + CC_GUARD, t->sum_row + (size_t)x * Dp,
                                t->sum_row + (size_t)x * Dp);
    }
}

void cc_pass_rows(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int16_t *raw_left,
                  int16_t *raw_right, uint16_t *volume_out)
{
    const int w = f->width, h = f->height, Dp = s->Dp, D = s->D;
#pragma omp parallel num_threads(ws->threads)
    {
        cc_thread_scratch t = cc_thread_scratch_at(s, ws, omp_get_thread_num());
#pragma omp for schedule(dynamic, 4)
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++)
                cc_cost_pixel(s, f, x, y, t.cost_row + (size_t)x * Dp);
            horizontal_paths(s, f, &t, ws->volume + (size_t)y * w * Dp, y);
            cc_select_row(s, t.sum_row, Dp, w, raw_left + (size_t)y * w, raw_right + (size_t)y * w,
                          t.select_tmp);
            if (volume_out)
                for (int x = 0; x < w; x++)
                    memcpy(volume_out + ((size_t)y * w + x) * D, t.sum_row + (size_t)x * Dp,
                           sizeof(uint16_t) * D);
        }
    }
}
