/*
 * Hot loops of the measurement after the match (cellctl.vision.outliers, cellctl.vision.subpixel,
 * cellctl.vision.surface): per-point and per-patch arithmetic that numpy can only do in many full passes
 * over ~10^5 elements, and neighbour searches that would otherwise be a Python loop over a k-d tree.
 * Each entry point checks its arguments and returns a CK_* status; nothing is allocated (scratch space
 * comes from the caller). `threads`: the OpenMP threads to use (0: all OpenMP offers; small calls stay on
 * one). Every output element is computed whole by one thread in a fixed arithmetic order, so the results
 * are bit-identical for any thread count.
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
 * The wider windows of cellctl.vision.outliers (for the points ck_neighbour_means leaves inexact): per point,
 * for each window half h in halves (increasing, 1..CK_MAX_HALF), the 19 nearest of the (2h + 1)^2 - 1
 * pixels around it (float32 distances as ck_neighbour_means takes them, NaN = none = infinite), each capped
 * at (h + 1) spacings (what lies outside the window is at least that far), summed in double over 20 and
 * stored as float32 in mean; the point is settled (settled[i] 1, no wider window) once its 19 nearest lie
 * within 0.95 x (h + 1) spacings. An unsettled point keeps the widest window's mean (settled 0: its
 * neighbours lie anywhere, a k-d tree must decide). Each window is searched as the previous one plus its
 * ring, keeping the 19 smallest so far. at[i]: flat pixel index of point i, its widest window inside the grid.
 */
#define CK_MAX_HALF 255
int ck_window_means(const float *grid, int height, int width, const int64_t *at, int64_t count,
                    const double *spacing, const int32_t *halves, int n_halves, float *mean, uint8_t *settled,
                    int threads);

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

/*
 * A cell grid of points in a plane (the sole's points seen from above, cellctl.vision.surface): the points
 * of cell (row, col) are order[starts[row * cols + col] .. starts[row * cols + col + 1]), cell (row, col)
 * covering [x0 + col * cell, x0 + (col + 1) * cell) and the same in y. A radius query of a point reads only
 * the cells the radius reaches; within them a point counts when its squared distance in double,
 * (qx - x)^2 + (qy - y)^2, is below radius^2 (as a k-d tree's radius search takes it).
 *
 * ck_grid_build: the counting sort of n points (x, y) into the grid; every point must fall inside it.
 * Out: order (n, point indices cell after cell, ascending within a cell) and starts (rows * cols + 1).
 */
int ck_grid_build(const double *x, const double *y, int64_t n, double x0, double y0, double cell, int64_t cols,
                  int64_t rows, int64_t *order, int64_t *starts);

/*
 * The grid's points within `radius` of each of the `count` queries (qx, qy): how many (counts), and with
 * `offsets` (count + 1, the counts' running sum) and `found` (offsets[count] entries) which ones, query k's
 * in found[offsets[k] .. offsets[k + 1]) in cell order (found NULL: counts only). gx, gy: the points'
 * coordinates in grid order (x[order[i]]), gi: their indices (order).
 */
int ck_grid_radius(const double *gx, const double *gy, const int64_t *gi, const int64_t *starts, double x0,
                   double y0, double cell, int64_t cols, int64_t rows, const double *qx, const double *qy,
                   int64_t count, double radius, int64_t *counts, const int64_t *offsets, int64_t *found,
                   int threads);

/*
 * The median of the heights gz (in grid order, finite) of the grid's points within `radius` of each query,
 * as numpy's median takes it (the mean of the two middle values; one for an odd count), NaN where none.
 * offsets: count + 1, the running sum of the queries' counts (ck_grid_radius); scratch: offsets[count]
 * doubles. A query with more points than its slot is refused (CK_ERR_RANGE).
 */
int ck_grid_radius_medians(const double *gx, const double *gy, const double *gz, const int64_t *starts, double x0,
                           double y0, double cell, int64_t cols, int64_t rows, const double *qx, const double *qy,
                           int64_t count, double radius, const int64_t *offsets, double *scratch, double *medians,
                           int threads);

