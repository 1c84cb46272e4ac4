"""Self-checks a measurement must pass before it is valid (docs/measurements.md, Validity).

A refused cycle is an inconvenience; a wrong number published as valid drives the robot's nozzle into the
fixture. Each check compares a result with evidence it was not derived from:

- outline against the depth step: just inside the outline the sole must rise above the table, a little
  further out than stereo edge fattening reaches it must not (a rim cut off by the edge finder, a
  shadow or a neighbouring object taken for sole);
- outline against the right camera (taught table only): the outline, found in the left image, placed in
  the right image must have changed pixels just inside and the taught table just outside;
- glue path: heights continuous along the path and within the sole's own height range, normals
  consistent with the surface fitted around each point.

Each returns None or a `CheckFailure` (kind and reason); cellctl.vision.measurement refuses on the first.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.footprint import Footprint

OUTLINE_INSIDE_MM = 2.0  # the sole must rise above the table this far inside its outline...
OUTLINE_OUTSIDE_MM = 7.0  # ...and not this far outside (stereo edge fattening reaches ~5 mm)
MIN_OUTLINE_AGREEMENT = 0.9  # of the testable outline points
MIN_TESTABLE = 0.5  # of the outline points: fewer with evidence and the outline cannot be confirmed
RIGHT_INSIDE_MM = 1.5
RIGHT_OUTSIDE_MM = 3.0
GLUE_HEIGHT_MARGIN_MM = 1.5  # glue heights beyond the sole's own height range by more than this: not on it
GLUE_MAX_SLOPE = 0.6  # height change per mm along the path between neighbouring points
# Smoothed path against its own raw samples (after lone outliers are repaired): a patch's height noise on a
# black sole reaches ~1.4 mm at worst; a failed fit is off by tens of mm.
GLUE_MAX_DEVIATION_MM = 2.5
# Path normal against the patches' own normals smoothed along the path: these are noisy (up to ~20 degrees
# on plain black soles), so the check catches gross faults only; the path normal itself is far better.
GLUE_MAX_NORMAL_DEG = 30.0
MIN_GLUE_NZ = 0.5  # a glue normal more than 60 degrees off vertical is not on a sole's top surface


@dataclass(frozen=True)
class CheckFailure:
    kind: FailureKind
    reason: str


def check_outline_depth(
    outline: np.ndarray,
    outward: np.ndarray,
    raised: Footprint,
    measured: Footprint,
    footprint: Footprint | None = None,
) -> CheckFailure | None:
    """The outline (N x 2, table mm) against the depth step (cells where most points rise above the table).

    With the `footprint` the outline bounds, points whose test positions fall on the wrong side of it (past
    a pointed tip, across a narrow waist) are not tested: there the offset along the normal means nothing.
    """
    inside = outline - OUTLINE_INSIDE_MM * outward
    outside = outline + OUTLINE_OUTSIDE_MM * outward
    in_known, out_known = measured.contains(inside), measured.contains(outside)
    if footprint is not None:
        in_known &= footprint.contains(inside)
        out_known &= ~footprint.contains(outside)
    in_ok = raised.contains(inside)
    out_ok = ~raised.contains(outside)
    testable = in_known & out_known
    if np.count_nonzero(testable) < MIN_TESTABLE * len(outline):
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"outline not confirmed by depth: only {np.count_nonzero(testable)} of {len(outline)} outline points "
            "have measured depth on both sides",
        )
    agree = float(np.mean((in_ok & out_ok)[testable]))
    if agree < MIN_OUTLINE_AGREEMENT:
        low_inside = float(np.mean(~in_ok[testable]))
        high_outside = float(np.mean(~out_ok[testable]))
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"outline disagrees with the depth step at {100 * (1 - agree):.0f} % of its points "
            f"({100 * high_outside:.0f} % still raised {OUTLINE_OUTSIDE_MM:g} mm outside, {100 * low_inside:.0f} % "
            f"not raised {OUTLINE_INSIDE_MM:g} mm inside): the edge found is not the sole's edge",
        )
    return None


def check_outline_right(
    outline: np.ndarray,
    outward: np.ndarray,
    edge_height: np.ndarray,
    changed_right: np.ndarray,
    table_to_right_pixel: Callable[[np.ndarray], np.ndarray],
    right_centre: np.ndarray,
    footprint: Footprint,
) -> CheckFailure | None:
    """The outline placed in the right image: changed just inside (at the sole's height), table just outside.

    `table_to_right_pixel(points N x 3) -> N x 2` projects table points into the rectified right image;
    `right_centre` is the right camera's centre in the table frame. Points outside whose view from the right
    camera passes over the sole (hidden behind it) are not tested.
    """
    project = table_to_right_pixel
    height, width = changed_right.shape
    inside = np.column_stack([outline - RIGHT_INSIDE_MM * outward, np.maximum(edge_height, 0.0)])
    outside = np.column_stack([outline + RIGHT_OUTSIDE_MM * outward, np.zeros(len(outline))])
    # Hidden: the ray from the table point to the camera is above the footprint at the edge's height.
    lift = np.clip(edge_height / right_centre[2], 0.0, 1.0)[:, None]
    over = outside[:, :2] + lift * (right_centre[:2] - outside[:, :2])
    visible = ~footprint.contains(over)

    def sample(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px = np.round(project(points)).astype(np.int64)
        ok = (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
        values = np.zeros(len(points), bool)
        values[ok] = changed_right[px[ok, 1], px[ok, 0]]
        return values, ok

    in_changed, in_ok = sample(inside)
    out_changed, out_ok = sample(outside)
    inside_agree = float(np.mean(in_changed[in_ok])) if np.any(in_ok) else 0.0
    tested = out_ok & visible
    outside_agree = float(np.mean(~out_changed[tested])) if np.count_nonzero(tested) > 0.2 * len(outline) else 1.0
    if inside_agree < MIN_OUTLINE_AGREEMENT or outside_agree < MIN_OUTLINE_AGREEMENT:
        return CheckFailure(
            FailureKind.OUTLINE_INCONSISTENT,
            f"the outline found in the left image does not fit the right image: {100 * inside_agree:.0f} % "
            f"of the points {RIGHT_INSIDE_MM:g} mm inside show the sole and {100 * outside_agree:.0f} % of those "
            f"{RIGHT_OUTSIDE_MM:g} mm outside the table (need {100 * MIN_OUTLINE_AGREEMENT:.0f} %)",
        )
    return None


def check_glue_path(
    points: np.ndarray,
    normals: np.ndarray,
    raw_z: np.ndarray,
    patch_normals: np.ndarray,
    sole_heights: tuple[float, float],
    spacing_mm: float,
) -> CheckFailure | None:
    """Glue points (N x 3) and normals against the sole's height range, their own samples and the surface."""
    z = points[:, 2]
    low, high = sole_heights[0] - GLUE_HEIGHT_MARGIN_MM, sole_heights[1] + GLUE_HEIGHT_MARGIN_MM
    outside = np.flatnonzero((z < max(low, 0.0)) | (z > high))
    if outside.size:
        k = int(outside[np.argmax(np.abs(z[outside] - np.clip(z[outside], low, high)))])
        return _glue(
            f"glue point {k} at {z[k]:.1f} mm height is outside the sole's heights {sole_heights[0]:.1f}.."
            f"{sole_heights[1]:.1f} mm"
        )
    step = np.abs(np.diff(np.append(z, z[:1])))
    if step.max() > GLUE_MAX_SLOPE * spacing_mm:
        k = int(np.argmax(step))
        return _glue(f"glue path height jumps {step[k]:.1f} mm between points {k} and {(k + 1) % len(z)}")
    deviation = np.abs(z - raw_z)
    if np.nanmax(deviation) > GLUE_MAX_DEVIATION_MM:
        k = int(np.nanargmax(deviation))
        return _glue(
            f"glue point {k} is {deviation[k]:.1f} mm from the surface measured there: the surface is not "
            "continuous along the path"
        )
    if normals[:, 2].min() < MIN_GLUE_NZ:
        return _glue(f"a glue normal is {np.degrees(np.arccos(normals[:, 2].min())):.0f} degrees off vertical")
    cosine = np.clip(np.sum(normals * patch_normals, axis=1), -1.0, 1.0)
    angle = np.degrees(np.arccos(cosine))
    if np.nanmax(angle) > GLUE_MAX_NORMAL_DEG:
        k = int(np.nanargmax(angle))
        return _glue(
            f"glue normal {k} is {angle[k]:.0f} degrees from the surface fitted around it "
            f"(limit {GLUE_MAX_NORMAL_DEG:g})"
        )
    return None


def _glue(reason: str) -> CheckFailure:
    return CheckFailure(FailureKind.GLUE_PATH_INCONSISTENT, reason)
