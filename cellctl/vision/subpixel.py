"""Sub-pixel disparity of small surface patches by direct image alignment (Lucas-Kanade on a disparity plane).

Why this exists: the matcher's parabola fit locks disparities towards whole pixels on weakly textured
soles, and the semi-global smoothing leaves correlated errors of ~0.1 px over areas of several mm. At 550 mm
one pixel of disparity is ~3.6 mm of height, so a height needs ~0.03 px. A patch of a smooth surface has an
affine disparity d(x, y) = a + b (x - cx) + c (y - cy) in rectified images (exact for a plane); fitting
(a, b, c) by Gauss-Newton to several hundred pixels of the rectified pair removes both the locking and the
smoothing error. Patches are solved together (per-patch normal equations by bincount), coarse to fine
(images blurred, then sharp) so that start errors of a few tenths of a pixel converge.

OpenCV has sparse pyramidal LK (calcOpticalFlowPyrLK) but it tracks a constant 2-D shift per window, with
no mask for the sole's edge and no plane model, which is what a patch on a sloped sole needs.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.stereo.kernels import patch_sample, patch_shift, patch_step

BLUR_LEVELS: tuple[tuple[float, int], ...] = ((2.0, 4), (1.0, 3), (0.0, 3))  # (Gaussian sigma px, iterations)
MIN_PATCH_PIXELS = 40
MAX_STEP_PX = 0.5  # per iteration: larger updates mean the linearisation does not hold
# The step kernels run on one thread: ~2 ms per call, and measured on 2 cores a second thread gained nothing
# (the remaps and blurs between them already use both cores through OpenCV's own threads).
KERNEL_THREADS = 1


@dataclass
class PatchFit:
    """Affine disparity per patch: d = a + b (x - cx) + c (y - cy) for pixels (x, y) of the rectified left image."""

    params: np.ndarray  # K x 3 (a, b, c)
    ok: np.ndarray  # K bool: converged with enough textured pixels
    ids: np.ndarray  # the pixels used, patch after patch: patch of each (N, sorted)...
    xy: np.ndarray  # ... and its (x, y) (N x 2)

    @property
    def pixels(self) -> list[np.ndarray]:
        """Per patch, the (x, y) pixels used (M_k x 2): split when asked (the fit itself never needs them)."""
        return np.split(self.xy, np.cumsum(np.bincount(self.ids, minlength=len(self.params)))[:-1])

    def disparities(self, centres: np.ndarray) -> np.ndarray:
        """The fitted disparity at every pixel of `xy` (N), for patch centres K x 2."""
        # Rows gathered with np.take: the same rows as indexing, ~3 x faster on ~10^5 of them.
        a, b, c = np.take(self.params, self.ids, axis=0).T
        offset = self.xy - np.take(np.asarray(centres, np.float64), self.ids, axis=0)
        return a + b * offset[:, 0] + c * offset[:, 1]


class PatchSums:
    """Per-patch sums over pixels stored patch after patch (ids sorted), by np.add.reduceat.

    One reduceat over a (m, N) array does m sums at once; bincount with weights does one sum per call
    over scattered ids, several times slower for the ~10^5 pixels of a cycle's patches.
    """

    def __init__(self, ids: np.ndarray, count: int) -> None:
        self.ids = ids
        self.sizes = np.bincount(ids, minlength=count)
        self._filled = np.flatnonzero(self.sizes > 0)
        self._starts = (np.cumsum(self.sizes) - self.sizes)[self._filled]  # strictly increasing

    def __call__(self, values: np.ndarray) -> np.ndarray:
        """Sums of values (N,) or (m, N) per patch: (K,) or (m, K); 0 for empty patches."""
        out = np.zeros(values.shape[:-1] + (len(self.sizes),))
        if self._filled.size:
            out[..., self._filled] = np.add.reduceat(values, self._starts, axis=-1)
        return out

    def means_at_pixels(self, values: np.ndarray) -> np.ndarray:
        """Each pixel's patch mean of values (N)."""
        return (self(values) / np.maximum(self.sizes, 1))[self.ids]


