/* The three aggregation passes over the image (see aggregate.c for the plan). */
#include <omp.h>
#include <string.h>

#include "aggregate.h"
#include "cost.h"
#include "passes.h"
#include "select.h"

/* Paths from the previous row: straight, and for 8 paths also from x-1 and x+1. */
static const int path_dx[3] = {0, -1, 1};

/* Row y of the vertical pass, columns x0..x1-1; `cur` picks which row buffer is new. */
static void vertical_row(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int first, int y, int py,
                         int x0, int x1, int cur, int downward)
{
    const int w = f->width;
    const int npaths = s->p.paths == 8 ? 3 : 1;
    const size_t vs = ws->vstride, cs = ws->cstride;
    uint8_t *costs = ws->costs + (size_t)y * w * cs;
    if (downward) /* pass 1 computes the costs, the later passes read them */
        cc_cost_segment(s, f, x0, x1, y, costs + (size_t)x0 * cs, cs);
    uint16_t *acc = ws->volume + (size_t)y * w * s->Dp;
    for (int j = 0; j < npaths; j++) {
        uint16_t *rows = ws->vpath + (size_t)j * 2 * w * vs, *mins = ws->vmin + (size_t)j * 2 * w;
        cc_path_rows r = {.width = w, .cost = costs, .cs = cs, .vs = vs,
                          .grey = f->lgrey + (size_t)y * w, .prev_grey = first ? NULL : f->lgrey + (size_t)py * w,
                          .prev = first ? NULL : rows + (size_t)(cur ^ 1) * w * vs,
                          .prev_min = mins + (size_t)(cur ^ 1) * w,
                          .out = rows + (size_t)cur * w * vs, .out_min = mins + (size_t)cur * w,
                          .acc_in = (downward && j == 0) ? NULL : acc, .acc_out = acc,
                          .stream = downward && npaths == 1 && ws->stream};
        cc_path_vertical_row(s, &r, x0, x1, path_dx[j]);
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
        /* four stripes per thread where each is at least 32 px wide, else fewer but a multiple of the thread
         * count, so that equal threads finish together (7 stripes on 2 threads left one waiting for a
         * seventh of the pass) */
        int per_thread = w / (32 * ws->threads);
        per_thread = per_thread > 4 ? 4 : per_thread;
        int stripes = per_thread > 0 ? per_thread * ws->threads : (w / 32 > 0 ? w / 32 : 1);
#pragma omp parallel for schedule(dynamic, 1) num_threads(ws->threads)
        for (int st = 0; st < stripes; st++) {
            int x0 = (int)((long)st * w / stripes), x1 = (int)((long)(st + 1) * w / stripes);
            for (int i = 0; i < h; i++) {
                int y = downward ? i : h - 1 - i;
                vertical_row(s, f, ws, i == 0, y, downward ? y - 1 : y + 1, x0, x1, i & 1, downward);
            }
        }
        return;
    }
#pragma omp parallel num_threads(ws->threads)
    {
        int n = omp_get_num_threads(), id = omp_get_thread_num();
        int x0 = (int)((long)id * w / n), x1 = (int)((long)(id + 1) * w / n);
        for (int i = 0; i < h; i++) {
            int y = downward ? i : h - 1 - i;
            vertical_row(s, f, ws, i == 0, y, downward ? y - 1 : y + 1, x0, x1, i & 1, downward);
#pragma omp barrier
        }
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
            cc_path_rows r = {.width = w, .cost = ws->costs + (size_t)y * w * ws->cstride, .cs = ws->cstride,
                              .grey = f->lgrey + (size_t)y * w, .acc_in = ws->volume + (size_t)y * w * Dp,
                              .acc_out = t.sum_row};
            cc_path_horizontal_row(s, &r, t.hpath);
            cc_select_row(s, t.sum_row, Dp, w, raw_left + (size_t)y * w, raw_right + (size_t)y * w,
                          t.select_tmp);
            if (volume_out)
                for (int x = 0; x < w; x++)
                    memcpy(volume_out + ((size_t)y * w + x) * D, t.sum_row + (size_t)x * Dp,
                           sizeof(uint16_t) * D);
        }
    }
}
