"""The trigger/result handshake with the PLC, on an in-memory image of the register map.

This module does no I/O: the Modbus server (firmware_io.server) calls the `plc_*` methods from its
event-loop thread for every PLC request, the controller calls the others from its own thread. One
lock guards the image, so every PLC request sees the map either wholly before or wholly after a
controller update: a result is never readable half-written.

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

import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

from numpy.typing import ArrayLike

from firmware_io.pdu import ExceptionCode
from firmware_io.registers import ErrorCode, MapLayout, Register, RegisterMap, StatusBit
from firmware_io.result_image import EncodedResult, Inspection, PathInfo, ResultImage

__all__ = ["Inspection", "PathInfo", "PlcHandshake", "Trigger"]


@dataclass(frozen=True)
class Trigger:
    """A cycle the PLC started."""

    cycle: int  #: the number the PLC wrote, 1..65535
    received_at: float  #: time.monotonic() when the trigger write arrived; cycle time counts from here
    recipe: int = 0  #: RECIPE_SELECT when the trigger was accepted (map v2; always 0 in version 1)


class PlcHandshake:
    """Register image plus handshake state, shared by the Modbus server thread and the controller.

    Over 150 lines (~225, most of it the public methods' documentation): one state machine under one lock,
    which the PLC's requests and the controller's calls both change; what the result registers hold is
    firmware_io.result_image.
    """

    def __init__(self, register_map: RegisterMap, layout: MapLayout | None = None) -> None:
        self.layout = MapLayout.of(1) if layout is None else layout
        self._changed = threading.Condition()  # its lock guards everything below
        self._result = ResultImage(register_map, self.layout)
        self._image = self._result.registers
        self._running: int | None = None
        self._running_recipe = 0
        self._running_since: float | None = None
        self._last_accepted = 0
        self._timed_out: int | None = None  # the cycle the link answered with CYCLE_TIMEOUT itself
        self._pending: Trigger | None = None
        self._closed = False
        self._controller_seen_at = time.monotonic()
        self._update_status()

    # ---- PLC side: called by the Modbus server for each request -------------------------------

    @property
    def map_size(self) -> int:
        """Registers in the served map (firmware_io.pdu refuses reads beyond it)."""
        return self.layout.size

    @property
    def plc_writable(self) -> frozenset[int]:
        """Registers a PLC may write in the served map version."""
        return self.layout.plc_writable

    def plc_read(self, address: int, count: int) -> list[int]:
        """Registers [address, address + count) as the PLC sees them now."""
        with self._changed:
            return self._image[address : address + count]

    def plc_write(self, address: int, values: Sequence[int]) -> ExceptionCode | None:
        """Apply a PLC write to the trigger; returns the Modbus exception to answer with, or None.

        Writes to read-only registers never get here: firmware_io.pdu refuses them first (exception
        0x02), so anything else is a bug in the server wiring.
        """
        if address not in self.layout.plc_writable or len(values) != 1:
            also = " (and recipe select, map v2)" if self.layout.version >= 2 else ""
            raise ValueError(f"only the trigger register is writable{also}, got {len(values)} values at {address}")
        if address == Register.RECIPE_SELECT:
            with self._changed:
                self._image[Register.RECIPE_SELECT] = int(values[0])
            return None
        cycle = int(values[0])
        with self._changed:
            if cycle == 0 or cycle == self._last_accepted:
                self._image[Register.TRIGGER] = cycle
                return None
            if self._running is not None:
                refused = self._image[Register.REFUSED_TRIGGERS]
                self._image[Register.REFUSED_TRIGGERS] = (refused + 1) & 0xFFFF
                return ExceptionCode.DEVICE_BUSY
            self._accept(cycle)
            return None

    def expire_overdue(self, cycle_timeout_s: float | None) -> int | None:
        """Answer a cycle older than cycle_timeout_s with CYCLE_TIMEOUT; returns its number, if any.

        The link does this itself because the controller may be stuck inside the cycle: the PLC gets
        an answer with a reason instead of waiting into its own timeout.
        """
        with self._changed:
            started = self._running_since
            if self._running is None or started is None or cycle_timeout_s is None:
                return None
            age_s = time.monotonic() - started
            if age_s <= cycle_timeout_s:
                return None
            expired = self._timed_out = self._running
            self._finish(expired, self._result.encode_error(ErrorCode.CYCLE_TIMEOUT, age_s * 1000.0))
            return expired

    def beat(self, liveness_timeout_s: float | None) -> bool:
        """Advance the heartbeat if the controller is alive and working; True if it advanced.

        "Working": a cycle is running (expire_overdue bounds how long that lasts), or the controller
        made a call (a waiting wait_trigger() counts) within liveness_timeout_s.
        """
        with self._changed:
            silent_for = time.monotonic() - self._controller_seen_at
            if self._running is None and liveness_timeout_s is not None and silent_for > liveness_timeout_s:
                return False
            self._advance_heartbeat()
            return True

    def _advance_heartbeat(self) -> None:
        self._image[Register.HEARTBEAT] = (self._image[Register.HEARTBEAT] + 1) & 0xFFFF

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
                self._controller_seen_at = time.monotonic()
                if self._pending is not None or self._closed:
                    trigger, self._pending = self._pending, None
                    return trigger
                wait = liveness_slice_s
                if deadline is not None:
                    wait = min(wait, deadline - time.monotonic())
                    if wait <= 0:
                        return None
                self._changed.wait(wait)

    def timed_out(self, cycle: int) -> bool:
        """True if the link answered `cycle` with CYCLE_TIMEOUT itself (its result will not be published)."""
        with self._changed:
            return cycle == self._timed_out and cycle != self._running

    def restore_last_cycle(self, cycle: int) -> None:
        """After a restart: the cycle answered last (from the journal); writing it again starts nothing.

        The trigger register shows it, as the PLC left it, so `max(reg 2, reg 3) + 1` stays the next number.
        """
        if not 0 <= cycle <= 0xFFFF:
            raise ValueError(f"last cycle {cycle} is not a cycle number 0..65535")
        with self._changed:
            if self._last_accepted != 0 or self._running is not None:
                raise RuntimeError("restore_last_cycle() is for a fresh link, before the PLC triggered anything")
            self._last_accepted = cycle
            self._image[Register.TRIGGER] = cycle

    def set_health(self, *, cameras_ok: bool, calibration_ok: bool) -> None:
        """Report camera and calibration state (status bits 4, 5 and hence READY)."""
        with self._changed:
            self._controller_seen_at = time.monotonic()
            self._set_flag(StatusBit.CAMERAS_OK, cameras_ok)
            self._set_flag(StatusBit.CALIBRATION_OK, calibration_ok)
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

    # ---- internals (lock held) -----------------------------------------------------------------

    def _accept(self, cycle: int) -> None:
        self._image[Register.TRIGGER] = cycle
        self._running = self._last_accepted = cycle
        self._running_since = time.monotonic()
        self._result.clear()
        self._update_status()
        self._running_recipe = self._image[Register.RECIPE_SELECT] if self.layout.version >= 2 else 0
        self._pending = Trigger(cycle, time.monotonic(), self._running_recipe)
        self._changed.notify_all()

    def _finish(self, cycle: int, result: EncodedResult) -> bool:
        self._controller_seen_at = time.monotonic()
        if cycle == self._timed_out and cycle != self._running:
            return False  # the link answered it with CYCLE_TIMEOUT already; the late result is dropped
        if cycle != self._running:
            raise RuntimeError(
                f"cannot publish cycle {cycle}: the running cycle is {self._running} "
                "(publish exactly once per trigger, with the trigger's cycle number)"
            )
        self._result.write(cycle, result, self._running_recipe)
        self._running = None
        self._running_since = None
        self._update_status()
        return True

    def _set_flag(self, bit: StatusBit, on: bool) -> None:
        self._result.set_flag(bit, on)

    def _update_status(self) -> None:
        self._result.update_status(busy=self._running is not None)