def refine_patches(
    left: np.ndarray,
    right: np.ndarray,
    mask: np.ndarray,
    centres: np.ndarray,
    radius_px: float,
    start: np.ndarray,
) -> PatchFit:
    """Fit an affine disparity to each circular patch (centre (x, y), radius) of `mask` pixels.

    left, right: rectified grey images (float32); mask: bool, pixels that belong to the surface;
    start: K initial disparities (a), or K x 3 initial (a, b, c); slopes default to zero.
    """
    ids, pixels = disc_pixels(mask, centres, radius_px)
    start = np.asarray(start, np.float64)
    params = start.reshape(-1, 3) if start.ndim == 2 else np.column_stack([start, np.zeros((len(start), 2))])
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    groups = _row_groups(centres[:, 1], radius_px)
    if len(groups) == 1:
        return fit_disparity_planes(left, right, ids, pixels, centres, params)
    # Patches in rows far apart (a heel and a toe): each group filters only its own rows. Every patch is
    # fitted on its own, so the fits are those of one call over all of them.
    parts = []
    for group in groups:
        chosen = np.flatnonzero(np.isin(ids, group))
        local = np.searchsorted(group, ids[chosen])
        parts.append((group, fit_disparity_planes(left, right, local, pixels[chosen], centres[group], params[group])))
    return merged_fits(parts, len(centres))


def _row_groups(rows: np.ndarray, radius_px: float) -> list[np.ndarray]:
    """Patches (indices, ascending) in groups whose filtered rows (radius and the filters' reach) do not meet."""
    order = np.argsort(rows, kind="stable")
    gap = 2.0 * (radius_px + _ROW_MARGIN_PX) + 2.0
    cuts = np.flatnonzero(np.diff(rows[order]) > gap) + 1
    return [np.sort(part) for part in np.split(order, cuts)]


def merged_fits(parts: list[tuple[np.ndarray, PatchFit]], count: int) -> PatchFit:
    """One PatchFit of `count` patches from fits of groups of them (global indices, ascending, per group):
    every patch is fitted on its own, so this is the fit of one call over all of them."""
    params, ok = np.empty((count, 3)), np.zeros(count, bool)
    for group, fit in parts:
        params[group], ok[group] = fit.params, fit.ok
    ids = np.concatenate([group[fit.ids] for group, fit in parts])
    order = np.argsort(ids, kind="stable")  # patch after patch, each patch's pixels in their order
    ids, xy = ids[order], np.concatenate([fit.xy for _, fit in parts])[order]
    return PatchFit(params, ok, ids, xy)


