/*
 * cellctl matching core: Census + Birchfield-Tomasi cost, semi-global
 * aggregation, winner-takes-all, left-right check, fill and median.
 *
 * Conventions follow OpenCV's StereoSGBM: left(x, y) matches right(x - d, y);
 * disparities are int16 fixed point with 4 fractional bits (value = d * 16);
 * CC_INVALID marks pixels without a disparity.  Every entry point checks its
 * arguments and returns a CC_* status instead of touching memory it was not
 * given.  Images are 8-bit grey, row-major, with an explicit row stride.
 */
#ifndef CELLCTL_CORE_H
#define CELLCTL_CORE_H

#include <stddef.h>
#include <stdint.h>

#define CC_DISP_SCALE 16
#define CC_INVALID (-32768)

enum cc_status {
    CC_OK = 0,
    CC_ERR_NULL = 1,        /* a required pointer is NULL */
    CC_ERR_SIZE = 2,        /* image size or stride out of range */
    CC_ERR_PARAM = 3,       /* a parameter out of range; see cc_param_error */
    CC_ERR_NOMEM = 4,       /* a buffer could not be allocated */
    CC_ERR_RANGE = 5        /* the disparity range does not fit the image */
};

enum cc_cost_mode { CC_COST_CENSUS_BT = 0, CC_COST_CENSUS = 1, CC_COST_BT = 2 };
enum cc_fill_mode { CC_FILL_NONE = 0, CC_FILL_BACKGROUND = 1, CC_FILL_WEIGHTED = 2 };
/* AUTO: the widest kernels the CPU runs (AVX-512 for the cost where it has BW, VL, VBMI and BITALG, else
 * AVX2); SCALAR: the portable ones; AVX2: the AVX2 ones even where AVX-512 ones could run (tests). */
enum cc_simd_mode { CC_SIMD_AUTO = 0, CC_SIMD_SCALAR = 1, CC_SIMD_AVX2 = 2 };

typedef struct cc_params {
    int min_disparity;      /* may be negative */
    int num_disparities;    /* any count >= 1 */
    int census_width;       /* odd, 1..9 */
    int census_height;      /* odd, 1..7 */
    int census_smooth;      /* 0: census of the pixels; 1: of their 3x3 sums (robust in flat regions) */
    int census_threshold;   /* 0: binary census (centre >= neighbour); t > 0: ternary census, 2 bits per
                               neighbour, a pair differing by fewer than t levels counts as similar
                               (window of at most 32 pixels) */
    int cost_mode;          /* enum cc_cost_mode */
    float lambda_census;    /* rho scale of the Hamming distance (bits), > 0 */
    float lambda_bt;        /* rho scale of the BT cost (levels of the BT image), > 0 */
    int bt_prefilter;       /* BT image: 0 = raw intensities; 1..63 = horizontal Sobel clipped to
                               [-cap, cap] (OpenCV's preFilterCap), robust to gain and exposure */
    int cost_scale;         /* each rho term is quantised to 0..cost_scale (1..127) */
    int p1;                 /* penalty for a disparity step of 1 */
    int p2;                 /* penalty for larger steps, p1 < p2 <= CC_MAX_P2 */
    int p2_gamma;           /* 0: constant P2; >0: P2 * g / (g + |dI|), never below p1 */
    int paths;              /* 4 or 8 */
    int subpixel;           /* parabola refinement of the left disparity */
    int uniqueness;         /* % margin the best cost must keep below every cost > 1 level away,
                               else the left pixel is invalid (as StereoSGBM's uniquenessRatio), 0..99 */
    int lr_max_diff;        /* left-right tolerance in 1/16 px; < 0 disables the check */
    int fill_mode;          /* enum cc_fill_mode */
    int median;             /* 0 (off), 3 or 5 */
    int fill_interpolate;   /* fill: a run between two valid pixels at most this many px apart in
                               disparity is interpolated linearly (one surface), else background; 0 off */
    int fill_radius;        /* CC_FILL_WEIGHTED: window radius of the weighted median over filled pixels */
    int border_fit;         /* fill: border-occluded end strips of a row follow a line fitted to the
                               next border_fit px of measurements (0: the nearest value), 0 or 2..64 */
    int weighted_median;    /* radius of the final colour-weighted median, 0 (off)..CC_MAX_WM_RADIUS */
    float wm_sigma_colour;  /* weighted medians: colour scale (summed |dB|+|dG|+|dR|), > 0 */
    float wm_sigma_space;   /* weighted medians: distance scale in px, > 0 */
    int threads;            /* 0: all available */
    int simd;               /* enum cc_simd_mode */
} cc_params;

