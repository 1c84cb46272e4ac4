/* The matcher object, its buffers, and the public entry points. */
#define _GNU_SOURCE
#include <omp.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "internal.h"

#define CC_ALIGN 64
#define CC_HUGE (2u << 20)

void *cc_alloc(size_t bytes)
{
    void *p = NULL;
    if (bytes == 0)
        bytes = CC_ALIGN;
    size_t align = bytes >= CC_HUGE ? CC_HUGE : CC_ALIGN;
    if (posix_memalign(&p, align, bytes) != 0)
        return NULL;
#ifdef MADV_HUGEPAGE
    /* The volume is touched once per pass: fewer TLB misses and page faults. */
    if (align == CC_HUGE)
        madvise(p, bytes, MADV_HUGEPAGE);
#endif
    return p;
}

void cc_free(void *ptr) { free(ptr); }

int cc_thread_count(const cc_params *p)
{
    int n = p->threads > 0 ? p->threads : omp_get_max_threads();
    return n > 0 ? n : 1;
}

struct cc_matcher {
    cc_setup setup;
    cc_frame frame;
    cc_workspace ws;
    int16_t *maps;           /* raw_left, raw_right, checked, filled when not supplied */
    void *post;              /* scratch of the post-processing (a map, histograms) */
    size_t bytes;
};


size_t cc_thread_scratch_bytes(const cc_setup *s, int width)
{
    size_t dp = (size_t)s->Dp, w = (size_t)width;
    size_t n = cc_round_up(w * dp + 64, CC_ALIGN);                /* cost row */
    n += cc_round_up(w * dp * 2, CC_ALIGN);                       /* sum row */
    n += 2 * cc_round_up((dp + 2 * CC_GUARD) * 2, CC_ALIGN);      /* horizontal paths */
    n += cc_round_up(cc_select_tmp_bytes(s, width), CC_ALIGN);    /* selection */
    /* The frame preparation runs before the passes and borrows the same slices. */
    size_t frame = cc_round_up(cc_frame_scratch_bytes(width), CC_ALIGN);
    return n > frame ? n : frame;
}

cc_thread_scratch cc_thread_scratch_at(const cc_setup *s, const cc_workspace *ws, int thread)
{
    size_t dp = (size_t)s->Dp, w = (size_t)ws->width;
    uint8_t *p = ws->scratch + ws->scratch_stride * (size_t)thread;
    cc_thread_scratch t;
    t.cost_row = p;
    p += cc_round_up(w * dp + 64, CC_ALIGN);
    t.sum_row = (uint16_t *)p;
    p += cc_round_up(w * dp * 2, CC_ALIGN);
    for (int i = 0; i < 2; i++) {
        t.hpath[i] = (uint16_t *)p;
        p += cc_round_up((dp + 2 * CC_GUARD) * 2, CC_ALIGN);
    }
    t.select_tmp = (uint16_t *)p;
    return t;
}

