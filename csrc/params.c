/* Parameter defaults, validation and the derived setup (rho tables). */
#include <math.h>
#include <string.h>

#include "aggregate.h"
#include "params.h"

void cc_params_default(cc_params *p)
{
    if (!p)
        return;
    memset(p, 0, sizeof *p);
    p->min_disparity = 0;
    p->num_disparities = 64;
    p->census_width = 5;
    p->census_height = 5;
    p->census_smooth = 0;
    p->census_threshold = 1;
    p->cost_mode = CC_COST_CENSUS_BT;
    p->lambda_census = 120.0f;
    p->lambda_bt = 20.0f;
    p->bt_prefilter = 31;
    p->cost_scale = 63;
    p->p1 = 32;
    p->p2 = 100;
    p->p2_gamma = 18;
    p->paths = 4;
    p->subpixel = 1;
    p->uniqueness = 30;
    p->lr_max_diff = CC_DISP_SCALE;
    p->fill_mode = CC_FILL_WEIGHTED;
    p->median = 3;
    p->fill_interpolate = 2;
    p->fill_radius = 15;
    p->border_fit = 24;
    p->weighted_median = 3;
    p->wm_sigma_colour = 12.0f;
    p->wm_sigma_space = 20.0f;
    p->threads = 0;
    p->simd = CC_SIMD_AUTO;
}

#define REJECT(msg)          \
    do {                     \
        if (message)         \
            *message = msg;  \
        return CC_ERR_PARAM; \
    } while (0)

int cc_params_check(const cc_params *p, const char **message)
{
    if (message)
        *message = "";
    if (!p)
        REJECT("parameters are NULL");
    if (p->num_disparities < 1 || p->num_disparities > CC_MAX_DISPARITIES)
        REJECT("num_disparities must be between 1 and 2048");
    if (p->min_disparity <= -CC_MAX_DIM || p->min_disparity >= CC_MAX_DIM)
        REJECT("min_disparity is out of range");
    if (p->census_width < 1 || p->census_width > 9 || p->census_width % 2 == 0)
        REJECT("census_width must be odd and between 1 and 9");
    if (p->census_height < 1 || p->census_height > 7 || p->census_height % 2 == 0)
        REJECT("census_height must be odd and between 1 and 7");
    if (p->census_smooth < 0 || p->census_smooth > 2)
        REJECT("census_smooth must be 0 (pixels), 1 (3x3 sums) or 2 (centre-weighted 3x3 sums)");
    if (p->census_threshold < 0 || p->census_threshold > 255)
        REJECT("census_threshold must be between 0 (binary census) and 255 (levels)");
    if (p->census_threshold > 0 && p->census_width * p->census_height > 32)
        REJECT("census_threshold > 0 (ternary census, 2 bits per neighbour) needs a census window of at most "
               "32 pixels, e.g. 5x5");
    if (p->cost_mode < CC_COST_CENSUS_BT || p->cost_mode > CC_COST_BT)
        REJECT("cost_mode must be census_bt, census or bt");
    if (p->cost_mode != CC_COST_BT && p->census_width * p->census_height < 2)
        REJECT("a census window needs at least 2 pixels");
    if (!(p->lambda_census > 0.0f) || !isfinite(p->lambda_census))
        REJECT("lambda_census must be a finite number > 0");
    if (!(p->lambda_bt > 0.0f) || !isfinite(p->lambda_bt))
        REJECT("lambda_bt must be a finite number > 0");
    if (p->bt_prefilter < 0 || p->bt_prefilter > 63)
        REJECT("bt_prefilter must be between 0 (raw intensities) and 63 (Sobel cap)");
    if (p->cost_scale < 1 || p->cost_scale > 127)
        REJECT("cost_scale must be between 1 and 127");
    if (p->p1 < 0)
        REJECT("p1 must be >= 0");
    if (p->p2 <= p->p1)
        REJECT("p2 must be greater than p1");
    if (p->p2 > CC_MAX_P2)
        REJECT("p2 must be <= 2000");
    if (p->p2_gamma < 0 || p->p2_gamma > 255)
        REJECT("p2_gamma must be between 0 (off) and 255");
    if (p->paths != 4 && p->paths != 8)
        REJECT("paths must be 4 or 8");
    if (p->subpixel != 0 && p->subpixel != 1)
        REJECT("subpixel must be 0 or 1");
    if (p->uniqueness < 0 || p->uniqueness > 99)
        REJECT("uniqueness must be between 0 (off) and 99 (% margin of the best cost)");
    if (p->lr_max_diff > 16 * CC_MAX_DISPARITIES)
        REJECT("lr_max_diff is out of range");
    if (p->fill_mode < CC_FILL_NONE || p->fill_mode > CC_FILL_WEIGHTED)
        REJECT("fill_mode must be none, background or weighted");
    if (p->median != 0 && p->median != 3 && p->median != 5)
        REJECT("median must be 0, 3 or 5");
    if (p->fill_interpolate < 0 || p->fill_interpolate > 64)
        REJECT("fill_interpolate must be between 0 (off) and 64 (px)");
    if (p->fill_radius < 1 || p->fill_radius > CC_MAX_WM_RADIUS)
        REJECT("fill_radius must be between 1 and 15 (px)");
    if (p->border_fit != 0 && (p->border_fit < 2 || p->border_fit > CC_MAX_BORDER_FIT))
        REJECT("border_fit must be 0 (off) or between 2 and 64 (px of measurements the line is fitted to)");
    if (p->weighted_median < 0 || p->weighted_median > CC_MAX_WM_RADIUS)
        REJECT("weighted_median must be between 0 (off) and 15 (window radius in px)");
    if (!(p->wm_sigma_colour > 0.0f) || !isfinite(p->wm_sigma_colour))
        REJECT("wm_sigma_colour must be a finite number > 0");
    if (!(p->wm_sigma_space > 0.0f) || !isfinite(p->wm_sigma_space))
        REJECT("wm_sigma_space must be a finite number > 0");
    if (p->threads < 0 || p->threads > 256)
        REJECT("threads must be between 0 (all) and 256");
    if (p->simd != CC_SIMD_AUTO && p->simd != CC_SIMD_SCALAR && p->simd != CC_SIMD_AVX2)
        REJECT("simd must be auto, scalar or avx2");
    return CC_OK;
}

