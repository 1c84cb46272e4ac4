/*
 * The rectified pixels of chosen cloud points, marked on images (cellctl.vision.sole_region): what numpy does
 * in some fifteen passes over ~3 10^5 points (gather, round, bounds, scatter, for each camera) in one.
 * Statuses are cloud_kernels.h's CK_* codes; nothing is allocated.
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

#endif
