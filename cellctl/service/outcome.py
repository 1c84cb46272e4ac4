"""One cycle's outcome: as the journal keeps it (`journal_record`) and as the factory sees it (`CycleOutcome`
for OPC UA and the station: what was measured, with which recipe, and whether the sole passed). Built by
the daemon after the cycle; listeners get it after the PLC has its answer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cellctl.cameras.base import StereoFrame
from cellctl.service.glue_output import thinned
from cellctl.service.journal import CycleRecord
from cellctl.service.recipes import Recipe
from cellctl.vision.measurement import SoleMeasurement
from firmware_io.registers import ErrorCode, FeatureBit


@dataclass(frozen=True)
class CycleOutcome:
    """A finished cycle; measurements are NaN when the cycle failed."""

    result_id: str  #: unique per cell and cycle: "<cell>-<triggered_at in ms>-<cycle>"
    cycle: int
    triggered_at: float  #: wall clock, Unix seconds
    recipe: int
    recipe_name: str
    error_code: int  #: firmware_io ErrorCode, 0 = measured
    error_name: str
    length_mm: float = math.nan
    heel_height_mm: float = math.nan
    toe_height_mm: float = math.nan
    cycle_time_ms: float = math.nan
    glue_points: int = 0
    in_tolerance: bool | None = None  #: None: no tolerances checked (recipe 0, or no valid measurement)
    failed_features: tuple[str, ...] = field(default_factory=tuple)

    @property
    def measured(self) -> bool:
        return self.error_code == 0

    @property
    def passed(self) -> bool:
        """Measured, and within every tolerance checked (a result without tolerances passes if measured)."""
        return self.measured and self.in_tolerance is not False


OutcomeListener = Callable[[CycleOutcome], None]


def outcome_of(cell: str, record: CycleRecord, recipe: Recipe | None) -> CycleOutcome:
    """The outcome of a journaled cycle; `recipe` is the one its number named (None: unknown number)."""
    code = ErrorCode(record.error_code)
    nan = math.nan
    return CycleOutcome(
        result_id=f"{cell}-{int(record.triggered_at * 1000)}-{record.cycle}",
        cycle=record.cycle,
        triggered_at=record.triggered_at,
        recipe=record.recipe,
        recipe_name="" if recipe is None else recipe.name,
        error_code=int(code),
        error_name=code.name,
        length_mm=nan if record.length_mm is None else record.length_mm,
        heel_height_mm=nan if record.heel_height_mm is None else record.heel_height_mm,
        toe_height_mm=nan if record.toe_height_mm is None else record.toe_height_mm,
        cycle_time_ms=record.cycle_time_ms,
        glue_points=len(record.glue_path),
        in_tolerance=record.in_tolerance,
        failed_features=tuple(record.failed_features),
    )


def journal_record(
    cycle: int,
    triggered_at: float,
    code: ErrorCode,
    reason: str | None,
    cycle_time_ms: float,
    timings: dict[str, float],
    measurement: SoleMeasurement | None,
    frame: StereoFrame | None,
    recipe: int = 0,
    failed: FeatureBit | None = None,
) -> CycleRecord:
    """The journal row of a finished cycle (measurements only when it was measured); `recipe` the number the
    PLC selected, `failed` the features out of tolerance (None: nothing checked)."""
    record = CycleRecord(
        cycle=cycle,
        recipe=recipe,
        triggered_at=triggered_at,
        status="error",
        error_code=int(code),
        reason=reason,
        cycle_time_ms=cycle_time_ms,
        timings={k: round(v, 5) for k, v in timings.items()},
        source={} if frame is None else {**frame.info, "skew_ms": round(frame.skew_s * 1000.0, 3)},
    )
    if code is not ErrorCode.NONE or measurement is None:
        return record
    path = measurement.glue_path
    record.status = "ok"
    if failed is not None:
        record.in_tolerance = not failed
        record.failed_features = [bit.name or "" for bit in FeatureBit if failed & bit]
    record.length_mm = float(measurement.length_mm)
    record.heel_height_mm = float(measurement.heel_height_mm)
    record.toe_height_mm = float(measurement.toe_height_mm)
    # Table frame, thinned and float32 as the PLC gets it with [robot] publish_frame = "table" and no nozzle
    # offset: the journal keeps the measurement, whatever frame the robot is given.
    record.glue_path = path.points[thinned(len(path.points))].astype(np.float32).astype(float).tolist()
    return record
