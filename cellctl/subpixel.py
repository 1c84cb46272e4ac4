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

BLUR_LEVELS: tuple[tuple[float, int], ...] = ((2.0, 4), (1.0, 3), (0.0, 3))  # (Gaussian sigma px, iterations)
MIN_PATCH_PIXELS = 40
MAX_STEP_PX = 0.5  # per iteration: larger updates mean the linearisation does not hold


@dataclass
class PatchFit:
    """Affine disparity per patch: d = a + b (x - cx) + c (y - cy) for pixels (x, y) of the rectified left image."""

    params: np.ndarray  # K x 3 (a, b, c)
    ok: np.ndarray  # K bool: converged with enough textured pixels
    pixels: list[np.ndarray]  # per patch, the (x, y) pixels used (M_k x 2)


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
    return fit_disparity_planes(left, right, ids, pixels, centres, params)


def disc_pixels(mask: np.ndarray, centres: np.ndarray, radius_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(patch id, (x, y)) of the `mask` pixels within `radius_px` of each centre."""
    height, width = mask.shape
    offsets = _disc_offsets(radius_px)
    patch_id, pixels = [], []
    for k, (cx, cy) in enumerate(np.asarray(centres, np.float64).reshape(-1, 2)):
        px = np.round(cx).astype(int) + offsets[:, 0]
        py = np.round(cy).astype(int) + offsets[:, 1]
        inside = (px >= 0) & (px < width) & (py >= 0) & (py < height)
        px, py = px[inside], py[inside]
        on = mask[py, px]
        patch_id.append(np.full(int(on.sum()), k))
        pixels.append(np.column_stack([px[on], py[on]]))
    return np.concatenate(patch_id).astype(np.int64), np.vstack(pixels).astype(np.float64)


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
    ids = np.asarray(ids, np.int64)[order]
    x = np.asarray(pixels, np.float64)[order, 0].astype(np.float32)
    y = np.asarray(pixels, np.float64)[order, 1].astype(np.float32)
    centres = np.asarray(centres, np.float64).reshape(-1, 2)
    count = len(centres)
    params = np.array(start, np.float64).reshape(count, 3)
    dx = x - centres[ids, 0]
    dy = y - centres[ids, 1]
    sizes = np.bincount(ids, minlength=count)
    last_step = np.full(count, np.inf)
    for sigma, iterations in BLUR_LEVELS:
        l_img = cv2.GaussianBlur(left, (0, 0), sigma) if sigma > 0 else left
        r_img = cv2.GaussianBlur(right, (0, 0), sigma) if sigma > 0 else right
        r_grad = cv2.Sobel(r_img, cv2.CV_32F, 1, 0, ksize=3) / 8.0
        l_val = _sample(l_img, x, y)
        for _ in range(iterations):
            d = params[ids, 0] + params[ids, 1] * dx + params[ids, 2] * dy
            step = _gauss_newton_step(l_val, _sample(r_img, x - d, y), _sample(r_grad, x - d, y), ids, dx, dy, count)
            params += np.clip(step, -MAX_STEP_PX, MAX_STEP_PX)
            last_step = np.abs(step[:, 0])
    ok = (sizes >= MIN_PATCH_PIXELS) & (last_step < 0.02) & np.all(np.isfinite(params), axis=1)
    split = np.cumsum(sizes)[:-1]
    return PatchFit(params, ok, np.split(np.column_stack([x, y]).astype(np.float64), split))


def _gauss_newton_step(l_val: np.ndarray, r_val: np.ndarray, r_grad: np.ndarray, ids: np.ndarray,
                       dx: np.ndarray, dy: np.ndarray, count: int) -> np.ndarray:
    """One Gauss-Newton update of (a, b, c) per patch.

    Intensities are compared after removing each patch's mean and scaling the right patch to the left one's
    contrast: the two cameras never have quite the same gain, vignetting or highlights, and an uncorrected
    brightness ramp across a patch shifts the fitted disparity.
    """
    sizes = np.maximum(np.bincount(ids, minlength=count), 1)
    l_mean = np.bincount(ids, weights=l_val, minlength=count) / sizes
    r_mean = np.bincount(ids, weights=r_val, minlength=count) / sizes
    l_dev, r_dev = l_val - l_mean[ids], r_val - r_mean[ids]
    gain = np.sqrt(np.bincount(ids, weights=l_dev**2, minlength=count) /
                   np.maximum(np.bincount(ids, weights=r_dev**2, minlength=count), 1e-9))
    r_grad = r_grad * gain[ids]
    error = l_dev - gain[ids] * r_dev
    # Down-weight pixels with large residuals (specular spots, occlusion at the edge): Huber weights, scaled
    # by the patch's mean absolute residual (sqrt(pi / 2) * mean |e| is sigma for Gaussian noise; a median
    # would be more robust but costs a sort per patch and iteration).
    scale = 1.2533 * np.bincount(ids, weights=np.abs(error), minlength=count) / sizes + 1e-3
    weight = np.minimum(1.0, 2.0 * scale[ids] / np.maximum(np.abs(error), 1e-9))
    # d R(x - d) / d params = -grad * (1, dx, dy); the step solves sum w (e - J step)^2 -> min.
    jac = -r_grad[:, None] * np.column_stack([np.ones_like(dx), dx, dy])
    normal = np.zeros((count, 3, 3))
    rhs = np.zeros((count, 3))
    for i in range(3):
        rhs[:, i] = np.bincount(ids, weights=weight * jac[:, i] * error, minlength=count)
        for j in range(i, 3):
            normal[:, i, j] = normal[:, j, i] = np.bincount(ids, weights=weight * jac[:, i] * jac[:, j], minlength=count)
    normal += np.eye(3) * 1e-6
    # R(x - d - s) ~ R(x - d) - grad * s, so the residual becomes e - J step: step = (J^T W J)^-1 J^T W e.
    return np.linalg.solve(normal, rhs[..., None])[..., 0]


def _sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bicubic samples at scattered points (cv2.remap; bilinear would bias sub-pixel shifts)."""
    n = len(x)
    if n == 0:
        return np.zeros(0)
    rows = -(-n // 1024)
    mx = np.zeros(rows * 1024, np.float32)
    my = np.zeros(rows * 1024, np.float32)
    mx[:n], my[:n] = x, y
    out = cv2.remap(image, mx.reshape(rows, 1024), my.reshape(rows, 1024), cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    return out.ravel()[:n].astype(np.float64)


def _disc_offsets(radius: float) -> np.ndarray:
    r = int(np.ceil(radius))
    oy, ox = np.mgrid[-r : r + 1, -r : r + 1]
    inside = ox**2 + oy**2 <= radius**2
    return np.column_stack([ox[inside], oy[inside]])
