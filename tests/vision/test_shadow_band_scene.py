"""A cast shadow's band on a rendered scene, end to end (cellctl.vision.shadow_band through the segmentation and the
measurement): a white sole under the side lamp, taught and measured as the cell does. Read as the sole, its band
put the edge in the images beyond the outline, and the edge-offset check refused it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import cellctl.vision.sole_region as sole_region
from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind
from cellctl.eval.sole_bench import scene_frame, taught_reconstructor
from cellctl.sim.matrix import combined_soles
from cellctl.sim.rig import rig_for
from cellctl.sim.scene import SoleScene
from cellctl.vision.measurement import MeasurementResult, SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import SoleReconstructor

# `cellctl bench-sole --matrix --combined --variations shadows --soles 24 --first-seed 50000 --taught`: sole 50003,
# refused before the band was told from the sole, measured right after it (docs/sole-benchmark.md, 38th round).
SEED_INDEX = 3
Shadowed = tuple[SoleScene, SoleReconstructor, StereoFrame]


@pytest.fixture(scope="module")
def shadowed() -> Shadowed:
    sole = combined_soles(SEED_INDEX + 1, 50000, ("shadows",))[SEED_INDEX]
    calib = rig_for(sole.look.rig)
    scene = SoleScene.random(sole.seed, sole.color, calib, sole.look)
    return scene, taught_reconstructor(calib, scene), scene_frame(scene)


def _measure(shadowed: Shadowed) -> MeasurementResult:
    _, reconstructor, frame = shadowed
    reconstruction = reconstructor.reconstruct(  # type: ignore[attr-defined]
        frame.left,
        frame.right,
        frame.averaged,
        frame.info.get("averaged_frames"),  # type: ignore[attr-defined]
    )
    return measure_sole(reconstruction)


def _outline_error_mm(scene: SoleScene, result: MeasurementResult) -> float:
    assert scene.sole is not None and result.outline is not None and result.camera_to_table is not None
    transform = scene.table_from_measured(result.camera_to_table)
    outline = np.asarray(result.outline) @ transform[:2, :2].T + transform[:2, 3]
    truth = scene.sole.footprint_table().astype(np.float32).reshape(-1, 1, 2)
    return max(abs(cv2.pointPolygonTest(truth, (float(x), float(y)), True)) for x, y in outline)


def test_a_shadowed_sole_is_measured_once_its_band_is_the_table(
    shadowed: Shadowed, monkeypatch: pytest.MonkeyPatch
) -> None:
    scene = shadowed[0]
    measured = _measure(shadowed)
    assert isinstance(measured, SoleMeasurement), measured.reason
    assert _outline_error_mm(scene, measured) < 1.0
    monkeypatch.setattr(sole_region, "SHADOW_BANDS", False)
    read_as_sole = _measure(shadowed)
    assert not isinstance(read_as_sole, SoleMeasurement)
    assert read_as_sole.failure is FailureKind.OUTLINE_INCONSISTENT
