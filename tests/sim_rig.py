"""A half-size simulated rig for service tests: same geometry, 640x512 images, ~4 x faster to render and measure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cellctl.sim.rig import default_rig
from cellctl.vision.calibration import Calibration

# The half-size rig sees 0.78 mm per pixel on the table and measures glue heights to ~1-2 mm, not the default 1 mm
# (white soles 0.96-1.79 mm off): with the default its cycles are refused as measured too coarsely
# (checks.check_glue_precision), so its cells and measurements allow 2.5 mm (2 mm until the share on a clean
# camera's mean of exposures became 0.19: sole 2's expected error on the mean, 0.39 mm, is then over 2 mm's 0.38).
HALF_RIG_GLUE_TOLERANCE_MM = 2.5
# The tests' cells measure plain simulated soles without a taught table (tests/vision/test_teach.py teaches).
UNTAUGHT_MEASURE = "[measure]\nrequire_taught_table = false\n"
HALF_RIG_MEASURE = f"[measure]\nglue_height_tolerance_mm = {HALF_RIG_GLUE_TOLERANCE_MM}\nrequire_taught_table = false\n"


def half_size_rig() -> Calibration:
    """default_rig() with both cameras' pixel grids halved (focal lengths and principal points scaled)."""
    rig = default_rig()
    scale = np.diag([0.5, 0.5, 1.0])
    width, height = rig.image_size
    return Calibration.from_extrinsics(
        (width // 2, height // 2), scale @ rig.K1, rig.D1, scale @ rig.K2, rig.D2, rig.R, rig.T
    )


def write_half_size_rig(directory: Path) -> Path:
    path = directory / "calib-half.yaml"
    half_size_rig().save(path)
    return path
