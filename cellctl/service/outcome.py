"""One cycle's outcome as the factory sees it (OPC UA, the station): what was measured, with which recipe,
and whether the sole passed. Built by the daemon after the PLC has its answer, handed to listeners.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field


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
