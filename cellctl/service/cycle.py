"""One cycle as a pure function: a stereo frame in, a result out.

No sockets, no journal, no PLC: `measure_frame` is what the daemon calls between grabbing a pair and
publishing the answer, and what tests call directly. The result is a success (`Measured`) or a failure
(`Refused`, with its kind and reason) by type.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind, MeasurementInputError
from cellctl.vision.defaults import GLUE_HEIGHT_TOLERANCE_MM
from cellctl.vision.measurement import MeasurementRefused, SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import Reconstruction, SoleReconstructor
from cellctl.vision.stereo_order import cameras_swapped

#: What swapped cameras look like to the measurement: the matcher finds (almost) nothing on the table.
_SWAP_SYMPTOMS = (FailureKind.TOO_FEW_POINTS, FailureKind.NO_TABLE, FailureKind.SURFACE_NOT_MEASURED)
SWAPPED = (
    "left and right cameras are swapped (the table's disparity is negative): exchange the cameras' cables "
    "or the [cameras] left/right devices in the config"
)


@dataclass(frozen=True)
class MeasureSettings:
    """What a cycle needs to know beyond the frame: glue path offset and spacing, the glue heights' tolerance
    (mm), and what the line knows of the sole model's wall (measure_sole's wall_draft_deg)."""

    glue_offset_mm: float
    glue_spacing_mm: float
    glue_height_tolerance_mm: float = GLUE_HEIGHT_TOLERANCE_MM
    wall_draft_deg: float | None = None


@dataclass(frozen=True)
class Measured:
    """A valid measurement of the sole in the frame."""

    reconstruction: Reconstruction
    measurement: SoleMeasurement
    timings: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Refused:
    """No valid result: why (kind for programs, reason for people)."""

    failure: FailureKind
    reason: str
    timings: dict[str, float] = field(default_factory=dict)
    # Set where the same still sole on the mean of this many exposures in all may be measured (the glue heights'
    # precision: cellctl.vision.checks.CheckFailure).
    more_exposures: int | None = None


CycleResult = Measured | Refused


def measure_frame(frame: StereoFrame, reconstructor: SoleReconstructor, settings: MeasureSettings) -> CycleResult:
    """Reconstruct and measure the sole in one synchronised pair."""
    try:
        reconstruction = reconstructor.reconstruct(
            frame.left, frame.right, frame.averaged, frame.info.get("averaged_frames")
        )
    except MeasurementInputError as exc:  # e.g. frames of another size than the calibration
        return Refused(exc.kind, f"cameras deliver frames the measurement cannot use: {exc}")
    measurement = measure_sole(
        reconstruction,
        settings.glue_offset_mm,
        settings.glue_spacing_mm,
        settings.glue_height_tolerance_mm,
        wall_draft_deg=settings.wall_draft_deg,
    )
    timings = dict(measurement.timings)
    if isinstance(measurement, MeasurementRefused):
        if measurement.failure in _SWAP_SYMPTOMS and cameras_swapped(
            reconstructor.calib, frame.left, frame.right, reconstructor.min_disparity
        ):
            return Refused(FailureKind.CALIBRATION_MISMATCH, SWAPPED, timings)
        return Refused(measurement.failure, measurement.reason, timings, measurement.more_exposures)
    # A measurement is only made of a reconstruction that found a sole.
    assert isinstance(reconstruction, Reconstruction)
    return Measured(outliving_the_cycle(reconstruction), measurement, timings)


def outliving_the_cycle(reconstruction: Reconstruction) -> Reconstruction:
    """The reconstruction as the cycle's result keeps it: the sole's points, colours, pixels and footprint, without
    the image-sized rasters only the measurement reads (the rectified pair and the surface fits' pair, the sole and
    change masks, the depth-step rasters).

    The result outlives its cycle: the artifact writer holds it until its PLY and overlay are written, the
    operator station until the next cycle ends, the image log while it waits. The rasters are ~20 MB a cycle
    (two float32 1280 x 1024 images alone are 10 MB), and held into the next cycles they split the heap the
    cycles allocate from: in the demo glibc grew it by 58 MB in cycles 7-19 although a third of it was free, each
    new page a fault in the measurement (0.3-2k in each of 6 cycles). Without them the heap stays as the warm-up left it."""
    return replace(
        reconstruction,
        rectified=None,
        surface_grey=None,
        sole_mask=None,
        raised=None,
        measured_cells=None,
        table_points=None,
        changed_left=None,
        changed_right=None,
    )
