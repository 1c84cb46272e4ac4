/* Internal declarations shared by the core's translation units. */
#ifndef CELLCTL_INTERNAL_H
#define CELLCTL_INTERNAL_H

#include "cellctl_core.h"

#define CC_LANES 16          /* uint16 lanes of one AVX2 vector; Dp is a multiple */
#define CC_GUARD 16          /* guard lanes before and after each stored path vector */
#define CC_LUT 64            /* rho tables cover indices 0..63 */
#define CC_PATH_INF 0xFFFFu  /* path cost of a disparity that does not exist */

#if defined(__x86_64__) || defined(__i386__)
#define CC_HAVE_X86 1
#else
#define CC_HAVE_X86 0
#endif

/* A fixed-point disparity (x16) rounded to the nearest whole pixel, halves up, for any sign. */
static inline int cc_whole_px(int d16)
{
    int v = d16 + CC_DISP_SCALE / 2;
    return v >= 0 ? v / CC_DISP_SCALE : -((-v + CC_DISP_SCALE - 1) / CC_DISP_SCALE);
}

/* v rounded up to a multiple of a. */
static inline size_t cc_round_up(size_t v, size_t a) { return (v + a - 1) / a * a; }

/* The two images prepared for the cost: census bytes and BT bounds.  The right
 * image is stored mirrored and padded per row so that, for a left pixel x, the
 * right pixels x - d of consecutive d are consecutive in memory. */
typedef struct cc_frame {
    int width, height;
    int nbytes;              /* census bytes per pixel */
    int pad, rstride;        /* mirrored right rows: index pad + (width-1-x) */
    uint8_t *lcen;           /* [nbytes][height][width] */
    uint8_t *lint, *lmin, *lmax;            /* [height][width]: the BT image and its bounds */
    uint8_t *lgrey;                         /* [height][width]: left intensities (adaptive P2) */
    uint8_t *rcen;           /* [nbytes][height][rstride] */
    uint8_t *rint, *rmin, *rmax;            /* [height][rstride]: the BT image and its bounds */
} cc_frame;

/* Everything the kernels need, derived once from the parameters. */
typedef struct cc_setup {
    cc_params p;
    int D, Dp;               /* disparity count and its padded count */
    int cmax;                /* largest fused cost */
    int use_avx2;
    uint8_t lut_census[CC_LUT];
    uint8_t lut_bt[CC_LUT];
    uint16_t p2_by_step[256];
} cc_setup;

int cc_setup_init(cc_setup *s, const cc_params *p);
int cc_check_images(const uint8_t *left, const uint8_t *right, int width, int height,
                    int stride_left, int stride_right, const cc_params *p);
int cc_cpu_has_avx2(void);

/* frame.c */
size_t cc_frame_bytes(const cc_setup *s, int width, int height);
int cc_frame_alloc(cc_frame *f, const cc_setup *s, int width, int height);
void cc_frame_free(cc_frame *f);
size_t cc_frame_scratch_bytes(int width);
void cc_frame_prepare(cc_frame *f, const cc_setup *s, const uint8_t *left, int stride_left,
                      const uint8_t *right, int stride_right, int threads, uint8_t *scratch);
/* scratch: 9 * width + 8 bytes */
void cc_census_row(const uint8_t *img, int width, int height, int stride, int cw, int ch,
                   int y, uint64_t *out, uint8_t *scratch);

/* cost.c: fused costs of pixels x0..x1-1 of row y, pixel x at out + (x - x0) * stride,
 * all disparities (Dp values, writing up to 32 bytes of slack past the last). */
void cc_cost_segment(const cc_setup *s, const cc_frame *f, int x0, int x1, int y, uint8_t *out, size_t stride);

/* aggregate.c */
uint16_t cc_path_step(const cc_setup *s, const uint8_t *cost, const uint16_t *prev,
                      uint16_t prev_min, int p2, uint16_t *out,
                      const uint16_t *acc_in, uint16_t *acc_out);
/* P2 for every intensity step |I(p) - I(p-r)|: P2 * g / (g + step), never below P1
 * (constant P2 when g = 0); a table so the hot loops do no division. */
void cc_p2_table(const cc_params *p, uint16_t table[256]);
static inline int cc_p2_for_step(const cc_setup *s, int intensity, int prev_intensity)
{
    return s->p2_by_step[intensity > prev_intensity ? intensity - prev_intensity : prev_intensity - intensity];
}