/*
 * Per cell of the grid, the value of rank floor(n / 2) among its n points' values gz (in grid order,
 * finite): the median for an odd count, the upper of the two middle values for an even one; NaN for an
 * empty cell. scratch: starts[cells] doubles. out: cells.
 */
int ck_cell_upper_medians(const double *gz, const int64_t *starts, int64_t cells, double *scratch, double *out,
                          int threads);

/*
 * Where each point lies against a closed polygon, as OpenCV's pointPolygonTest (measureDist false, float32
 * contour) answers for it: 1 inside, -1 outside, 0 on an edge or vertex (the same crossing rule and the
 * same float32 differences and double products). polygon: n vertices (x, y float32); points: m (x, y
 * float32), sorted by y; out: m. Each point meets only the edges whose y span holds it (one thread: every
 * edge updates the points of its rows).
 */
int ck_points_in_polygon(const float *polygon, int64_t n, const float *points, int64_t m, int8_t *out);

/*
 * Bicubic samples of a two-channel image on whole rows, where each patch pixel's plane puts it (x - (a + b dx
 * + c dy), as ck_patch_shift rounds it to float32): Keys' cubic convolution with a = -0.75 (OpenCV's
 * INTER_CUBIC weights, here from the exact fraction of x in float32), border columns replicated
 * (BORDER_REPLICATE). It agrees with cv2.remap at an integer y to ~2e-6 of the value: OpenCV quantises and
 * orders its arithmetic differently. A NaN position samples column 0. image: height x width x 2 float32
 * (value, x gradient); rows[i] in 0..height-1; out: pixels x 2. simd: 1 to use the AVX2 kernel where the CPU
 * has it (the same bits: the same operations in the same order, no fused multiply-adds), 0 for the scalar one.
 */
int ck_patch_sample(int64_t patches, const int64_t *starts, const double *params, const float *x, const double *dx,
                    const double *dy, const int32_t *rows, const float *image, int height, int width, float *out,
                    int simd, int threads);

/*
 * Points on a raster of the table plane (cellctl.vision.footprint.Footprint): point i at (xy[i * stride],
 * xy[i * stride + 1]) lies in cell (floor((y - y0) / cell), floor((x - x0) / cell)) of a rows x cols raster,
 * computed in double as numpy computes it; points outside the raster (or NaN) are in none.
 * ck_cell_counts: out (rows x cols float32, overwritten) counts the points of each cell.
 * ck_cells_marked: out[i] = 1 where point i's cell is non-zero in mask (rows x cols uint8), else 0.
 * stride: doubles from one point to the next (2 for N x 2 rows, 3 for x y z rows), at least 2.
 */
int ck_cell_counts(const double *xy, int64_t n, int64_t stride, double x0, double y0, double cell, int64_t rows,
                   int64_t cols, float *out);
int ck_cells_marked(const double *xy, int64_t n, int64_t stride, double x0, double y0, double cell,
                    const uint8_t *mask, int64_t rows, int64_t cols, uint8_t *out);

/*
 * Binary dilation of a raster by a disc made of centred runs (OpenCV's elliptic structuring element, or any
 * element whose row d, -reach..reach, is the run of columns -half[d + reach]..half[d + reach]): out = 1 where
 * a source cell lies within the disc around the cell (the complement with invert 1), else 0. Sources: the
 * non-zero cells of mask (of_zero 0) or its zero cells (of_zero 1: the complement's dilation, i.e. an
 * erosion); cells off the raster are never sources, as OpenCV's default border makes them for a dilation and
 * (complemented) for an erosion. mask, out: rows x cols; half: 2 reach + 1 runs; scratch: rows x cols.
 */
#define CK_MAX_RASTER 20000
int ck_disc_dilate(const uint8_t *mask, int64_t rows, int64_t cols, int of_zero, const int32_t *half, int32_t reach,
                   int invert, uint8_t *out, int16_t *scratch);

#endif
