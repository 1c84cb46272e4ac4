/* The matcher object, its buffers, and the public entry points. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "cost.h"
#include "frame.h"
#include "memory.h"
#include "passes.h"
#include "postprocess.h"
#include "select.h"
#include "workspace.h"

#if CC_HAVE_X86
#include <immintrin.h>
#endif

struct cc_matcher {
    cc_setup setup;
    cc_frame frame;
    cc_workspace ws;
    int16_t *maps;           /* raw_left, raw_right, checked, filled when not supplied */
    void *post;              /* scratch of the post-processing (a map, histograms) */
    size_t bytes;
};


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
    cc_workspace_free(&m->ws);
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
        rc = cc_workspace_alloc(&m->ws, &m->setup, width, height, &ws_bytes);
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
                     m->ws.scratch, m->ws.scratch_stride);
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

#if CC_HAVE_X86
/* 8 values at a time; returns how many it did. */
__attribute__((target("avx2"))) static size_t disparity_to_float_avx2(const int16_t *disp, size_t count, float *out)
{
    const __m256 scale = _mm256_set1_ps(1.0f / CC_DISP_SCALE), nan = _mm256_set1_ps(NAN);
    const __m256i invalid = _mm256_set1_epi32(CC_INVALID);
    size_t i = 0;
    for (; i + 8 <= count; i += 8) {
        __m256i d = _mm256_cvtepi16_epi32(_mm_loadu_si128((const __m128i *)(disp + i)));
        __m256 v = _mm256_mul_ps(_mm256_cvtepi32_ps(d), scale);
        __m256 bad = _mm256_castsi256_ps(_mm256_cmpeq_epi32(d, invalid));
        _mm256_storeu_ps(out + i, _mm256_blendv_ps(v, nan, bad));
    }
    return i;
}
#endif

int cc_disparity_to_float(const int16_t *disp, size_t count, float *out)
{
    if (!disp || !out)
        return CC_ERR_NULL;
    size_t i = 0;
#if CC_HAVE_X86
    if (cc_cpu_has_avx2())
        i = disparity_to_float_avx2(disp, count, out);
#endif
    const float scale = 1.0f / CC_DISP_SCALE; /* a power of two: the same as dividing */
    for (; i < count; i++)
        out[i] = disp[i] == CC_INVALID ? NAN : (float)disp[i] * scale;
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
    uint8_t *scratch = cc_alloc(cc_census_scratch_bytes(width));
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
        cc_frame_prepare(&f, &s, left, stride_left, right, stride_right, threads, scratch,
                         cc_frame_scratch_bytes(width));
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
