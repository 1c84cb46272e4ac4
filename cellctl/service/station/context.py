"""What the station's handlers read: the daemon's shared objects and the station's own parts."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cellctl.service.imagelog import ImageLog
from cellctl.service.journal import CycleRecord, Journal
from cellctl.service.metrics import CellMetrics
from cellctl.service.operator_text import describe_code
from cellctl.service.station.actions import CameraActions
from cellctl.service.station.hub import StationHub
from cellctl.service.station.live import LiveView
from cellctl.service.timefmt import local_time

HISTORY_SCAN = 5000  # newest journal rows the history page filters; older ones: `cellctl results --csv`


@dataclass
class StationContext:
    """Built by Station.attach(); one per service."""

    hub: StationHub
    metrics: CellMetrics
    image_log: ImageLog
    live: LiveView
    actions: CameraActions
    state_dir: Path
    calibration_path: Path
    token: str | None
    plc: Any  # firmware_io PlcLink (connected clients, heartbeat), or None
    cell_name: str
    active_recipe: Callable[[], tuple[int, str] | None] | None = None  # (number, name) the cell measures with
    taught_problem: str = ""  # why the cell has no taught table ("": loaded; cellctl.service.measuring)
    taught_required: bool = True  # [measure] require_taught_table: without one every cycle is refused

    def cell_view(self) -> dict[str, Any]:
        """The state panel's and last result's facts, as the pages and /api/state show them."""
        s, plc = self.hub.state, self.plc
        return {
            "phase": s.phase,
            "cameras_ok": s.cameras_ok,
            "calibration_ok": s.calibration_ok,
            "cycles_done": s.cycles_done,
            "cycle": s.cycle,
            "plc_clients": None if plc is None else plc.connected_clients,
            "heartbeat_ok": None if plc is None else not plc.heartbeat_stalled,
            "recipe": None if self.active_recipe is None else self.active_recipe(),
            "state_version": self.hub.state_version,
            "cycle_version": self.hub.cycle_version,
            "last": self._last_view(),
        }

    def _last_view(self) -> dict[str, Any] | None:
        last = self.hub.last
        if last is None:
            return None
        r = last.record
        name, meaning, action = describe_code(r.error_code)
        return {
            "row_id": r.id,
            "cycle": r.cycle,
            "time": local_time(r.triggered_at),
            "ok": r.status == "ok",
            "cycle_time_ms": round(r.cycle_time_ms),
            "length_mm": r.length_mm,
            "heel_height_mm": r.heel_height_mm,
            "toe_height_mm": r.toe_height_mm,
            "glue_points": len(r.glue_path),
            "error_code": r.error_code,
            "error_name": name,
            "error_meaning": meaning,
            "error_action": action,
            "reason": r.reason,
            "has_picture": last.frame is not None,
            "recipe": r.recipe,
            # Out of tolerance is a measured sole that fails its recipe: the operator sees FAIL.
            "passed": r.status == "ok" and r.in_tolerance is not False,
            "in_tolerance": r.in_tolerance,
            "failed_features": [name.replace("_", " ").lower() for name in r.failed_features],
        }

    def journal_rows(self) -> list[CycleRecord]:
        """The newest HISTORY_SCAN cycles (a read-only connection per call: SQLite WAL, never blocks the service)."""
        journal = self._journal()
        if journal is None:
            return []
        try:
            return journal.last(HISTORY_SCAN)
        finally:
            journal.close()

    def journal_row(self, row_id: int) -> CycleRecord | None:
        journal = self._journal()
        if journal is None:
            return None
        try:
            return journal.get(row_id)
        finally:
            journal.close()

    def _journal(self) -> Journal | None:
        try:
            return Journal.open(self.state_dir, readonly=True)
        except FileNotFoundError:
            return None