int cc_cpu_has_avx512_lookup(void)
{
#if CC_HAVE_X86 && defined(__GNUC__)
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512vbmi") && __builtin_cpu_supports("avx512bitalg");
#else
    return 0;
#endif
}

int cc_cpu_has_avx2(void)
{
#if CC_HAVE_X86 && defined(__GNUC__)
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") ? 1 : 0;
#else
    return 0;
#endif
}

/* round(scale * (1 - exp(-c / lambda))), rounding halves up. */
static void fill_rho_table(uint8_t *table, double lambda, int scale)
{
    for (int c = 0; c < CC_LUT; c++)
        table[c] = (uint8_t)floor(scale * (1.0 - exp(-c / lambda)) + 0.5);
}

int cc_setup_init(cc_setup *s, const cc_params *p)
{
    int rc = cc_params_check(p, NULL);
    if (rc != CC_OK)
        return rc;
    memset(s, 0, sizeof *s);
    s->p = *p;
    s->D = p->num_disparities;
    s->Dp = (p->num_disparities + CC_LANES - 1) / CC_LANES * CC_LANES;
    s->use_avx2 = p->simd != CC_SIMD_SCALAR && cc_cpu_has_avx2();
    s->use_avx512 = p->simd == CC_SIMD_AUTO && s->use_avx2 && cc_cpu_has_avx512_lookup();
    if (p->cost_mode != CC_COST_BT)
        fill_rho_table(s->lut_census, p->lambda_census, p->cost_scale);
    if (p->cost_mode != CC_COST_CENSUS)
        fill_rho_table(s->lut_bt, p->lambda_bt, p->cost_scale);
    s->cmax = s->lut_census[CC_LUT - 1] + s->lut_bt[CC_LUT - 1];
    cc_p2_table(p, s->p2_by_step);
    return CC_OK;
}

int cc_check_images(const uint8_t *left, const uint8_t *right, int width, int height,
                    int stride_left, int stride_right, const cc_params *p)
{
    if (!left || !right)
        return CC_ERR_NULL;
    if (width < 1 || height < 1 || width > CC_MAX_DIM || height > CC_MAX_DIM)
        return CC_ERR_SIZE;
    if (stride_left < width || stride_right < width)
        return CC_ERR_SIZE;
    /* A range that reaches past the image on either side matches nothing. */
    if (p->num_disparities > width || p->min_disparity >= width ||
        p->min_disparity + p->num_disparities - 1 <= -width)
        return CC_ERR_RANGE;
    return CC_OK;
}
