/*
 * Passes over the rectified images for the sole's segmentation and outline checks, each one pass where numpy
 * makes many over the same elements: the rectified pixels of chosen cloud points marked on images
 * (cellctl.vision.sole_region), and the change mask's edge read along the outline's normals
 * (cellctl.vision.edge_checks.edge_offset_pair), the measured pixels of the matcher's map gathered for the
 * cloud (cellctl.vision.cloud), and the areas of labelled regions (cellctl.vision.footprint). Statuses are cloud_kernels.h's CK_* codes; nothing is allocated.
 */
#ifndef CELLCTL_PIXEL_MARKS_H
#define CELLCTL_PIXEL_MARKS_H

#include <stdint.h>

/*
 * pixels: n x 2 doubles (x, y) of the points in the rectified left image; disparity: n doubles (NULL: no
 * right image). index: the count points to mark (each in 0..n-1), or NULL for all n. For each point marked,
 * left[y * cols + x] = 1 at x = rint(px), y = rint(py), and right[y * cols + xr] = 1 at xr = rint(px - d)
 * (rint in the default rounding mode: to nearest, halves to even, as numpy's round); pixels off the image
 * (or not finite) are left out. The other bytes of left and right are not touched (the caller zeroes them).
 * right may be NULL when disparity is. Returns CK_OK, CK_ERR_NULL, CK_ERR_SIZE (n, count, rows or cols out
 * of range) or CK_ERR_RANGE (an index outside 0..n-1; nothing is guaranteed marked then).
 */
int pm_mark_pixels(const double *pixels, const double *disparity, int64_t n, const int64_t *index, int64_t count,
                   int64_t rows, int64_t cols, uint8_t *left, uint8_t *right);

/*
 * The change mask's step along n profiles of k samples each (cellctl.vision.edge_checks.edge_offset_pair):
 * sample j of profile i lies at the integer pixel (x, y) = (pixel[2 (i k + j)], pixel[2 (i k + j) + 1]).
 * A sample is known where it lies on the rows x cols mask `changed` (0/1 bytes), and its value is the mask's
 * there (unknown samples are unchanged); where level is given (n k bytes, NULL: none), a changed sample with
 * level[i k + j] != 0 and j >= first_out is unknown too (a changed pixel on the measured table outside the
 * outline: no evidence). The misfit of a step before sample j (j = 0..k) is the number of known unchanged
 * samples before j plus the known changed ones from j on. Out, per profile: inner[i] and outer[i], the first
 * and the last j of the least misfit, misfit[i] that misfit, known[i] the number of known samples.
 * Returns CK_OK, CK_ERR_NULL or CK_ERR_SIZE (n, k, rows, cols or first_out out of range).
 */
int pm_edge_profiles(const int64_t *pixel, int64_t n, int64_t k, const uint8_t *changed, int64_t rows, int64_t cols,
                     const uint8_t *level, int64_t first_out, int32_t *inner, int32_t *outer, int32_t *misfit,
                     int32_t *known);

/*
 * The measured pixels of the matcher's final map (cellctl.vision.cloud.cloud_from_disparity): fixed (rows x cols
 * int16, `invalid` where unmeasured) where texture (rows x cols float32) >= min_texture, in raster order.
 * pm_count_measured: their number (count). pm_gather_measured: for the n of them, flat[k] their index in the map,
 * pixels[2 k ..] = (x + x0, y + y0) and pixel_disparity[3 k ..] = (x + x0, y + y0, d) as doubles, with
 * disparity[k] = d = fixed / scale + shift in double (the operations and their order as numpy takes them).
 * Returns CK_OK, CK_ERR_NULL, CK_ERR_SIZE (rows, cols or scale out of range; n not the count).
 */
int pm_count_measured(const int16_t *fixed, const float *texture, int64_t rows, int64_t cols, int16_t invalid,
                      float min_texture, int64_t *count);
int pm_gather_measured(const int16_t *fixed, const float *texture, int64_t rows, int64_t cols, int16_t invalid,
                       float min_texture, int64_t x0, int64_t y0, double scale, double shift, int64_t n,
                       int64_t *flat, double *pixels, double *pixel_disparity, double *disparity);

/*
 * The number of cells of each label (cellctl.vision.footprint.largest_component): areas[l] for l = 0..count-1
 * counts the n labels equal to l (as np.bincount counts them). Returns CK_OK, CK_ERR_NULL, CK_ERR_SIZE (n or
 * count out of range) or CK_ERR_RANGE (a label outside 0..count-1).
 */
int pm_label_areas(const int32_t *labels, int64_t n, int32_t count, int64_t *areas);

#endif
