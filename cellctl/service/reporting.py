"""Telling a finished cycle, in the service's order: the journal first (SQLite commit: durable before the
PLC hears of it), then the PLC (result or error, one atomic update), then the listeners (OPC UA, station).

A cycle the PLC link has already answered with CYCLE_TIMEOUT keeps that answer: its late result is not
published, and the journal says what the PLC was told.
"""

from __future__ import annotations

import logging
import time

from cellctl.cameras import StereoFrame
from cellctl.service.config import CellConfig
from cellctl.service.cycle import Measured
from cellctl.service.glue_output import GlueOutput
from cellctl.service.journal import CycleRecord, Journal
from cellctl.service.outcome import OutcomeListener, journal_record, outcome_of
from cellctl.service.recipes import Recipe
from cellctl.vision.measurement import SoleMeasurement
from firmware_io.handshake import Inspection, PathInfo, Trigger
from firmware_io.registers import ErrorCode, FeatureBit
from firmware_io.server import PlcLink

log = logging.getLogger("cellctl.service.daemon")  # the service's one log, as operators know it


class CycleReporter:
    """Journals and publishes finished and aborted cycles; tells the listeners."""

    def __init__(self, config: CellConfig, link: PlcLink, glue_output: GlueOutput) -> None:
        self.config, self.link, self.glue_output = config, link, glue_output
        #: Called with each finished cycle after the PLC has its answer (OPC UA, station); must not block.
        self.listeners: list[OutcomeListener] = []

    def report(
        self,
        journal: Journal,
        trigger: Trigger,
        outcome: tuple[ErrorCode, str | None, Measured | None],
        timings: dict[str, float],
        frame: StereoFrame | None,
        recipe: Recipe | None,
    ) -> tuple[CycleRecord, Measured | None]:
        """Journal, then publish a finished cycle; the record and the result as published (None: not)."""
        code, reason, result = outcome
        triggered_at = time.time() - (time.monotonic() - trigger.received_at)
        cycle_time_ms = (time.monotonic() - trigger.received_at) * 1000.0
        late = f"not published within cycle_timeout_s = {self.config.plc.cycle_timeout_s:g} s (took {cycle_time_ms:.0f} ms)"
        if self.link.timed_out(trigger.cycle):  # the link answered CYCLE_TIMEOUT: the late result is not used
            code, reason, result = ErrorCode.CYCLE_TIMEOUT, late, None
        measurement = None if result is None else result.measurement
        failed = inspect(recipe, measurement) if code is ErrorCode.NONE else None
        record = journal_record(
            trigger.cycle,
            triggered_at,
            code,
            reason,
            cycle_time_ms,
            timings,
            measurement,
            frame,
            trigger.recipe,
            failed,
        )
        row_id = journal.record(record)  # durable before the PLC hears of it
        if (
            not self._publish(trigger.cycle, code, cycle_time_ms, measurement, recipe, failed)
            and code is not ErrorCode.CYCLE_TIMEOUT
        ):
            # It timed out between the check above and publishing: the journal says what the PLC was told.
            journal.amend_error(row_id, int(ErrorCode.CYCLE_TIMEOUT), late)
            code, reason, result = ErrorCode.CYCLE_TIMEOUT, late, None
            record = journal_record(
                trigger.cycle, triggered_at, code, reason, cycle_time_ms, timings, None, frame, trigger.recipe, None
            )
        return record, result

    def abort(self, journal: Journal, trigger: Trigger, recipe: Recipe | None) -> CycleRecord:
        """Answer a trigger that arrived once stopping had begun with CYCLE_ABORTED."""
        reason = "the service is stopping"
        cycle_time_ms = (time.monotonic() - trigger.received_at) * 1000.0
        triggered_at = time.time() - (time.monotonic() - trigger.received_at)
        code = ErrorCode.CYCLE_ABORTED
        record = journal_record(
            trigger.cycle, triggered_at, code, reason, cycle_time_ms, {}, None, None, trigger.recipe
        )
        journal.record(record)
        self.link.publish_error(trigger.cycle, ErrorCode.CYCLE_ABORTED, cycle_time_ms=cycle_time_ms)
        self.tell_listeners(record, recipe)
        log.warning("cycle %d: aborted, %s", trigger.cycle, reason)
        return record

    def tell_listeners(self, record: CycleRecord, recipe: Recipe | None) -> None:
        if not self.listeners:
            return
        outcome = outcome_of(self.config.opcua.cell_name, record, recipe)
        for listener in self.listeners:
            try:
                listener(outcome)
            except Exception:  # a listener's fault never stops the line
                log.exception("cycle %d: result listener %r failed", record.cycle, listener)

    def _publish(
        self,
        cycle: int,
        code: ErrorCode,
        cycle_time_ms: float,
        measurement: SoleMeasurement | None,
        recipe: Recipe | None,
        failed: FeatureBit | None,
    ) -> bool:
        """Answer the PLC (False if the link had answered CYCLE_TIMEOUT already); `failed`: the features out of
        tolerance (None when nothing was checked)."""
        if code is not ErrorCode.NONE or measurement is None or recipe is None:
            return self.link.publish_error(cycle, code, cycle_time_ms=cycle_time_ms)
        out = self.glue_output.prepare(measurement.glue_path.points, measurement.glue_path.normals)
        return self.link.publish_result(
            cycle,
            heel_height_mm=measurement.heel_height_mm,
            toe_height_mm=measurement.toe_height_mm,
            length_mm=measurement.length_mm,
            cycle_time_ms=cycle_time_ms,
            glue_points=out.points,
            path=PathInfo(out.normals, out.frame, out.nozzle_offset_mm, recipe.glue_offset_mm),
            inspection=None if failed is None else Inspection(failed),
        )


def log_cycle(record: CycleRecord) -> None:
    """One line per cycle in the service's log."""
    if record.error_code == ErrorCode.NONE:
        log.info(
            "cycle %d: length %.2f heel %.2f toe %.2f mm, %d glue points, %.0f ms",
            record.cycle,
            record.length_mm,
            record.heel_height_mm,
            record.toe_height_mm,
            len(record.glue_path),
            record.cycle_time_ms,
        )
    else:
        code = ErrorCode(record.error_code)
        log.warning(
            "cycle %d: error %d %s: %s (%.0f ms)", record.cycle, code, code.name, record.reason, record.cycle_time_ms
        )


def inspect(recipe: Recipe | None, measurement: SoleMeasurement | None) -> FeatureBit | None:
    """Features of a measured sole outside the recipe's tolerances; None when the recipe checks nothing."""
    if recipe is None or measurement is None or not recipe.checks_tolerances:
        return None
    return recipe.inspect(measurement.length_mm, measurement.heel_height_mm, measurement.toe_height_mm)
