/* The buffers of one matcher for one image size: the matching costs, the
 * aggregated volume, the vertical path rows and the per-thread scratch (sums,
 * horizontal paths, selection; the frame preparation borrows the same slices
 * first). */
#include <string.h>

#include "frame.h"
#include "memory.h"
#include "select.h"
#include "workspace.h"

#define ALIGN 64

static size_t thread_scratch_bytes(const cc_setup *s, int width)
{
    size_t dp = (size_t)s->Dp, w = (size_t)width;
    size_t n = cc_round_up(w * dp * 2, ALIGN);                 /* sum row */
    n += 2 * cc_round_up((dp + 2 * CC_GUARD) * 2, ALIGN);      /* horizontal paths */
    n += cc_round_up(cc_select_tmp_bytes(s, width), ALIGN);    /* selection */
    /* The frame preparation runs before the passes and borrows the same slices. */
    size_t frame = cc_round_up(cc_frame_scratch_bytes(width), ALIGN);
    return n > frame ? n : frame;
}

cc_thread_scratch cc_thread_scratch_at(const cc_setup *s, const cc_workspace *ws, int thread)
{
    size_t dp = (size_t)s->Dp, w = (size_t)ws->width;
    uint8_t *p = ws->scratch + ws->scratch_stride * (size_t)thread;
    cc_thread_scratch t;
    t.sum_row = (uint16_t *)p;
    p += cc_round_up(w * dp * 2, ALIGN);
    for (int i = 0; i < 2; i++) {
        t.hpath[i] = (uint16_t *)p;
        p += cc_round_up((dp + 2 * CC_GUARD) * 2, ALIGN);
    }
    t.select_tmp = (uint16_t *)p;
    return t;
}

void cc_workspace_free(cc_workspace *ws)
{
    cc_free(ws->volume);
    cc_free(ws->costs);
    cc_free(ws->vpath);
    cc_free(ws->vmin);
    cc_free(ws->scratch);
    memset(ws, 0, sizeof *ws);
}

/* Guard lanes read by the vector kernels around every stored path vector. */
static void set_guards(uint16_t *base, size_t count, size_t stride)
{
    for (size_t i = 0; i < count; i++)
        for (size_t g = 0; g < stride; g++)
            base[i * stride + g] = CC_PATH_INF;
}

int cc_workspace_alloc(cc_workspace *ws, const cc_setup *s, int width, int height, size_t *bytes)
{
    memset(ws, 0, sizeof *ws);
    ws->width = width;
    ws->height = height;
    ws->threads = cc_thread_count(&s->p);
    int npaths = s->p.paths == 8 ? 3 : 1;
    ws->vstride = (size_t)s->Dp + 2 * CC_GUARD;
    size_t vol = (size_t)width * height * s->Dp * sizeof(uint16_t);
    ws->cstride = cc_round_up((size_t)s->Dp, 32);
    size_t costs = (size_t)width * height * ws->cstride + 64;
    size_t vpath = (size_t)npaths * 2 * width * ws->vstride * sizeof(uint16_t);
    size_t vmin = (size_t)npaths * 2 * width * sizeof(uint16_t);
    ws->scratch_stride = thread_scratch_bytes(s, width);
    size_t scratch = ws->scratch_stride * (size_t)ws->threads;
    ws->volume = cc_alloc(vol);
    ws->stream = vol >= ((size_t)64 << 20);
    ws->costs = cc_alloc(costs);
    ws->vpath = cc_alloc(vpath);
    ws->vmin = cc_alloc(vmin);
    ws->scratch = cc_alloc(scratch);
    if (!ws->volume || !ws->costs || !ws->vpath || !ws->vmin || !ws->scratch) {
        cc_workspace_free(ws);
        return CC_ERR_NOMEM;
    }
    set_guards(ws->vpath, (size_t)npaths * 2 * width, ws->vstride); /* pass 3 sets its own per call */
    *bytes = vol + costs + vpath + vmin + scratch;
    return CC_OK;
}
