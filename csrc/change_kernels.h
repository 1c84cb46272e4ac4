/*
 * The per-pixel work of the change test against the taught table (cellctl.vision.change, which keeps the
 * rules, their constants and the reasons; cellctl.stereo.change_kernels passes them in). numpy and OpenCV did
 * it in ~40 full-image passes and ~15 box blurs, most of the taught cycle's background stage.
 *
 * Bit-identical to that numpy/OpenCV code: every float32 operation is the one numpy does, in its order
 * (thresholds are the doubles Python computes, rounded to float32 as numpy rounds a Python float against a
 * float32 array), and each box mean is computed as OpenCV's cv2.blur computes it on float32 (border
 * BORDER_REFLECT_101; running sums in double along each row, then down each column over the whole height,
 * each output the double sum times 1 / (k * k), rounded to float32). Each box is streamed down the image by
 * one thread (its row sums in a ring of k + 1 rows, in cache); the threads share out the independent boxes of a
 * step and the rows of the per-pixel steps, so results do not depend on the thread count.
 *
 * Each entry point checks its arguments and returns a CHK_* status; nothing is allocated: scratch space comes
 * from the caller (chk_texture_scratch_bytes, chk_residual_scratch_bytes). `threads`: OpenMP threads (0: all OpenMP offers).
 */
#ifndef CELLCTL_CHANGE_KERNELS_H
#define CELLCTL_CHANGE_KERNELS_H

#include <stddef.h>
#include <stdint.h>

enum chk_status {
    CHK_OK = 0,
    CHK_ERR_NULL = 1,  /* a required pointer is NULL */
    CHK_ERR_SIZE = 2,  /* an image size, row stride, window, scratch size or thread count out of range */
    CHK_ERR_VALUE = 3  /* a parameter that is not finite or outside its range (gain <= 0, sigma <= 0) */
};

#define CHK_MAX_DIM 16384   /* largest image side */
#define CHK_MAX_WINDOW 255  /* largest box side (odd) */

/*
 * The rules' constants (cellctl.vision.change) and the fitted gain, offset and noise of one image. The
 * variance thresholds are squared by the caller, as numpy compares against the Python double.
 */
typedef struct {
    double gain, offset;          /* the taught prediction: gain x reference + offset */
    double gain_floor;            /* max(gain, 1e-6): the texture gain's divisor */
    int ncc_window;               /* NCC_WINDOW_PX */
    double table_ncc;             /* TABLE_NCC */
    double min_texture_gain;      /* MIN_TEXTURE_GAIN */
    double max_texture_gain;      /* MAX_TEXTURE_GAIN */
    double unanimous;             /* UNANIMOUS */
    double gone_share;            /* 1 - UNANIMOUS, as Python computes it */
    double min_textured_share;    /* MIN_TEXTURED_SHARE */
    double textured_variance;     /* (TEXTURE_SIGMAS sigma)^2 */
    double still_variance;        /* (STILL_TEXTURE_SIGMAS sigma)^2 */
    double fit_variance;          /* (FIT_SIGMAS sigma)^2 */
    double scale_agreement;       /* SCALE_AGREEMENT */
    double max_shadow_factor;     /* MAX_SHADOW_FACTOR */
    double max_carried_factor;    /* MAX_CARRIED_FACTOR */
    int illumination_window;      /* ILLUMINATION_WINDOW_PX; then its half (integer division) */
    double far_weight, near_weight; /* least still-table weight of the whole and the half window (0.05, 0.1) */
    int local_shadow_fit;         /* LOCAL_SHADOW_FIT */
    double min_local_fit_share;   /* MIN_LOCAL_FIT_SHARE */
    double raised_local_fit_share; /* RAISED_LOCAL_FIT_SHARE */
} chk_texture_params;

/* Bytes of scratch space for boxes up to window x window on `threads` threads (0: all OpenMP offers) over an
 * image of height x width (0 if out of range). chk_box_mean needs it for its window and one thread. */
size_t chk_scratch_bytes(int height, int width, int window, int threads);

/* Bytes of scratch space chk_texture needs with these rules and threads (0 if out of range). */
size_t chk_texture_scratch_bytes(int height, int width, const chk_texture_params *p, int threads);

/*
 * ChangeTest._texture: per pixel still table (0/1), texture gone (0/1), the illumination factor and the
 * share of textured windows (float32), as cellctl.vision.change defines them.
 * current, reference: float32 height x width images, rows `current_stride` / `reference_stride` floats apart,
 * finite values; raised: NULL or a 0/1 image, rows `raised_stride` bytes apart. Outputs: contiguous height x
 * width. scratch: chk_texture_scratch_bytes(height, width, p, threads) bytes, 8-byte aligned.
 */
int chk_texture(const float *current, int64_t current_stride, const float *reference, int64_t reference_stride,
                const uint8_t *raised, int64_t raised_stride, int height, int width, const chk_texture_params *p,
                uint8_t *still, uint8_t *gone, float *illumination, float *share, void *scratch,
                size_t scratch_bytes, int threads);

/*
 * The box mean of a float32 image over k x k (k 3..CHK_MAX_WINDOW) as cv2.blur computes it (see above), on
 * one thread, into a contiguous height x width float32 image (not the source). scratch:
 * chk_scratch_bytes(height, width, k, 1) bytes, 8-byte aligned. For the tests.
 */
int chk_box_mean(const float *src, int64_t src_stride, int height, int width, int k, float *dst, void *scratch,
                 size_t scratch_bytes);

/*
 * The pixel test of ChangeTest.changed, after the texture vote: the residual against the table as lit now,
 * residual = (current - predicted) - predicted (illumination - 1), predicted = gain x reference + offset;
 * raw (0/1) where |residual| exceeds `floor` and half a contrast, or where the texture is gone (gone, 0/1) and
 * the local contrast (the mean magnitude of the clear pixels, |residual| above floor, within contrast_window)
 * is fainter than faint_contrast or more than gone_inside of the pixels within gone_window passed the first
 * test. The contrast: where the pixel's residual has the sign of the window's summed clear residuals (the
 * change that dominates it), that change's brightness (the mean current value of the window's clear pixels
 * of that sign) less this pixel's table as lit now (current - residual), in magnitude; elsewhere the local
 * contrast.
 */
typedef struct {
    double gain, offset;
    double floor;           /* PIXEL_SIGMAS sigma */
    int contrast_window;    /* CONTRAST_WINDOW_PX */
    double faint_contrast;  /* FAINT_CONTRAST_SIGMAS sigma */
    int gone_window;        /* GONE_WINDOW_PX */
    double gone_inside;     /* GONE_INSIDE */
} chk_residual_params;

/* Bytes of scratch space chk_residual needs with these rules and threads (0 if out of range). */
size_t chk_residual_scratch_bytes(int height, int width, const chk_residual_params *p, int threads);

/*
 * current, reference as for chk_texture; illumination (float32, finite) and gone (0/1) contiguous height x
 * width, as chk_texture gives them. Out: residual (float32) and raw (0/1), contiguous height x width.
 */
int chk_residual(const float *current, int64_t current_stride, const float *reference, int64_t reference_stride,
                 const float *illumination, const uint8_t *gone, int height, int width, const chk_residual_params *p,
                 float *residual, uint8_t *raw, void *scratch, size_t scratch_bytes, int threads);

#endif
