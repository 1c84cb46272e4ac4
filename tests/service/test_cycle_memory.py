"""What a cycle leaves behind in memory: its result without image-sized rasters.

The result of a cycle outlives it (artifact writer, operator station, image log). Held into the next cycles,
image-sized rasters split the heap the cycles allocate from and glibc grows it: every new page is a fault in
a later measurement (cellctl.service.cycle.outliving_the_cycle).
"""

from __future__ import annotations

import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.service.cycle import Measured, MeasureSettings, measure_frame
from cellctl.sim.scene import SoleScene
from cellctl.vision.reconstruction import SoleReconstructor
from tests.sim_rig import HALF_RIG_GLUE_TOLERANCE_MM, half_size_rig


def test_a_measured_cycle_keeps_its_sole_but_no_image_sized_raster() -> None:
    calib = half_size_rig()
    pair = SoleScene.random(seed=1, calib=calib).render()
    reconstructor = SoleReconstructor(calib)
    result = measure_frame(
        StereoFrame(pair.left, pair.right, 0.0, 0.0),
        reconstructor,
        MeasureSettings(2.0, 2.0, HALF_RIG_GLUE_TOLERANCE_MM),
    )
    assert isinstance(result, Measured)
    kept = result.reconstruction
    assert len(kept.sole_points) == len(kept.sole_colors) == len(kept.sole_pixels) > 1000
    width, height = calib.image_size

    def arrays(value: object) -> list[np.ndarray]:
        if isinstance(value, np.ndarray):
            return [value]
        if isinstance(value, tuple | list):
            return [a for v in value for a in arrays(v)]
        return [a for v in vars(value).values() for a in arrays(v)] if hasattr(value, "__dict__") else []

    held = [(name, a.shape) for name, v in vars(kept).items() if name != "taught" for a in arrays(v)]
    # The taught table is the cell's, held by the reconstructor anyway; no raster of the images is kept (the
    # footprint, a raster of cells on the table, stays with the sole).
    assert not [(name, shape) for name, shape in held if tuple(shape[:2]) == (height, width)], held
