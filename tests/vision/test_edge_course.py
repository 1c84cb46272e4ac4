"""The edge-offset check's deep readings held to the outline's course (edge_checks.held_to_course): a notch in both
cameras' masks where the outline runs smoothly is no bump of the outline; a bump of the outline, a smeared stretch
and a long offset stay refused. Synthetic readings along a round outline (radius 50 mm, points 1 mm apart)."""

from __future__ import annotations

import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.edge_checks import check_edge_offsets, chord_bulge, held_to_course

RADIUS = 50.0
POINTS = 314


def outline(bump: np.ndarray | None = None) -> np.ndarray:
    """A counter-clockwise circle, 1 mm apart, pushed out by `bump` (mm per point) where given."""
    angle = np.linspace(0.0, 2 * np.pi, POINTS, endpoint=False)
    radius = RADIUS + (np.zeros(POINTS) if bump is None else bump)
    return radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])


def readings(at: slice, depth: float | list[float]) -> np.ndarray:
    """Readings near the outline (a sharp edge's 0.12 mm scatter) with `depth` (mm, + beyond) at `at`."""
    found = np.where(np.arange(POINTS) % 2 == 0, 0.12, -0.12)
    found[at] = depth
    return found


def test_a_circle_bulges_over_its_chords_as_an_arc() -> None:
    bulge, half = chord_bulge(outline(), 5)
    assert np.allclose(half, 5.0, atol=0.01)
    assert np.allclose(bulge, RADIUS - np.sqrt(RADIUS**2 - 5.0**2), atol=0.01)  # the sagitta: 0.25 mm


def test_a_notch_both_masks_share_on_a_smooth_outline_is_not_a_bump() -> None:
    left, right = readings(slice(100, 103), [-2.4, -3.6, -2.9]), readings(slice(101, 104), [-2.1, -2.6, -1.9])
    assert check_edge_offsets([left, right]) is not None  # read as they are: a 3 mm notch
    assert check_edge_offsets([left, right], outline()) is None
    held = held_to_course(0.5 * (left + right), outline())
    # The chords round it read ~0: its middle is held by short chords (a 12 mm concave arc sags 0.17 mm over 2 mm
    # either side), its flanks, whose short chords end in the notch, by wider ones (0.69 mm over 4 mm).
    assert np.all(held[101:103] > -0.6) and np.all(held[100:104] > -1.0)


def test_a_bump_of_the_outline_stays_refused() -> None:
    bump = np.zeros(POINTS)
    bump[100:104] = [0.6, 1.2, 1.2, 0.6]  # the outline pushed out over 4 mm; the masks show the true edge
    found = readings(slice(100, 104), [-0.6, -1.2, -1.2, -0.6])
    problem = check_edge_offsets([found, found.copy()], outline(bump))
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT
    assert "1.2 mm inside" in problem.reason


def test_a_smeared_stretch_with_a_peak_stays_refused() -> None:
    # std20 sole 1: the outline 0.6 mm beyond the edge over 9 mm and 0.9 on two points (the agreed-run rule's case).
    depth = [-0.6, -0.6, -0.6, -0.9, -0.9, -0.6, -0.6, -0.6, -0.6]
    found = readings(slice(100, 109), depth)
    problem = check_edge_offsets([found, found.copy()], outline(-readings(slice(100, 109), depth) * (found < -0.3)))
    assert problem is not None and "0.9 mm inside" in problem.reason


def test_a_long_stretch_inside_has_no_course_to_hold_it() -> None:
    found = readings(slice(100, 130), -1.1)  # the outline smoothly 1.1 mm beyond the edge over 30 mm
    bump = np.zeros(POINTS)
    bump[100:130] = 1.1
    for shape in (outline(), outline(bump)):  # whether or not the outline shows it as a bump
        problem = check_edge_offsets([found, found.copy()], shape)
        assert problem is not None and "1.1 mm inside" in problem.reason


def test_a_wide_concave_edge_the_outline_bridged_stays_refused() -> None:
    # A sole's edge curving inward with 12 mm of radius (the tightest allowed) over 12 mm, the outline running on
    # across it: the masks read the arc's sag, up to 1.6 mm deep, which an edge may have; the reading stands.
    at = np.arange(94, 107)
    depth = np.sqrt(108.0) - np.sqrt(144.0 - (at - 100.0) ** 2)  # 0 at its ends, -1.61 mm in its middle
    found = readings(slice(94, 107), list(depth))
    problem = check_edge_offsets([found, found.copy()], outline())
    assert problem is not None and "inside" in problem.reason


def test_a_wide_bump_whose_flanks_read_short_of_it_stays_refused() -> None:
    # Fresh sole 39015: the outline 0.5-1.06 mm beyond the edge over 6 mm, the masks reading 0.4-0.6 mm short of the
    # bump on its flanks: chords lying on the bump end on those flanks, which are not read on the outline.
    bump = np.zeros(POINTS)
    bump[99:107] = [0.3, 0.5, 0.8, 0.8, 0.92, 1.06, 0.86, 0.5]
    found = readings(slice(99, 107), [-0.12, -0.38, -0.5, -0.62, -0.88, -0.88, -0.38, -0.12])
    problem = check_edge_offsets([found, found.copy()], outline(bump))
    assert problem is not None and "inside" in problem.reason
