"""What measuring one sole gives: `SoleMeasurement` (with its `GluePath`) or `MeasurementRefused`.

Callers narrow `MeasurementResult` with isinstance: a success has every number, a refusal has none, only
its `FailureKind` (what a program acts on, e.g. the service's PLC code), the reason in words and what was
found before the refusal, for pictures.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cellctl.errors import FailureKind


@dataclass
class GluePath:
    """Closed path on the sole's top surface, table frame, ordered from the heel end (first point not repeated)."""

    points: np.ndarray  # N x 3, mm
    normals: np.ndarray  # N x 3, unit, nz > 0
    closed: bool = True
    # What the path was made from, for its self-check (cellctl.vision.checks): per point, the height of the
    # surface patch before smoothing along the path, and the patches' own normals smoothed along it.
    raw_z: np.ndarray | None = None
    surface_normals: np.ndarray | None = None
    # Per point the expected error (sd, mm) of its height: the noise and bias of the fit along the path that gave
    # it (cellctl.vision.surface.path_heights), for the glue-precision check.
    height_sd: np.ndarray | None = None
    # Per point how far (mm) its height stands above the top's course further in (cellctl.vision.glue_path: NaN where
    # not read), for the raised-lip check (checks.check_glue_rise).
    edge_rise: np.ndarray | None = None

    @property
    def length_mm(self) -> float:
        steps = np.diff(np.vstack([self.points, self.points[:1]]) if self.closed else self.points, axis=0)
        return float(np.linalg.norm(steps, axis=1).sum())


@dataclass
class SoleMeasurement:
    """The measurements of one sole (the success of `MeasurementResult`)."""

    length_mm: float
    heel_height_mm: float
    toe_height_mm: float
    glue_path: GluePath
    points: int  # sole points the measurement rests on
    # Where the numbers come from (table frame), for drawings and diagnostics.
    axis: np.ndarray  # unit heel->toe direction (x, y)
    heel_point: np.ndarray  # (x, y, z) where heel_height_mm is taken
    toe_point: np.ndarray
    outline: np.ndarray  # footprint outline, N x 2
    half_area_difference: float  # (toe half - heel half) / area
    camera_to_table: np.ndarray  # 4 x 4, rectified left camera -> table
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        return True

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary (keys of the `cellctl measure --json` output)."""
        path = self.glue_path
        return {
            "length_mm": _round(self.length_mm),
            "heel_height_mm": _round(self.heel_height_mm),
            "toe_height_mm": _round(self.toe_height_mm),
            "glue_path": np.round(path.points, 3).tolist(),
            "glue_normals": np.round(path.normals, 4).tolist(),
            "points": int(self.points),
            "valid": True,
            "reason": None,
            "failure": None,
            "heel_point": np.round(self.heel_point, 3).tolist(),
            "toe_point": np.round(self.toe_point, 3).tolist(),
            "camera_to_table": np.round(self.camera_to_table, 6).tolist(),
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


@dataclass
class MeasurementRefused:
    """No measurements: why (kind for programs, reason for people) and what was found before the refusal
    (None where the measurement did not get that far), for pictures and diagnostics."""

    failure: FailureKind
    reason: str
    points: int  # sole points found
    timings: dict[str, float] = field(default_factory=dict)
    axis: np.ndarray | None = None
    heel_point: np.ndarray | None = None
    toe_point: np.ndarray | None = None
    outline: np.ndarray | None = None
    half_area_difference: float | None = None
    camera_to_table: np.ndarray | None = None
    # Set where the scene on the mean of this many exposures in all may be measured (checks.CheckFailure).
    more_exposures: int | None = None

    @property
    def valid(self) -> bool:
        return False

    def to_dict(self) -> dict[str, object]:
        """JSON-ready summary: the keys of SoleMeasurement.to_dict, without numbers."""
        return {
            "length_mm": None,
            "heel_height_mm": None,
            "toe_height_mm": None,
            "glue_path": [],
            "glue_normals": [],
            "points": int(self.points),
            "valid": False,
            "reason": self.reason,
            "failure": self.failure.value,
            "heel_point": None if self.heel_point is None else np.round(self.heel_point, 3).tolist(),
            "toe_point": None if self.toe_point is None else np.round(self.toe_point, 3).tolist(),
            "camera_to_table": None if self.camera_to_table is None else np.round(self.camera_to_table, 6).tolist(),
            "timings_s": {k: round(v, 4) for k, v in self.timings.items()},
        }


MeasurementResult = SoleMeasurement | MeasurementRefused


def _round(value: float) -> float:
    return round(float(value), 3)
