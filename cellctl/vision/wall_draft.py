"""A moulded sole's draft: its side wall leans out by a few degrees from the top edge down to the table.

The cameras look down on the sole from a few degrees off vertical along its sides (about 17 at its ends, at the
default rig). A wall that leans out by less than that faces away from both of them: it hides behind the top edge
exactly as a vertical wall does, and no image or depth reading differs (docs/measurements.md, Validity;
docs/sole-benchmark.md, twenty-fourth round). The outline the cell finds is then the top edge, and the sole's
foot, where its length and its outline are taken, lies further out by the wall's run, h tan(draft) at a top
edge h above the table: on 72 soles drawn with 1-6 degree drafts (the simulator's `draft` variation) all 32
results published were 0.7-4.7 mm short.

A line knows its sole model's draft from the mould. A recipe that states it (`[sole] wall = "drafted"`,
`draft_deg`; docs/recipes.md) has the outline moved out by that run at each point, from the measured height of
the top near it. The outline's own checks still judge the top edge the cameras see (a wall steeper than their
view shows in the images beyond it, and is refused as without the declaration); the moved outline gives the
length, the axis and the glue line.

The glue line lies `glue_offset_mm` inside that foot, so only offset - run inside the top edge: it must stay at
least MIN_TOP_INSET_MM inside it, where the top's depth is measured (the last mm of a top edge is the depth
step's blur), or the cycle is refused with the offset that would do.
"""

from __future__ import annotations

import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.checks import CheckFailure
from cellctl.vision.closed_path import outward_normals, smooth_along
from cellctl.vision.defaults import WALL_DRAFT_RANGE_DEG
from cellctl.vision.image_edge import edge_heights
from cellctl.vision.surface import SoleSurface

# The run follows the top's height along the outline; the heights 3 mm inside scatter by a few tenths of a mm
# (black soles), a run by a few hundredths: smoothed over ~5 mm of outline all the same.
RUN_SMOOTHING_MM = 5.0
# The glue line at least this far inside the top edge, where the top's depth reaches (the depth step blurs the last
# 0.5-1 mm). Stated drafts on the draft set 17000-17023: glue lines 0.9 and 1.0 mm inside the top edge were measured
# within tolerance (glue heights 0.48, 0.50 mm off), one 0.6 mm inside lost the surface under 5 % of its path and
# the coverage check refused it without naming the draft (docs/sole-benchmark.md, twenty-fourth round).
MIN_TOP_INSET_MM = 0.75


def check_draft(draft_deg: float) -> None:
    """ValueError unless `draft_deg` is a draft a recipe may state (WALL_DRAFT_RANGE_DEG, 0 excluded: vertical)."""
    low, high = WALL_DRAFT_RANGE_DEG
    if not low < draft_deg <= high:
        raise ValueError(f"a wall's draft must be in ({low:g}, {high:g}] degrees, got {draft_deg:g}")


def wall_runs(top_edge: np.ndarray, surface: SoleSurface, draft_deg: float) -> np.ndarray:
    """Per point of the top edge's outline (closed, counter-clockwise, table mm): how far (mm) a wall leaning out
    `draft_deg` from it down to the table runs beyond it, from the measured top's height near it."""
    spacing = float(np.median(np.linalg.norm(np.diff(top_edge, axis=0), axis=1)))
    heights = np.clip(edge_heights(surface, top_edge, outward_normals(top_edge)), 0.0, None)
    heights = np.nan_to_num(heights, nan=0.0)  # no height measured anywhere near: the other checks refuse it
    return smooth_along(heights * np.tan(np.radians(draft_deg)), RUN_SMOOTHING_MM / max(spacing, 1e-6))


def foot_outline(top_edge: np.ndarray, runs: np.ndarray) -> np.ndarray:
    """The top edge's outline moved out along its normals by `runs` (per point, mm): the wall's foot. Exact where
    the outline's curvature radius exceeds the run (a few mm) on its concave stretches, as a sole's are."""
    return top_edge + runs[:, None] * outward_normals(top_edge)


def check_glue_inset(runs: np.ndarray, glue_offset_mm: float) -> CheckFailure | None:
    """A glue line `glue_offset_mm` inside the foot must lie MIN_TOP_INSET_MM or more inside the top edge."""
    widest = float(np.max(runs)) if len(runs) else 0.0
    if glue_offset_mm - widest >= MIN_TOP_INSET_MM:
        return None
    return CheckFailure(
        FailureKind.GLUE_PATH_INCONSISTENT,
        f"the stated draft puts the sole's foot up to {widest:.1f} mm beyond its top edge: a glue line "
        f"{glue_offset_mm:g} mm inside the foot would run within {MIN_TOP_INSET_MM:g} mm of the top edge, where its "
        f"height is not measured; set the recipe's [glue] offset_mm to {widest + MIN_TOP_INSET_MM:.1f} or more",
    )
