/* Passes over the rectified images for the segmentation and the outline checks (pixel_marks.h). */
#include "pixel_marks.h"

#include <math.h>
#include <stddef.h>

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

/* Profile samples are at most this many (EDGE_SEARCH_MM / EDGE_SEARCH_STEP_MM is 33): a misfit fits an int32_t. */
#define PM_MAX_SAMPLES ((int64_t)1 << 20)

/* Sample j of a profile: 1 changed, 0 unchanged, -1 unknown (off the mask, or excused on a table-level cell). */
static inline int sample_state(const int64_t *at, const uint8_t *changed, int64_t rows, int64_t cols,
                               const uint8_t *level, int64_t j, int64_t first_out) {
    const int64_t x = at[2 * j], y = at[2 * j + 1];
    if (x < 0 || x >= cols || y < 0 || y >= rows)
        return -1;
    if (!changed[y * cols + x])
        return 0;
    return level && level[j] && j >= first_out ? -1 : 1;
}

int pm_edge_profiles(const int64_t *pixel, int64_t n, int64_t k, const uint8_t *changed, int64_t rows, int64_t cols,
                     const uint8_t *level, int64_t first_out, int32_t *inner, int32_t *outer, int32_t *misfit,
                     int32_t *known) {
    if (!pixel || !changed || !inner || !outer || !misfit || !known)
        return CK_ERR_NULL;
    if (n < 0 || k < 1 || k > PM_MAX_SAMPLES || n > INT64_MAX / (2 * k) || rows < 1 || cols < 1 ||
        rows > PM_MAX_SIDE || cols > PM_MAX_SIDE || first_out < 0 || first_out > k)
        return CK_ERR_SIZE;
    for (int64_t i = 0; i < n; ++i) {
        const int64_t *at = pixel + 2 * i * k;
        const uint8_t *lv = level ? level + i * k : NULL;
        int32_t on = 0, count = 0;
        for (int64_t j = 0; j < k; ++j) {
            const int s = sample_state(at, changed, rows, cols, lv, j, first_out);
            on += s == 1;
            count += s >= 0;
        }
        /* The step before sample j, j = 0..k: `before` known unchanged samples in front, `after` changed from j. */
        int32_t before = 0, after = on, best = INT32_MAX, first = 0, last = 0;
        for (int64_t j = 0; j <= k; ++j) {
            const int32_t m = before + after;
            if (m < best) {
                best = m;
                first = (int32_t)j;
            }
            if (m == best)
                last = (int32_t)j;
            if (j < k) {
                const int s = sample_state(at, changed, rows, cols, lv, j, first_out);
                before += s == 0;
                after -= s == 1;
            }
        }
        inner[i] = first;
        outer[i] = last;
        misfit[i] = best;
        known[i] = count;
    }
    return CK_OK;
}

/* The map's size as the matcher's (and any crop of it): within PM_MAX_SIDE a side, origin within it too. */
static int measured_args(const int16_t *fixed, const float *texture, int64_t rows, int64_t cols) {
    if (!fixed || !texture)
        return CK_ERR_NULL;
    if (rows < 1 || cols < 1 || rows > PM_MAX_SIDE || cols > PM_MAX_SIDE)
        return CK_ERR_SIZE;
    return CK_OK;
}

int pm_count_measured(const int16_t *fixed, const float *texture, int64_t rows, int64_t cols, int16_t invalid,
                      float min_texture, int64_t *count) {
    const int rc = measured_args(fixed, texture, rows, cols);
    if (rc != CK_OK)
        return rc;
    if (!count)
        return CK_ERR_NULL;
    int64_t n = 0;
    for (int64_t i = 0; i < rows * cols; ++i)
        n += fixed[i] != invalid && texture[i] >= min_texture;
    *count = n;
    return CK_OK;
}

int pm_gather_measured(const int16_t *fixed, const float *texture, int64_t rows, int64_t cols, int16_t invalid,
                       float min_texture, int64_t x0, int64_t y0, double scale, double shift, int64_t n,
                       int64_t *flat, double *pixels, double *pixel_disparity, double *disparity) {
    const int rc = measured_args(fixed, texture, rows, cols);
    if (rc != CK_OK)
        return rc;
    if (!flat || !pixels || !pixel_disparity || !disparity)
        return CK_ERR_NULL;
    if (!(scale > 0.0) || n < 0 || x0 < -PM_MAX_SIDE || x0 > PM_MAX_SIDE || y0 < -PM_MAX_SIDE || y0 > PM_MAX_SIDE)
        return CK_ERR_SIZE;
    int64_t k = 0;
    for (int64_t y = 0; y < rows; ++y) {
        for (int64_t x = 0; x < cols; ++x) {
            const int64_t i = y * cols + x;
            if (fixed[i] == invalid || !(texture[i] >= min_texture))
                continue;
            if (k == n)
                return CK_ERR_SIZE; /* more measured pixels than the caller counted */
            const double px = (double)(x + x0), py = (double)(y + y0);
            const double d = (double)fixed[i] / scale + shift;
            flat[k] = i;
            pixels[2 * k] = px;
            pixels[2 * k + 1] = py;
            pixel_disparity[3 * k] = px;
            pixel_disparity[3 * k + 1] = py;
            pixel_disparity[3 * k + 2] = d;
            disparity[k] = d;
            ++k;
        }
    }
    return k == n ? CK_OK : CK_ERR_SIZE;
}

int pm_label_areas(const int32_t *labels, int64_t n, int32_t count, int64_t *areas) {
    if (!labels || !areas)
        return CK_ERR_NULL;
    if (n < 0 || count < 1)
        return CK_ERR_SIZE;
    for (int32_t l = 0; l < count; ++l)
        areas[l] = 0;
    for (int64_t i = 0; i < n; ++i) {
        const int32_t l = labels[i];
        if (l < 0 || l >= count)
            return CK_ERR_RANGE;
        ++areas[l];
    }
    return CK_OK;
}