static void workspace_free(cc_workspace *ws)
{
    cc_free(ws->volume);
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

static int workspace_alloc(cc_workspace *ws, const cc_setup *s, int width, int height, size_t *bytes)
{
    memset(ws, 0, sizeof *ws);
    ws->width = width;
    ws->height = height;
    ws->threads = cc_thread_count(&s->p);
    int npaths = s->p.paths == 8 ? 3 : 1;
    ws->vstride = (size_t)s->Dp + 2 * CC_GUARD;
    size_t vol = (size_t)width * height * s->Dp * sizeof(uint16_t);
    size_t vpath = (size_t)npaths * 2 * width * ws->vstride * sizeof(uint16_t);
    size_t vmin = (size_t)npaths * 2 * width * sizeof(uint16_t);
    ws->scratch_stride = cc_thread_scratch_bytes(s, width);
    size_t scratch = ws->scratch_stride * (size_t)ws->threads;
    ws->volume = cc_alloc(vol);
    ws->vpath = cc_alloc(vpath);
    ws->vmin = cc_alloc(vmin);
    ws->scratch = cc_alloc(scratch);
    if (!ws->volume || !ws->vpath || !ws->vmin || !ws->scratch) {
        workspace_free(ws);
        return CC_ERR_NOMEM;
    }
    set_guards(ws->vpath, (size_t)npaths * 2 * width, ws->vstride);
    for (int t = 0; t < ws->threads; t++) {
        cc_thread_scratch ts = cc_thread_scratch_at(s, ws, t);
        set_guards(ts.hpath[0], 1, ws->vstride);
        set_guards(ts.hpath[1], 1, ws->vstride);
    }
    *bytes = vol + vpath + vmin + scratch;
    return CC_OK;
}

int cc_matcher_create(const cc_params *p, cc_matcher **out)
{
    if (!p || !out)
        return CC_ERR_NULL;
    *out = NULL;
    cc_matcher *m = calloc(1, sizeof *m);
    if (!m)
        return CC_ERR_NOMEM;
    int rc = cc_setup_init(&m->setup, p);
    if (rc != CC_OK) {
        free(m);
        return rc;
    }
    *out = m;
    return CC_OK;
}

static void matcher_release(cc_matcher *m)
{
    cc_frame_free(&m->frame);
    workspace_free(&m->ws);
    cc_free(m->maps);
    m->maps = NULL;
    cc_free(m->post);
    m->post = NULL;
    m->bytes = 0;
}

void cc_matcher_destroy(cc_matcher *m)
{
    if (!m)
        return;
    matcher_release(m);
    free(m);
}

size_t cc_matcher_bytes(const cc_matcher *m) { return m ? m->bytes : 0; }
int cc_matcher_simd(const cc_matcher *m) { return m ? m->setup.use_avx2 : 0; }

/* Buffers are kept between calls of the same size: a cycle allocates nothing. */
static int matcher_reserve(cc_matcher *m, int width, int height)
{
    if (m->ws.volume && m->ws.width == width && m->ws.height == height)
        return CC_OK;
    matcher_release(m);
    size_t ws_bytes = 0;
    int rc = cc_frame_alloc(&m->frame, &m->setup, width, height);
    if (rc == CC_OK)
        rc = workspace_alloc(&m->ws, &m->setup, width, height, &ws_bytes);
    size_t maps = (size_t)width * height * 4 * sizeof(int16_t);
    size_t post = cc_postprocess_scratch_bytes(&m->setup.p, width, height, m->ws.threads);
    if (rc == CC_OK && (!(m->maps = cc_alloc(maps)) || !(m->post = cc_alloc(post))))
        rc = CC_ERR_NOMEM;
    if (rc != CC_OK) {
        matcher_release(m);
        return rc;
    }
    m->bytes = cc_frame_bytes(&m->setup, width, height) + ws_bytes + maps + post;
    return CC_OK;
}

/* Checks the pair against the parameters and makes the buffers fit it. */
static int matcher_prepare(cc_matcher *m, const uint8_t *left, const uint8_t *right, int width,
                           int height, int stride_left, int stride_right)
{
    int rc = cc_check_images(left, right, width, height, stride_left, stride_right, &m->setup.p);
    return rc == CC_OK ? matcher_reserve(m, width, height) : rc;
}

/* The cost and the aggregation passes of a prepared pair; pass 3 also selects disparities. */
static void run_passes(cc_matcher *m, const uint8_t *left, const uint8_t *right, int stride_left,
                       int stride_right, int16_t *raw_left, int16_t *raw_right, uint16_t *volume_out)
{
    cc_frame_prepare(&m->frame, &m->setup, left, stride_left, right, stride_right, m->ws.threads,
                     m->ws.scratch);
    cc_pass_vertical(&m->setup, &m->frame, &m->ws, 1);
    cc_pass_vertical(&m->setup, &m->frame, &m->ws, 0);
    cc_pass_rows(&m->setup, &m->frame, &m->ws, raw_left, raw_right, volume_out);
}

int cc_matcher_compute(cc_matcher *m, const uint8_t *left, const uint8_t *right,
                       int width, int height, int stride_left, int stride_right,
                       const uint8_t *guide, int guide_channels, int stride_guide,
                       int16_t *disp, int16_t *raw_left, int16_t *raw_right,
                       int16_t *checked, int16_t *filled)
{
    if (!m || !disp)
        return CC_ERR_NULL;
    cc_wm_image g = {.data = guide ? guide : left, .width = width, .height = height,
                     .channels = guide ? guide_channels : 1,
                     .stride = (size_t)(guide ? stride_guide : stride_left)};
    if (g.channels != 1 && g.channels != 3)
        return CC_ERR_PARAM;
    if (g.stride < (size_t)width * g.channels)
        return CC_ERR_SIZE;
    int rc = matcher_prepare(m, left, right, width, height, stride_left, stride_right);
    if (rc != CC_OK)
        return rc;
    size_t n = (size_t)width * height;
    raw_left = raw_left ? raw_left : m->maps;
    raw_right = raw_right ? raw_right : m->maps + n;
    checked = checked ? checked : m->maps + 2 * n;
    filled = filled ? filled : m->maps + 3 * n;
    run_passes(m, left, right, stride_left, stride_right, raw_left, raw_right, NULL);
    cc_postprocess_maps(&m->setup.p, raw_left, raw_right, &g, width, height, checked, filled, disp,
                        m->post, m->ws.threads);
    return CC_OK;
}

int cc_aggregate(cc_matcher *m, const uint8_t *left, const uint8_t *right,
                 int width, int height, int stride_left, int stride_right, uint16_t *out)
{
    if (!m || !out)
        return CC_ERR_NULL;
    int rc = matcher_prepare(m, left, right, width, height, stride_left, stride_right);
    if (rc != CC_OK)
        return rc;
    size_t n = (size_t)width * height;
    run_passes(m, left, right, stride_left, stride_right, m->maps, m->maps + n, out);
    return CC_OK;
}

int cc_census(const uint8_t *img, int width, int height, int stride,
              int census_width, int census_height, uint64_t *out)
{
    if (!img || !out)
        return CC_ERR_NULL;
    if (width < 1 || height < 1 || width > CC_MAX_DIM || height > CC_MAX_DIM || stride < width)
        return CC_ERR_SIZE;
    if (census_width < 1 || census_width > 9 || census_width % 2 == 0 || census_height < 1 ||
        census_height > 7 || census_height % 2 == 0)
        return CC_ERR_PARAM;
    uint8_t *scratch = cc_alloc((size_t)width * 9 + 8);
    if (!scratch)
        return CC_ERR_NOMEM;
    for (int y = 0; y < height; y++)
        cc_census_row(img, width, height, stride, census_width, census_height, y, out + (size_t)y * width, scratch);
    cc_free(scratch);
    return CC_OK;
}

int cc_cost_volume(const cc_params *p, const uint8_t *left, const uint8_t *right,
                   int width, int height, int stride_left, int stride_right, uint8_t *out)
{
    if (!p || !out)
        return CC_ERR_NULL;
    cc_setup s;
    int rc = cc_setup_init(&s, p);
    if (rc == CC_OK)
        rc = cc_check_images(left, right, width, height, stride_left, stride_right, p);
    if (rc != CC_OK)
        return rc;
    cc_frame f;
    int threads = cc_thread_count(p);
    uint8_t *scratch = cc_alloc(cc_frame_scratch_bytes(width) * threads);
    uint8_t *cost = cc_alloc((size_t)width * s.Dp + 64);
    rc = cc_frame_alloc(&f, &s, width, height);
    if (rc == CC_OK && (!scratch || !cost))
        rc = CC_ERR_NOMEM;
    if (rc == CC_OK) {
        cc_frame_prepare(&f, &s, left, stride_left, right, stride_right, threads, scratch);
        for (int y = 0; y < height; y++) {
            cc_cost_segment(&s, &f, 0, width, y, cost, s.Dp);
            for (int x = 0; x < width; x++)
                memcpy(out + ((size_t)y * width + x) * s.D, cost + (size_t)x * s.Dp, s.D);
        }
        cc_frame_free(&f);
    }
    cc_free(scratch);
    cc_free(cost);
    return rc;
}

int cc_select(const cc_params *p, const uint16_t *volume, int width, int height,
              int16_t *raw_left, int16_t *raw_right)
{
    if (!p || !volume || !raw_left || !raw_right)
        return CC_ERR_NULL;
    cc_setup s;
    int rc = cc_setup_init(&s, p);
    if (rc != CC_OK)
        return rc;
    if (width < 1 || height < 1 || width > CC_MAX_DIM || height > CC_MAX_DIM)
        return CC_ERR_SIZE;
    uint16_t *tmp = cc_alloc(cc_select_tmp_bytes(&s, width));
    if (!tmp)
        return CC_ERR_NOMEM;
    for (int y = 0; y < height; y++)
        cc_select_row(&s, volume + (size_t)y * width * s.D, s.D, width, raw_left + (size_t)y * width,
                      raw_right + (size_t)y * width, tmp);
    cc_free(tmp);
    return CC_OK;
}

int cc_postprocess(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                   const uint8_t *guide, int guide_channels, int stride_guide,
                   int width, int height, int16_t *checked, int16_t *filled, int16_t *disp)
{
    if (!p || !raw_left || !raw_right || !checked || !filled || !disp)
        return CC_ERR_NULL;
    int rc = cc_params_check(p, NULL);
    if (rc != CC_OK)
        return rc;
    if (width < 1 || height < 1 || width > CC_MAX_DIM || height > CC_MAX_DIM)
        return CC_ERR_SIZE;
    if (!guide && (p->fill_mode == CC_FILL_WEIGHTED || p->weighted_median > 0))
        return CC_ERR_NULL;
    if (guide && guide_channels != 1 && guide_channels != 3)
        return CC_ERR_PARAM;
    if (guide && stride_guide < width * guide_channels)
        return CC_ERR_SIZE;
    cc_wm_image g = {.data = guide, .width = width, .height = height, .channels = guide_channels,
                     .stride = (size_t)stride_guide};
    int threads = cc_thread_count(p);
    void *scratch = cc_alloc(cc_postprocess_scratch_bytes(p, width, height, threads));
    if (!scratch)
        return CC_ERR_NOMEM;
    cc_postprocess_maps(p, raw_left, raw_right, &g, width, height, checked, filled, disp, scratch, threads);
    cc_free(scratch);
    return CC_OK;
}