def disc_pixels(mask: np.ndarray, centres: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(patch id, (x, y)) of the `mask` pixels within `radius_px` of each centre, ordered by patch."""
    height, width = mask.shape
    offsets = _disc_offsets(radius_px)
    centres = np.round(np.asarray(centres, np.float64).reshape(-1, 2)).astype(np.int64)
    px = (centres[:, 0:1] + offsets[:, 0]).ravel()  # K x M candidates, patch after patch
    py = (centres[:, 1:2] + offsets[:, 1]).ravel()
    ids = np.repeat(np.arange(len(centres)), len(offsets))
    inside = np.flatnonzero((px >= 0) & (px < width) & (py >= 0) & (py < height))
    on = inside[np.take(np.ascontiguousarray(mask), py[inside] * width + px[inside])]  # mask[py, px] by flat index
    return ids[on], np.column_stack([px[on], py[on]]).astype(np.float64)


def fit_disparity_planes(
    left: np.ndarray,
    right: np.ndarray,
    ids: np.ndarray,
    pixels: np.ndarray,
    centres: np.ndarray,
    start: np.ndarray,
) -> PatchFit:
    """Fit d = a + b (x - cx) + c (y - cy) to each patch: pixels (N x 2, x y) labelled by ids (N, 0..K-1).

    start: K x 3 initial (a, b, c). Patches are sorted by id in the returned pixel lists.
    """
    order = np.argsort(ids, kind="stable")
    ids = np.take(np.asarray(ids, np.int64), order)
    # Gathers with np.take: the same values as indexing, a fraction of the time on ~10^5 pixels.
    ordered = np.take(np.asarray(pixels, np.float64), order, axis=0)
    x = ordered[:, 0].astype(np.float32)
    y_image = ordered[:, 1].astype(np.float32)
    # Rectified pixels are only ever sampled on their own row: blurring and differentiating the rows the
    # patches cover (plus the filters' reach) gives the same samples at a fraction of the whole images' cost.
    top, bottom = _row_span(y_image, left.shape[0])
    left, right, y = left[top:bottom], right[top:bottom], y_image - np.float32(top)
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    count = len(centres)
    params = np.array(start, np.float64).reshape(count, 3)
    dx = x - np.take(centres[:, 0], ids)
    dy = y_image - np.take(centres[:, 1], ids)
    sums = PatchSums(ids, count)
    sizes = sums.sizes
    last_step = np.full(count, np.inf)
    starts = np.concatenate([[0], np.cumsum(sizes)])
    # Patches of image pixels lie on whole rows: there the right image is sampled in C (ck_patch_sample).
    rows = y.astype(np.int32) if np.array_equal(y, np.round(y)) and len(y) else None
    right_at = _Sampler(y) if rows is None else None
    # The left image is sampled where its pixels are: at whole pixels the bicubic sample is the pixel itself
    # (read by flat index from the contiguous rows).
    columns = x.astype(np.int64) if rows is not None and np.array_equal(x, np.round(x)) else None
    flat = None if rows is None or columns is None else rows.astype(np.int64) * left.shape[1] + columns
    for sigma, iterations in BLUR_LEVELS:
        l_img = cv2.GaussianBlur(left, (0, 0), sigma) if sigma > 0 else left
        r_img = cv2.GaussianBlur(right, (0, 0), sigma) if sigma > 0 else right
        # The right image and its x gradient as two channels: one remap samples both at the same points.
        r_both = cv2.merge([r_img, cv2.Sobel(r_img, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)])
        l_val = _sample(l_img, x, y) if flat is None else np.take(np.ascontiguousarray(l_img), flat).astype(np.float64)
        l_dev = l_val - sums.means_at_pixels(l_val)  # the left patch does not move: its statistics are fixed per level
        l_energy = sums(l_dev**2)
        for _ in range(iterations):
            # Where each patch's plane puts its pixels (x - d), the right image there, and the step with its
            # per-patch sums and 3 x 3 solves, in C (csrc/cloud_kernels.c); the numpy formulation the step
            # follows is _gauss_newton_step, the tests' reference.
            if rows is None:
                assert right_at is not None
                samples = right_at(r_both, patch_shift(starts, params, x, dx, dy, KERNEL_THREADS))
            else:  # on whole rows: shift and bicubic sample in one C pass (cv2.remap's values to ~1e-6)
                samples = patch_sample(starts, params, x, dx, dy, rows, r_both, KERNEL_THREADS)
            step = patch_step(starts, l_dev, l_energy, samples, dx, dy, KERNEL_THREADS)
            params += np.clip(step, -MAX_STEP_PX, MAX_STEP_PX)
            last_step = np.abs(step[:, 0])
    ok = (sizes >= MIN_PATCH_PIXELS) & (last_step < 0.02) & np.all(np.isfinite(params), axis=1)
    xy = np.column_stack([x, y_image]).astype(np.float64)
    return PatchFit(params, ok, ids, xy)


# Rows beyond the patches that the filters reach: the widest Gaussian's kernel (OpenCV: radius 4 sigma for
# float images), Sobel's 1 and bicubic sampling's 2, rounded up.
_ROW_MARGIN_PX = int(4 * max(sigma for sigma, _ in BLUR_LEVELS)) + 8


def _row_span(y: np.ndarray, height: int) -> tuple[int, int]:
    """[top, bottom) of the image rows the fit can read."""
    if len(y) == 0:
        return 0, height
    return max(int(y.min()) - _ROW_MARGIN_PX, 0), min(int(np.ceil(y.max())) + _ROW_MARGIN_PX + 1, height)


def _gauss_newton_step(
    l_dev: np.ndarray, l_energy: np.ndarray, r_dev: np.ndarray, r_grad: np.ndarray, basis: np.ndarray, sums: PatchSums
) -> np.ndarray:
    """One Gauss-Newton update of (a, b, c) per patch.

    Intensities are compared after removing each patch's mean (l_dev, r_dev) and scaling the right patch to
    the left one's contrast: the two cameras never have quite the same gain, vignetting or highlights, and
    an uncorrected brightness ramp across a patch shifts the fitted disparity.
    """
    gain = np.sqrt(l_energy / np.maximum(sums(r_dev**2), 1e-9))[sums.ids]
    r_grad = r_grad * gain
    error = l_dev - gain * r_dev
    # Down-weight pixels with large residuals (specular spots, occlusion at the edge): Huber weights, scaled
    # by the patch's mean absolute residual (sqrt(pi / 2) * mean |e| is sigma for Gaussian noise; a median
    # would be more robust but costs a sort per patch and iteration).
    magnitude = np.abs(error)
    scale = 1.2533 * sums(magnitude) / np.maximum(sums.sizes, 1) + 1e-3
    weight = np.minimum(1.0, 2.0 * scale[sums.ids] / np.maximum(magnitude, 1e-9))
    # d R(x - d) / d params = J = -grad * (1, dx, dy); the step solves sum w (e - J step)^2 -> min, so
    # J^T W J = sum w grad^2 (1, dx, dy)^T (1, dx, dy) and J^T W e = -sum w grad e (1, dx, dy).
    weighted_grad = weight * r_grad
    moments = sums(np.vstack([basis * (weighted_grad * r_grad), basis[:3] * (-weighted_grad * error)]))
    s1, sx, sy, sxx, sxy, syy = moments[:6]
    rows = [np.stack(row, -1) for row in ((s1, sx, sy), (sx, sxx, sxy), (sy, sxy, syy))]
    normal = np.stack(rows, -2)
    normal += np.eye(3) * 1e-6
    rhs = moments[6:].T
    # R(x - d - s) ~ R(x - d) - grad * s, so the residual becomes e - J step: step = (J^T W J)^-1 J^T W e.
    return np.linalg.solve(normal, rhs[..., None])[..., 0]


def _sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bicubic samples at scattered points (cv2.remap; bilinear would bias sub-pixel shifts)."""
    n = len(x)
    if n == 0:
        return np.zeros(0)
    return _Sampler(y)(image, x).ravel()[:n].astype(np.float64)


class _Sampler:
    """Bicubic samples on fixed rows y at changing x (cv2.remap over the points laid out 1024 a row)."""

    def __init__(self, y: np.ndarray) -> None:
        self.count = len(y)
        rows = max(-(-self.count // 1024), 1)
        self.map_x = np.zeros((rows, 1024), np.float32)
        self.map_y = np.zeros((rows, 1024), np.float32)
        self.map_y.ravel()[: self.count] = y

    def __call__(self, image: np.ndarray, x: np.ndarray) -> np.ndarray:
        """N x C float32 samples of a C-channel image (N x 1 for a grey one) at (x, y)."""
        self.map_x.ravel()[: self.count] = x
        out = cv2.remap(image, self.map_x, self.map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(self.map_x.size, -1)[: self.count]


def _disc_offsets(radius: float) -> np.ndarray:
    r = int(np.ceil(radius))
    oy, ox = np.mgrid[-r : r + 1, -r : r + 1]
    inside = ox**2 + oy**2 <= radius**2
    return np.column_stack([ox[inside], oy[inside]])
