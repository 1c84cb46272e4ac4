"""Local plane fits of scattered surface heights: height and gradient at query points.

The glue path's heights and normals come from surface samples along the path (and a ring further in).
Smoothing them along the path's arc length biases both where the path turns sharply: at a pointed toe
that rises towards its tip, the tip is a peak of height along the arc and a Gaussian lowers it (by ~1 mm
on simulated soles), and the slopes of the two sides cancel. A plane fitted by weighted least squares in
the table plane has no such bias: a surface that is linear around the query point, however the samples lie
around it, is fitted exactly.
"""

from __future__ import annotations

import numpy as np

# Weight of a zero gradient (mm^2, like a sample at that squared distance): keeps a fit over samples along
# a nearly straight line (the path alone) stable; it shrinks slopes by ~1 / (sigma^2 spread in mm^2): 6 %
# at a 4 mm width, < 1 % for the normals' 12 mm.
GRADIENT_RIDGE_MM2 = 1.0


def local_planes(at: np.ndarray, xy: np.ndarray, z: np.ndarray, sigma_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Height (K) and gradient (K x 2) at table points `at` (K x 2) of planes fitted to samples (xy M x 2, z M).

    Gaussian weights of width `sigma_mm` on the distance in the table plane; NaN samples are left out; a
    query with no sample within reach gets NaN.
    """
    finite = np.isfinite(z)
    xy, z = xy[finite], z[finite]
    # Gaussian weights (K x M) of the squared distances in the table plane, in place.
    w = np.subtract.outer(at[:, 0], xy[:, 0])
    w *= w
    dy = np.subtract.outer(at[:, 1], xy[:, 1])
    dy *= dy
    w += dy
    w /= -2.0 * sigma_mm**2
    np.exp(w, out=w)
    # The weighted sums over the samples as one K x M by M x 9 product: moments about the samples' mean c,
    # shifted to each query point (sum w (p - a) = sum w (p - c) - s (a - c), and so on); the same sums as
    # over the K x M x 2 offsets (to ~1e-13 relative), without per-query loops over them.
    centre = xy.mean(axis=0) if len(xy) else np.zeros(2)
    u, v = (xy - centre).T
    a, b = (at - centre).T
    m = w @ np.column_stack([np.ones_like(u), u, v, u * u, u * v, v * v, z, u * z, v * z])
    s, su, sv, suu, suv, svv, sz, suz, svz = m.T
    sd = np.column_stack([su - s * a, sv - s * b])
    sdd = np.empty((len(at), 2, 2))
    sdd[:, 0, 0] = suu - 2.0 * a * su + s * a * a
    sdd[:, 0, 1] = sdd[:, 1, 0] = suv - a * sv - b * su + s * a * b
    sdd[:, 1, 1] = svv - 2.0 * b * sv + s * b * b
    sdd += GRADIENT_RIDGE_MM2 * s[:, None, None] * np.eye(2)
    normal = np.empty((len(at), 3, 3))
    normal[:, 0, 0], normal[:, 0, 1:], normal[:, 1:, 0], normal[:, 1:, 1:] = s, sd, sd, sdd
    rhs = np.column_stack([sz, suz - a * sz, svz - b * sz])
    ok = s > 1e-6
    solution = np.full((len(at), 3), np.nan)
    solution[ok] = np.linalg.solve(normal[ok], rhs[ok][..., None])[..., 0]
    return solution[:, 0], solution[:, 1:]
