"""The trigger/result handshake with the PLC, on an in-memory image of the register map.

No I/O here: the Modbus server (firmware_io.server) calls the `plc_*` methods from its event-loop
thread for every PLC request, the controller calls the others from its own thread. One lock guards
the image, so every PLC request sees the map either wholly before or wholly after a controller
update: a result is never readable half-written. Three parts: the rules (firmware_io.handshake_state,
pure), the PLC's side with the lock (firmware_io.plc_side), the controller's calls (PlcHandshake, here).

Handshake (docs/modbus.md has the timing diagram):

1. Idle: BUSY=0, READY=1 when cameras and calibration are ok.
2. The PLC writes cycle number N (non-zero, different from the previous cycle) to TRIGGER. Before the
   write is acknowledged: BUSY=1, READY=0, RESULT_VALID=0, ERROR=0, RESULT_CYCLE=0, ERROR_CODE=0 and
   the measurement registers are cleared, so the PLC can never pair a stale result with cycle N.
3. The controller measures and publishes: data registers first, then ERROR_CODE, RESULT_CYCLE=N and
   the status bits (RESULT_VALID or ERROR, BUSY=0), all in one locked update.
4. The PLC polls RESULT_CYCLE until it equals N, then reads status, error code and data.

Map version 2 adds a second PLC-writable register, RECIPE_SELECT: its value when a trigger is accepted is
the recipe of that cycle (Trigger.recipe) and is echoed in RESULT_RECIPE with the result; the controller
decides what a number means. Normals, frame and offsets of the glue path (PathInfo) and the tolerance
check (Inspection) are published in version 2 only; a version 1 map ignores them.

Writes to TRIGGER that start nothing: 0 (the PLC resetting its trigger), the number of the previous
or running cycle (a repeated or retried write). A *different* number while a cycle runs is refused
with Modbus exception 0x06 SERVER DEVICE BUSY and counted in REFUSED_TRIGGERS; the running cycle
goes on undisturbed.
"""

from __future__ import annotations

import time

from numpy.typing import ArrayLike

from firmware_io.handshake_state import Trigger
from firmware_io.plc_side import PlcSide
from firmware_io.registers import ErrorCode, Register, StatusBit
from firmware_io.result_image import Inspection, PathInfo

__all__ = ["Inspection", "PathInfo", "PlcHandshake", "Trigger"]


class PlcHandshake(PlcSide):
    """The handshake shared by the Modbus server thread (PlcSide: requests, heartbeat) and the controller (here).

    The methods here are the controller's; each takes the one lock as PlcSide describes.
    """

    # ---- controller side -----------------------------------------------------------------------

    @property
    def status(self) -> StatusBit:
        """The status register as the PLC reads it now."""
        with self._changed:
            return StatusBit(self._image[Register.STATUS])

    def wait_trigger(self, timeout_s: float | None, liveness_slice_s: float) -> Trigger | None:
        """The next accepted trigger, or None after timeout_s (or once closed).

        Waits in slices so a controller blocked here still counts as alive for the heartbeat.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        with self._changed:
            while True:
                self._state.controller_seen_at = time.monotonic()
                if self._state.pending is not None or self._closed:
                    return self._state.take_pending()
                wait = liveness_slice_s
                if deadline is not None:
                    wait = min(wait, deadline - time.monotonic())
                    if wait <= 0:
                        return None
                self._changed.wait(wait)  # lets go of the lock while waiting

    def timed_out(self, cycle: int) -> bool:
        """True if the link answered `cycle` with CYCLE_TIMEOUT itself (its result will not be published)."""
        with self._changed:
            return self._state.answered_by_link(cycle)

    def restore_last_cycle(self, cycle: int) -> None:
        """After a restart: the cycle answered last (from the journal); writing it again starts nothing.

        The trigger register shows it, as the PLC left it, so `max(reg 2, reg 3) + 1` stays the next number.
        """
        with self._changed:
            self._state.restore(cycle)
            self._image[Register.TRIGGER] = cycle

    def set_health(self, *, cameras_ok: bool, calibration_ok: bool) -> None:
        """Report camera and calibration state (status bits 4, 5 and hence READY)."""
        with self._changed:
            self._state.controller_seen_at = time.monotonic()
            self._result.set_flag(StatusBit.CAMERAS_OK, cameras_ok)
            self._result.set_flag(StatusBit.CALIBRATION_OK, calibration_ok)
            self._update_status()

    def publish_result(
        self,
        cycle: int,
        *,
        heel_height_mm: float,
        toe_height_mm: float,
        length_mm: float,
        cycle_time_ms: float,
        glue_points: ArrayLike,
        path: PathInfo | None = None,
        inspection: Inspection | None = None,
    ) -> bool:
        """Hand the PLC the measurement of `cycle`; refuses values that are not finite.

        Map version 2 needs `path` (normals); `inspection` None means no tolerances were checked (neither
        tolerance bit set). Version 1 publishes neither. False (and nothing published) if the cycle was
        already answered with CYCLE_TIMEOUT.
        """
        values = {
            "heel_height_mm": heel_height_mm,
            "toe_height_mm": toe_height_mm,
            "length_mm": length_mm,
            "cycle_time_ms": cycle_time_ms,
        }
        # Encode before taking the lock: a refused value leaves the map untouched.
        result = self._result.encode_result(values, glue_points, path, inspection)
        with self._changed:
            return self._finish(cycle, result)

    def publish_error(self, cycle: int, code: ErrorCode, *, cycle_time_ms: float) -> bool:
        """Tell the PLC that `cycle` ended with `code`; measurements read NaN and no glue points.

        False (and nothing published) if the cycle was already answered with CYCLE_TIMEOUT.
        """
        code = ErrorCode(code)
        if code is ErrorCode.NONE:
            raise ValueError("publish_error needs an error code other than ErrorCode.NONE")
        result = self._result.encode_error(code, cycle_time_ms)
        with self._changed:
            return self._finish(cycle, result)

    def close(self) -> None:
        """Wake any wait_trigger() so the controller can stop."""
        with self._changed:
            self._closed = True
            self._changed.notify_all()
