"""Closed paths in the table plane (outlines, glue lines): resampling, smoothing along the path, normals.

The measurement's outline and glue path are closed polygons sampled in mm; these helpers keep them closed
(wrap-around at the ends) where numpy's and OpenCV's 1-D filters would not.
"""

from __future__ import annotations

import warnings

import cv2
import numpy as np


def along_kernel(sigma_samples: float, count: int) -> np.ndarray:
    """The Gaussian weights smooth_along gives a point's neighbours -radius..radius on a closed path of `count`
    points (3 sigma, at most half the path either side)."""
    radius = min(int(np.ceil(3 * sigma_samples)), count // 2)
    return cv2.getGaussianKernel(2 * radius + 1, sigma_samples).ravel()


def smooth_along(values: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Gaussian smoothing of per-point values (N or N x k) along a closed path."""
    kernel = along_kernel(sigma_samples, len(values))
    radius = len(kernel) // 2
    if radius < 1:
        return values
    padded = np.concatenate([values[-radius:], values, values[:radius]])
    if padded.ndim == 1:
        return np.convolve(padded, kernel, mode="valid")
    return np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(padded.shape[1])])


def resample_closed(poly: np.ndarray, spacing: float) -> np.ndarray:
    """Points every `spacing` mm of arc length along a closed polygon (first point kept, not repeated)."""
    ring = np.vstack([poly, poly[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(ring, axis=0), axis=1))])
    count = max(3, int(round(arc[-1] / spacing)))
    s = np.linspace(0.0, arc[-1], count, endpoint=False)
    return np.column_stack([np.interp(s, arc, ring[:, 0]), np.interp(s, arc, ring[:, 1])])


def smooth_closed(poly: np.ndarray, sigma_mm: float) -> np.ndarray:
    """Gaussian smoothing along a closed polygon resampled at 0.25 mm (wrap-around at the ends)."""
    if len(poly) < 3:
        return poly
    step = 0.25
    ring = resample_closed(poly, step)
    sigma = sigma_mm / step
    radius = int(np.ceil(3 * sigma))
    kernel = cv2.getGaussianKernel(2 * radius + 1, sigma).ravel()
    padded = np.vstack([ring[-radius:], ring, ring[:radius]])
    return np.column_stack([np.convolve(padded[:, k], kernel, mode="valid") for k in range(2)])


def running_median(values: np.ndarray, reach: int, quorum: int = 1) -> np.ndarray:
    """Per point of a closed path the median of `values` over itself and the `reach` points either side, unknowns
    (NaN) left out; NaN where fewer than `quorum` of them are known."""
    around = (np.arange(len(values))[:, None] + np.arange(-reach, reach + 1)[None]) % len(values)
    window = values[around]
    enough = np.isfinite(window).sum(axis=1) >= quorum
    with warnings.catch_warnings():  # all-NaN windows: left out by `enough` (quorum 1 or more)
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.where(enough, np.nanmedian(window, axis=1), np.nan)


def outward_normals(poly: np.ndarray) -> np.ndarray:
    """Unit outward normals of a counter-clockwise closed polygon."""
    tangent = np.roll(poly, -1, axis=0) - np.roll(poly, 1, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    return np.column_stack([tangent[:, 1], -tangent[:, 0]])


def normal_samples(path: np.ndarray, outward: np.ndarray, offsets_mm: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Table points (N x K x 3) `offsets_mm` (K, +: outward) along each of the N path points' `outward` normals, at
    the height `level` (N) of its point: the profiles across an outline that the edge checks sample images on."""
    # Written per coordinate into one array: the same sums as path + offsets x outward, ~5 x faster than
    # broadcasting the pairs and concatenating.
    points = np.empty((len(path), len(offsets_mm), 3))
    for c in (0, 1):
        np.add(path[:, c, None], offsets_mm[None, :] * outward[:, c, None], out=points[:, :, c])
    points[:, :, 2] = level[:, None]
    return points


def closed_runs(flags: np.ndarray) -> list[np.ndarray]:
    """The runs of consecutive flagged points of a closed path: per run its indices in order along the path (a run
    across the path's end wraps, ..., n - 1, 0, 1, ...); the whole path as one run if every point is flagged."""
    n = len(flags)
    if not flags.any():
        return []
    if flags.all():
        return [np.arange(n)]
    start = int(np.flatnonzero(~flags)[0])  # roll so that no run wraps around the end
    rolled = np.flatnonzero(np.roll(flags, -start))
    breaks = np.flatnonzero(np.diff(rolled) > 1) + 1
    return [(run + start) % n for run in np.split(rolled, breaks)]


def run_lengths(flags: np.ndarray) -> np.ndarray:
    """Per point of a closed path, the length (points) of the run of consecutive flagged points it is in, 0 where
    not flagged."""
    lengths = np.zeros(len(flags))
    for run in closed_runs(flags):
        lengths[run] = len(run)
    return lengths
