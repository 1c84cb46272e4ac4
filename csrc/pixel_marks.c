/* The rectified pixels of chosen cloud points, marked on images (pixel_marks.h). */
#include "pixel_marks.h"

#include <math.h>

#include "cloud_kernels.h"

/* Upper bound on an image side: far beyond any camera, small enough that rows * cols fits an int64_t. */
#define PM_MAX_SIDE ((int64_t)1 << 20)

/* Marks image[y * cols + x] if the rounded (x, y) lies on it. A rounded value is compared as a double before it
 * is converted: a NaN fails every comparison, and a value off the image is never converted (undefined in C). */
static inline void mark(uint8_t *image, double x, double y, int64_t rows, int64_t cols) {
    if (x >= 0.0 && x < (double)cols && y >= 0.0 && y < (double)rows)
        image[(int64_t)y * cols + (int64_t)x] = 1;
}

int pm_mark_pixels(const double *pixels, const double *disparity, int64_t n, const int64_t *index, int64_t count,
                   int64_t rows, int64_t cols, uint8_t *left, uint8_t *right) {
    if (!pixels || !left || (disparity && !right))
        return CK_ERR_NULL;
    if (n < 0 || rows < 1 || cols < 1 || rows > PM_MAX_SIDE || cols > PM_MAX_SIDE)
        return CK_ERR_SIZE;
    if (index && count < 0)
        return CK_ERR_SIZE;
    const int64_t total = index ? count : n;
    for (int64_t k = 0; k < total; ++k) {
        const int64_t i = index ? index[k] : k;
        if (i < 0 || i >= n)
            return CK_ERR_RANGE;
        const double px = pixels[2 * i], y = rint(pixels[2 * i + 1]);
        mark(left, rint(px), y, rows, cols);
        if (disparity)
            mark(right, rint(px - disparity[i]), y, rows, cols);
    }
    return CK_OK;
}
