"""The outline's shape checks (cellctl.vision.edge_checks.check_outline_notch and check_outline_spur): the
simulator's true outlines of every end kind pass; one with a notch 3 mm long and 1.5 mm deep (what both cameras'
change masks can share and no other check sees) is refused, on a straight side and in the waist; so is one with a
spur 5 mm long and 1.4 mm high (a shadow beside the edge taken for the sole), on a side, in the waist and beside a
pointed tip."""

from __future__ import annotations

import numpy as np
import pytest

from cellctl.errors import FailureKind
from cellctl.sim.look import END_KINDS, SceneLook
from cellctl.sim.sole import SoleModel, SolePose, SoleShape
from cellctl.vision.closed_path import outward_normals, resample_closed
from cellctl.vision.edge_checks import check_outline_notch, check_outline_spur


def true_outline(seed: int, heel: str, toe: str, mirrored: bool) -> np.ndarray:
    """A simulated sole's footprint outline in the table frame, counter-clockwise, points 1 mm apart."""
    rng = np.random.default_rng(seed)
    shape = SoleShape.random(rng, SceneLook(heel=heel, toe=toe))
    pose = SolePose(float(rng.uniform(-40, 40)), float(rng.uniform(-40, 40)), float(rng.uniform(0, 360)), mirrored)
    return resample_closed(SoleModel(shape, pose).outline_table(4000), 1.0)


def notched(outline: np.ndarray, at: int, length_mm: float, depth_mm: float) -> np.ndarray:
    """The outline moved inward around point `at` (1 mm spacing): a flat-bottomed notch `length_mm` long at the
    rim, its sides sloping over a third of that, `depth_mm` deep; resampled at 1 mm as the checks see it."""
    dense = resample_closed(outline, 0.1)
    arc = np.arange(len(dense)) * 0.1
    centre = at * (arc[-1] + 0.1) / len(outline)
    s = np.abs((arc - centre + arc[-1] / 2) % (arc[-1] + 0.1) - arc[-1] / 2)
    side = length_mm / 3
    profile = np.clip((0.5 * length_mm - s) / side, 0.0, 1.0)
    return resample_closed(dense - depth_mm * profile[:, None] * outward_normals(dense), 1.0)


@pytest.mark.parametrize("heel", END_KINDS)
@pytest.mark.parametrize("toe", END_KINDS)
def test_every_end_kind_of_the_simulators_soles_passes(heel: str, toe: str) -> None:
    for seed in range(6):
        outline = true_outline(seed, heel, toe, mirrored=seed % 2 == 1)
        assert check_outline_notch(outline) is None, (heel, toe, seed)
        assert check_outline_spur(outline) is None, (heel, toe, seed)


def _waist_point(outline: np.ndarray) -> int:
    """The outline point where it turns inward most (the medial waist)."""
    before, after = np.roll(outline, 5, axis=0), np.roll(outline, -5, axis=0)
    chord, rel = after - before, outline - before
    return int(np.argmax(chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]))


def test_a_notch_3_mm_long_and_1_5_mm_deep_is_refused_on_a_side_and_in_the_waist() -> None:
    for seed, (heel, toe) in enumerate((("round", "round"), ("pointed", "cusped"), ("square", "pointed"))):
        outline = true_outline(seed, heel, toe, mirrored=seed == 1)
        for at in (len(outline) // 4, _waist_point(outline)):
            problem = check_outline_notch(notched(outline, at, 3.0, 1.5))
            assert problem is not None, (seed, at)
            assert problem.kind == FailureKind.OUTLINE_INCONSISTENT
            assert "notch" in problem.reason


def test_a_dent_within_the_glue_tolerance_passes() -> None:
    """0.5 mm deep over 3 mm: within what the outline may be off (the bound is about depth, not about shape)."""
    outline = true_outline(0, "round", "round", mirrored=False)
    assert check_outline_notch(notched(outline, len(outline) // 4, 3.0, 0.5)) is None


def _tip_point(outline: np.ndarray) -> int:
    """The outline point where it turns outward most (a pointed end's tip)."""
    before, after = np.roll(outline, 3, axis=0), np.roll(outline, -3, axis=0)
    chord, rel = after - before, outline - before
    return int(np.argmin(chord[:, 0] * rel[:, 1] - chord[:, 1] * rel[:, 0]))


def test_a_spur_5_mm_long_and_1_4_mm_high_is_refused_on_a_side_in_the_waist_and_beside_a_pointed_tip() -> None:
    """The spur of other-lights sole 62046 (black, ring light): a strip of shadowed table beside the edge taken for
    the sole, which put the glue line 1.25 mm off its inset while every other check passed."""
    for seed, (heel, toe) in enumerate((("round", "round"), ("pointed", "cusped"), ("square", "pointed"))):
        outline = true_outline(seed, heel, toe, mirrored=seed == 1)
        places = [len(outline) // 4, _waist_point(outline)]
        if toe == "pointed":
            places.append(_tip_point(outline) + 8)  # on the flank, 8 mm from the tip
        for at in places:
            problem = check_outline_spur(notched(outline, at, 5.0, -1.4))
            assert problem is not None, (seed, at)
            assert problem.kind == FailureKind.OUTLINE_INCONSISTENT
            assert "spur" in problem.reason
            assert check_outline_notch(notched(outline, at, 5.0, -1.4)) is None  # outward: the notch rule is silent


def test_a_bulge_within_the_glue_tolerance_passes() -> None:
    """0.5 mm high over 5 mm: within what the outline may be off (right outlines bulge so at places)."""
    outline = true_outline(0, "round", "round", mirrored=False)
    assert check_outline_spur(notched(outline, len(outline) // 4, 5.0, -0.5)) is None


def test_the_tip_of_a_pointed_end_is_no_spur_however_it_is_turned() -> None:
    """A tip's flanks turn round with it: the bound (h sin(phi / 2)) is what a sharp V reaches, so even a pointed end
    sharpened to a zero-radius tip passes."""
    outline = true_outline(2, "square", "pointed", mirrored=False)
    tip = _tip_point(outline)
    sharpened = notched(outline, tip, 1.0, -0.3)
    assert check_outline_spur(sharpened) is None