/* Buffers of one matcher for one image size; see cc_workspace_* in matcher.c. */
typedef struct cc_workspace {
    int width, height, threads;
    uint16_t *volume;        /* aggregated cost S, [height][width][Dp] */
    uint16_t *vpath;         /* vertical/diagonal paths: [paths][2 rows][width][vstride] */
    uint16_t *vmin;          /* their minima: [paths][2 rows][width] */
    size_t vstride;          /* Dp + 2 guards */
    uint8_t *scratch;        /* per thread: see cc_thread_scratch */
    size_t scratch_stride;
} cc_workspace;

/* Per-thread scratch of pass 3 and the selection. */
typedef struct cc_thread_scratch {
    uint8_t *cost_row;       /* [width][Dp] + slack */
    uint16_t *sum_row;       /* [width][Dp] */
    uint16_t *hpath[2];      /* two pixels' path vectors with guards */
    uint16_t *select_tmp;    /* [width] */
} cc_thread_scratch;

size_t cc_thread_scratch_bytes(const cc_setup *s, int width);
cc_thread_scratch cc_thread_scratch_at(const cc_setup *s, const cc_workspace *ws, int thread);

/* passes.c */
void cc_pass_vertical(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int downward);
void cc_pass_rows(const cc_setup *s, const cc_frame *f, cc_workspace *ws, int16_t *raw_left,
                  int16_t *raw_right, uint16_t *volume_out);

/* select.c */
/* tmp: cc_select_tmp_bytes(s, width) bytes */
size_t cc_select_tmp_bytes(const cc_setup *s, int width);
void cc_select_row(const cc_setup *s, const uint16_t *row, int stride, int width,
                   int16_t *left_out, int16_t *right_out, uint16_t *tmp);

/* weighted_median.c */
#define CC_WM_COLOURS (3 * 255 + 1)                                  /* summed channel differences */
#define CC_WM_SPACES (2 * CC_MAX_WM_RADIUS * CC_MAX_WM_RADIUS + 1)   /* squared distances */
typedef struct cc_wm_tables {
    uint16_t colour[CC_WM_COLOURS];
    uint16_t space[CC_WM_SPACES];
    uint16_t gather_pad[2];   /* the vector kernel reads 32 bits at each 16-bit entry */
} cc_wm_tables;
typedef struct cc_wm_image {  /* the guide: 1 or 3 interleaved 8-bit channels */
    const uint8_t *data;
    int width, height, channels;
    size_t stride;
    const uint32_t *packed;   /* optional: channels packed per pixel (B | G << 8 | R << 16), 8 px slack */
    int use_avx2;             /* the vector kernel may read `packed` */
} cc_wm_image;
/* Pack row y of the guide into out[0..width) (grey counts as three equal channels). */
void cc_wm_pack_row(const cc_wm_image *g, int y, uint32_t *out);
typedef struct cc_wm_hist {   /* per thread, one entry per disparity level, kept zero between pixels */
    int64_t *value;
    uint32_t *weight;
} cc_wm_hist;
void cc_wm_tables_init(cc_wm_tables *t, float sigma_colour, float sigma_space);
size_t cc_wm_hist_bytes(int levels);
cc_wm_hist cc_wm_hist_at(void *base, int levels);
void cc_wm_hist_clear(cc_wm_hist *h, int levels);
#define CC_WM_NO_LEVEL 0xFFFF
/* Histogram level of a disparity: rounded to whole px, clamped to the range; CC_WM_NO_LEVEL if invalid. */
int cc_wm_level(int v, int dmin, int levels);
/* Weighted median at (x, y) of `map`, whose levels (cc_wm_level) are in `level`. */
int16_t cc_wm_pixel(const cc_wm_tables *t, const cc_wm_image *g, const int16_t *map,
                    const uint16_t *level, int x, int y, int radius, cc_wm_hist *h);

/* postprocess.c: `scratch` holds cc_postprocess_scratch_bytes (one map and a histogram per thread). */
size_t cc_postprocess_scratch_bytes(const cc_params *p, int width, int height, int threads);
void cc_postprocess_maps(const cc_params *p, const int16_t *raw_left, const int16_t *raw_right,
                         const cc_wm_image *guide, int width, int height, int16_t *checked,
                         int16_t *filled, int16_t *disp, void *scratch, int threads);

/* memory helpers (matcher.c) */
void *cc_alloc(size_t bytes);
void cc_free(void *ptr);
int cc_thread_count(const cc_params *p);

#endif
