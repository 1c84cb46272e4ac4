/* The three aggregation passes over the image (see aggregate.c for the plan). */
#include <omp.h>
#include <string.h>

#include "aggregate.h"
#include "cost.h"
#include "passes.h"
#include "select.h"

static inline int intensity(const cc_frame *f, int x, int y) { return f->lgrey[(size_t)y * f->width + x]; }

/* Paths from the previous row: straight, and for 8 paths also from x-1 and x+1. */
static const int path_dx[3] = {0, -1, 1};

/* Row y of the vertical pass, columns x0..x1-1; `cur` picks which row buffer is new. */
static void vertical_row(const cc_setup *s, const cc_frame *f, cc_workspace *ws, const cc_thread_scratch *t,
                         int first, int y, int py, int x0, int x1, int cur, int downward)
{
    const int w = f->width, Dp = s->Dp;
    const int npaths = s->p.paths == 8 ? 3 : 1;
    const size_t vs = ws->vstride, cs = ws->cstride;
    uint8_t *costs = ws->costs + (size_t)y * w * cs;
    if (downward) /* pass 1 computes the costs, the later passes read them */
        cc_cost_segment(s, f, x0, x1, y, costs + (size_t)x0 * cs, cs);
    for (int x = x0; x < x1; x++) {
        const uint8_t *cost = costs + (size_t)x * cs;
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
            if (!first && px >= 0 && px < w) {
                prev = prow + (size_t)px * vs + CC_GUARD;
                prev_min = pmin[px];
                p2 = cc_p2_for_step(s, intensity(f, x, y), intensity(f, px, py));
            }
            const uint16_t *acc_in = (downward && j == 0) ? NULL : acc;
            cmin[x] = cc_path_step(s, cost, prev, prev_min, p2, crow + (size_t)x * vs + CC_GUARD, acc_in, acc);
        }
    }
}

/* With 4 paths a column depends only on itself, so column stripes run without
 * any synchronisation (a per-row barrier stalls badly when the cores are
 * shared with other work).  The diagonals of 8 paths read the neighbouring
 * columns of the previous row, so there the threads split each row and meet
 * at a barrier before the next. */
void cc_pass_vertical(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int downward)
{
    const int w = f->width, h = f->height;
    if (s->p.paths == 4) {
        int stripes = w / 64 < 4 * ws->threads ? w / 64 : 4 * ws->threads;
        stripes = stripes > 0 ? stripes : 1;
#pragma omp parallel for schedule(dynamic, 1) num_threads(ws->threads)
        for (int st = 0; st < stripes; st++) {
            cc_thread_scratch t = cc_thread_scratch_at(s, ws, omp_get_thread_num());
            int x0 = (int)((long)st * w / stripes), x1 = (int)((long)(st + 1) * w / stripes);
            for (int i = 0; i < h; i++) {
                int y = downward ? i : h - 1 - i;
                vertical_row(s, f, ws, &t, i == 0, y, downward ? y - 1 : y + 1, x0, x1, i & 1, downward);
            }
        }
        return;
    }
#pragma omp parallel num_threads(ws->threads)
    {
        cc_thread_scratch t = cc_thread_scratch_at(s, ws, omp_get_thread_num());
        int n = omp_get_num_threads(), id = omp_get_thread_num();
        int x0 = (int)((long)id * w / n), x1 = (int)((long)(id + 1) * w / n);
        for (int i = 0; i < h; i++) {
            int y = downward ? i : h - 1 - i;
            vertical_row(s, f, ws, &t, i == 0, y, downward ? y - 1 : y + 1, x0, x1, i & 1, downward);
#pragma omp barrier
        }
    }
}

static void horizontal_paths(const cc_setup *s, const cc_frame *f, const cc_thread_scratch *t,
                             const uint8_t *cost_row, size_t cs, const uint16_t *volume_row, int y)
{
    const int w = f->width, Dp = s->Dp;
    uint16_t prev_min = 0;
    for (int x = 0; x < w; x++) { /* left to right: S = volume + L */
        const uint16_t *prev = x > 0 ? t->hpath[(x - 1) & 1] + CC_GUARD : NULL;
        int p2 = x > 0 ? cc_p2_for_step(s, intensity(f, x, y), intensity(f, x - 1, y)) : s->p.p2;
        prev_min = cc_path_step(s, cost_row + (size_t)x * cs, prev, prev_min, p2,
                                t->hpath[x & 1] + CC_GUARD, volume_row + (size_t)x * Dp,
                                t->sum_row + (size_t)x * Dp);
    }
    for (int x = w - 1; x >= 0; x--) { /* right to left: S += L */
        const uint16_t *prev = x < w - 1 ? t->hpath[(x + 1) & 1] + CC_GUARD : NULL;
        int p2 = x < w - 1 ? cc_p2_for_step(s, intensity(f, x, y), intensity(f, x + 1, y)) : s->p.p2;
        prev_min = cc_path_step(s, cost_row + (size_t)x * cs, prev, prev_min, p2,
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
        /* the guard lanes of the horizontal path vectors: the frame preparation borrowed this scratch */
        for (int i = 0; i < 2; i++)
            for (size_t g = 0; g < ws->vstride; g++)
                t.hpath[i][g] = CC_PATH_INF;
#pragma omp for schedule(dynamic, 4)
        for (int y = 0; y < h; y++) {
            horizontal_paths(s, f, &t, ws->costs + (size_t)y * w * ws->cstride, ws->cstride,
                             ws->volume + (size_t)y * w * Dp, y);
            cc_select_row(s, t.sum_row, Dp, w, raw_left + (size_t)y * w, raw_right + (size_t)y * w,
                          t.select_tmp);
            if (volume_out)
                for (int x = 0; x < w; x++)
                    memcpy(volume_out + ((size_t)y * w + x) * D, t.sum_row + (size_t)x * Dp,
                           sizeof(uint16_t) * D);
        }
    }
}
