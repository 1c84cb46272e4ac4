/*
 * Hot loops of the measurement after the match (cellctl.vision.outliers, cellctl.vision.subpixel):
 * per-point and per-patch arithmetic that numpy can only do in many full passes over ~10^5 elements.
 * Each entry point checks its arguments and returns a CK_* status; nothing is allocated. `threads`: the
 * OpenMP threads to use (0: all OpenMP offers; small calls stay on one). Every output element is computed
 * whole by one thread in a fixed arithmetic order, so the results are bit-identical for any thread count.
 */
#ifndef CELLCTL_CLOUD_KERNELS_H
#define CELLCTL_CLOUD_KERNELS_H

#include <stdint.h>

enum ck_status {
    CK_OK = 0,
    CK_ERR_NULL = 1,  /* a required pointer is NULL */
    CK_ERR_SIZE = 2,  /* a count, image size or thread count out of range */
    CK_ERR_RANGE = 3  /* an index outside its array (a point too near the grid's edge, unsorted patches) */
};

/*
 * Mean distance of each point to its 19 nearest grid neighbours among the 36 pixels within 3.2 px, as
 * cellctl.vision.outliers defines it (its first two cases; wider windows stay in Python).
 * grid: height x width x 3 float32 (x y z of the point seen at each pixel; NaN where none); at[i]: flat
 * pixel index of point i (its 3-px neighbourhood must lie inside the grid); spacing[i]: mm between pixels at the point.
 * offsets: 36 (dx, dy) pairs, the first 20 the block within 2.3 px, then 16 up to 3.2 px.
 * Out: mean[i] and exact[i]. Where the block is complete and its second-farthest is no farther than the
 * 16 others and 3.5 spacings, mean is the block's sum minus its farthest over 20 (float32, summed in block
 * order as numpy does) and exact 1. Else mean is the sum of the 19 nearest of the 36, each capped at 3.6
 * spacings, over 20 (double, stored as float32), and exact says whether those 19 lie within 0.95 x 3.6
 * spacings (else a wider window must decide).
 */
int ck_neighbour_means(const float *grid, int height, int width, const int64_t *at, int64_t count,
                       const double *spacing, const int32_t *offsets, float *mean, uint8_t *exact, int threads);

/*
 * One Gauss-Newton step of affine disparity patches (cellctl.vision.subpixel._gauss_newton_step):
 * pixels stored patch after patch, patch k = [starts[k], starts[k+1]). Per pixel: l_dev (left minus its
 * patch mean), right[2 i], right[2 i + 1] (right image and its x gradient at x - d, float32 pairs as a
 * two-channel remap gives them), dx, dy (from the patch centre);
 * per patch l_energy (sum of l_dev^2). Out: step (patches x 3, a b c); 0 for an empty patch.
 */
int ck_patch_step(int64_t patches, const int64_t *starts, const double *l_dev, const double *l_energy,
                  const float *right, const double *dx, const double *dy, double *step, int threads);

/*
 * Where each pixel's patch plane puts it in the right image: out[i] = x[i] - (a + b dx[i] + c dy[i]) with
 * (a, b, c) = params[3 k] of its patch, computed in double and stored as float32 (a remap's map).
 */
int ck_patch_shift(int64_t patches, const int64_t *starts, const double *params, const float *x,
                   const double *dx, const double *dy, float *out, int threads);

#endif