#define CC_MAX_P2 2000
#define CC_MAX_DISPARITIES 2048
#define CC_MAX_DIM 16384
#define CC_MAX_WM_RADIUS 15 /* largest weighted-median window: 31 x 31 */
#define CC_MAX_BORDER_FIT 64

/* Fills *p with the defaults (tuned on Middlebury 2001/2003 + 2005/2006, see docs/benchmarks.md). */
void cc_params_default(cc_params *p);
/* CC_OK or CC_ERR_PARAM; on error a static message is stored in *message. */
int cc_params_check(const cc_params *p, const char **message);

typedef struct cc_matcher cc_matcher;

/* A matcher owns its buffers and reuses them across calls of the same size. */
int cc_matcher_create(const cc_params *p, cc_matcher **out);
void cc_matcher_destroy(cc_matcher *m);
/* Bytes currently held by the matcher's buffers (the cost volume and rows). */
size_t cc_matcher_bytes(const cc_matcher *m);
/* 1 when the AVX2 kernels are in use, 0 for the portable ones. */
int cc_matcher_simd(const cc_matcher *m);

/*
 * Full pipeline.  `disp` receives the final map (width*height int16).  `guide`
 * is the left image the weighted medians compare colours in: 8-bit, 1 (grey)
 * or 3 (BGR) interleaved channels, `stride_guide` bytes per row; NULL uses the
 * grey left image.  The optional stage outputs (NULL to skip) are: raw_left
 * (WTA + sub-pixel), raw_right (WTA of the right view, integer), checked
 * (raw_left after the left-right check) and filled (after the fill, before the
 * medians).
 */
int cc_matcher_compute(cc_matcher *m, const uint8_t *left, const uint8_t *right,
                       int width, int height, int stride_left, int stride_right,
                       const uint8_t *guide, int guide_channels, int stride_guide,
                       int16_t *disp, int16_t *raw_left, int16_t *raw_right,
                       int16_t *checked, int16_t *filled);

/* Fixed-point disparities (x16, CC_INVALID) to float pixels with NaN where invalid: out[i] = disp[i] / 16. */
int cc_disparity_to_float(const int16_t *disp, size_t count, float *out);

/* ---- Stage entry points: the same code the pipeline runs, for tests and tools. ---- */

/* Census bit string per pixel (bit i = centre >= i-th neighbour in raster order). */
int cc_census(const uint8_t *img, int width, int height, int stride,
              int census_width, int census_height, uint64_t *out);
/* Fused matching cost volume, layout [y][x][d], num_disparities per pixel. */
int cc_cost_volume(const cc_params *p, const uint8_t *left, const uint8_t *right,
                   int width, int height, int stride_left, int stride_right, uint8_t *out);
/* Aggregated cost S (sum over paths), layout [y][x][d]. */
int cc_aggregate(cc_matcher *m, const uint8_t *left, const uint8_t *right,
                 int width, int height, int stride_left, int stride_right, uint16_t *out);
/* WTA of an aggregated volume: left (sub-pixel) and right (integer) maps. */
int cc_select(const cc_params *p, const uint16_t *volume, int width, int height,
              int16_t *raw_left, int16_t *raw_right);
/* Left-right check, fill and medians on raw maps, as the pipeline does; the
 * guide (see cc_matcher_compute) is required only by the weighted stages. */
int cc_postprocess(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                   const uint8_t *guide, int guide_channels, int stride_guide,
                   int width, int height, int16_t *checked, int16_t *filled, int16_t *disp);

#endif
