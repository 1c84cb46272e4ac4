"""Exact polygon geometry for the simulator's truth (Green's theorem), apart from any measuring code."""

from __future__ import annotations

import numpy as np


def polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def polygon_moments(poly: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Area, centroid and second central moments (2 x 2, per unit area) of a simple polygon (Green's theorem)."""
    # Shift to a point near the centroid first: the formulas lose precision far from the origin.
    origin = poly.mean(axis=0)
    x, y = (poly - origin).T
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * np.sum(cross)
    cx = np.sum((x + xn) * cross) / (6 * area)
    cy = np.sum((y + yn) * cross) / (6 * area)
    sxx = np.sum((x * x + x * xn + xn * xn) * cross) / (12 * area) - cx * cx
    syy = np.sum((y * y + y * yn + yn * yn) * cross) / (12 * area) - cy * cy
    sxy = np.sum((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * cross) / (24 * area) - cx * cy
    return float(area), np.array([cx, cy]) + origin, np.array([[sxx, sxy], [sxy, syy]])


def clip_half_plane(poly: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """Part of a polygon where p . normal >= offset (Sutherland-Hodgman against one line, vectorised)."""
    side = poly @ normal - offset
    nxt = np.roll(poly, -1, axis=0)
    side_next = np.roll(side, -1)
    inside = side >= 0
    crossing = inside != (side_next >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(crossing, side / (side - side_next), 0.0)
    cut = poly + f[:, None] * (nxt - poly)
    # Per edge: the start vertex if inside, then the crossing point if the edge crosses the line.
    candidates = np.stack([poly, cut], axis=1).reshape(-1, 2)
    keep = np.stack([inside, crossing], axis=1).ravel()
    return candidates[keep]
