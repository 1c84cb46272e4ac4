"""A rounded top edge in numbers (cellctl.vision.rounded_edge) on a synthetic round sole: the fall across the
edge, its slope, and the bounds the silhouettes of a camera above the sole's middle put on the edge."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.vision import rounded_edge
from cellctl.vision.edge_checks import check_edge_profile, top_falls
from tests.vision.test_outline_checks import HEIGHT, RADIUS, measured, ring, top

CAMERA = np.array([0.0, 0.0, 550.0])  # above the sole's middle, like the cell's: it sees no wall
FOCAL = 2500.0  # 0.22 mm per pixel at the table
SIZE = 560


def project(points: np.ndarray) -> np.ndarray:
    rel = points - CAMERA
    return np.column_stack([FOCAL * rel[:, 0] / -rel[:, 2], FOCAL * rel[:, 1] / -rel[:, 2]]) + SIZE / 2


def silhouette(height: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    """Pixels whose ray meets the sole (a vertical wall under the top `height`)."""
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    direction = np.column_stack([(u.ravel() - SIZE / 2) / FOCAL, (v.ravel() - SIZE / 2) / FOCAL])
    hit = np.zeros(u.size, bool)
    for z in np.linspace(0.0, HEIGHT, 81):
        hit |= height(CAMERA[:2] + direction * (CAMERA[2] - z)) >= z - 1e-9
    return hit.reshape(SIZE, SIZE)


def fillet_fall(radius: float, d: np.ndarray) -> np.ndarray:
    return radius - np.sqrt(np.maximum(radius * radius - (radius - d) ** 2, 0.0))


def test_the_fall_profile_is_flat_on_a_sharp_edge_and_follows_a_fillet() -> None:
    outline, outward = ring()
    sharp = rounded_edge.fall_profile(top_falls(outline, outward, measured(top(), 0.3), rounded_edge.FALL_AT_MM))
    assert np.all(np.abs(sharp) < 1e-6)
    assert abs(rounded_edge.profile_tilt_deg(sharp, 2.0)) < 1e-3
    # A 4 mm fillet whose outer 0.5 mm has no depth: the outline found lies 0.5 mm in.
    inner, inner_outward = ring(RADIUS - 0.5)
    profile = rounded_edge.fall_profile(
        top_falls(inner, inner_outward, measured(top(4.0), 0.5), rounded_edge.FALL_AT_MM)
    )
    at = np.array(rounded_edge.FALL_AT_MM)
    # The line through 3-8 mm in is the flat top but for its first sample (3.5 mm from the true edge, still
    # 0.03 mm down the fillet): the fall is the fillet's own.
    assert np.allclose(profile, fillet_fall(4.0, at + 0.5), atol=0.05)
    # 1.5 mm in from the depth's outline, 2 mm from the true edge: the fillet's slope there is 30 degrees, its
    # central difference over +-0.5 mm 30 as well.
    secant = np.degrees(np.arctan(fillet_fall(4.0, 1.5) - fillet_fall(4.0, 2.5)))
    assert abs(rounded_edge.profile_tilt_deg(profile, 1.5) - secant) < 1.5
    assert abs(secant - 30.0) < 2.0


def test_the_silhouettes_bound_a_rounded_edge_beyond_the_depth() -> None:
    fillet, lost = 4.0, 1.0
    changed = silhouette(top(fillet))
    inner, inner_outward = ring(RADIUS - lost)
    low, high = rounded_edge.silhouette_bounds(
        inner, inner_outward, measured(top(fillet), lost), [(changed, project)], None
    )
    # The true edge lies `lost` mm beyond the depth's outline; the bounds hold it (a pixel is 0.22 mm).
    assert np.nanmedian(low) <= lost + 0.25
    assert np.nanmedian(high) >= lost - 0.25
    assert np.nanmedian(high) > np.nanmedian(low)
    # On a sharp edge the silhouette at the top's height is the edge: the inner bound is the depth's outline.
    outline, outward = ring()
    low, _ = rounded_edge.silhouette_bounds(outline, outward, measured(top(), 0.0), [(silhouette(top()), project)])
    assert abs(np.nanmedian(low)) <= 0.25


def test_the_edge_profile_refusal_carries_the_numbers_and_a_pass_asks_for_none() -> None:
    outline, outward = ring()
    asked = []

    def detail() -> str:
        asked.append(True)
        return "the numbers"

    assert check_edge_profile(outline, outward, measured(top(), 0.3), detail) is None
    assert not asked
    inner, inner_outward = ring(RADIUS - 1.0)
    problem = check_edge_profile(inner, inner_outward, measured(top(4.0), 1.0), detail)
    assert problem is not None and "rounded" in problem.reason and "(the numbers)" in problem.reason
    profile = rounded_edge.fall_profile(
        top_falls(inner, inner_outward, measured(top(4.0), 1.0), rounded_edge.FALL_AT_MM)
    )
    words = rounded_edge.describe(profile, None, 2.0)
    assert "slopes" in words and "degrees" in words
