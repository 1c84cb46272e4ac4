"""The handshake as the PLC reaches it: the register image under the handshake's one lock, trigger writes,
the heartbeat and the cycle timeout; and the transitions both sides make (a cycle accepted, a cycle answered).

firmware_io.handshake.PlcHandshake adds the controller's calls on top of this; firmware_io.pdu executes the
PLC's requests against it (firmware_io.pdu.RegisterAccess) and the server thread's heartbeat calls beat()
and expire_overdue(). The rules are firmware_io.handshake_state, the register contents firmware_io.result_image.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence

from firmware_io.handshake_state import HandshakeState, TriggerWrite
from firmware_io.pdu import ExceptionCode
from firmware_io.registers import ErrorCode, MapLayout, Register, RegisterMap
from firmware_io.result_image import EncodedResult, ResultImage


class PlcSide:
    """Register image plus handshake state, and what the PLC's requests and the heartbeat do to them.

    Lock discipline: one lock (the condition `_changed`) guards the state (firmware_io.handshake_state, its
    transitions), the register image (firmware_io.result_image, what the registers hold) and `_closed`. Every
    public method, here and in PlcHandshake, takes it once, makes its transition and writes the registers it
    asks for before letting go, so a PLC request sees a whole transition or none; the `_` methods below run
    with it held. Encoding a result happens before taking it.
    """

    def __init__(self, register_map: RegisterMap, layout: MapLayout | None = None) -> None:
        self.layout = MapLayout.of(1) if layout is None else layout
        self._changed = threading.Condition()  # its lock guards everything below
        self._result = ResultImage(register_map, self.layout)
        self._image = self._result.registers
        self._state = HandshakeState(controller_seen_at=time.monotonic())
        self._closed = False
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
        value = int(values[0])
        with self._changed:
            if address == Register.RECIPE_SELECT:
                self._image[Register.RECIPE_SELECT] = value
                return None
            write = self._state.trigger_write(value)
            if write is TriggerWrite.REFUSED:
                self._image[Register.REFUSED_TRIGGERS] = (self._image[Register.REFUSED_TRIGGERS] + 1) & 0xFFFF
                return ExceptionCode.DEVICE_BUSY
            self._image[Register.TRIGGER] = value
            if write is TriggerWrite.ACCEPTED:
                self._accept(value)
            return None

    def expire_overdue(self, cycle_timeout_s: float | None) -> int | None:
        """Answer a cycle older than cycle_timeout_s with CYCLE_TIMEOUT; returns its number, if any.

        The link does this itself because the controller may be stuck inside the cycle: the PLC gets
        an answer with a reason instead of waiting into its own timeout.
        """
        with self._changed:
            age_s = self._state.overdue_for(time.monotonic(), cycle_timeout_s)
            expired = self._state.running
            if age_s is None or expired is None:
                return None
            self._finish(expired, self._result.encode_error(ErrorCode.CYCLE_TIMEOUT, age_s * 1000.0), by_link=True)
            return expired

    def beat(self, liveness_timeout_s: float | None) -> bool:
        """Advance the heartbeat if the controller is alive and working (HandshakeState.heartbeat_may_advance)."""
        with self._changed:
            if not self._state.heartbeat_may_advance(time.monotonic(), liveness_timeout_s):
                return False
            self._image[Register.HEARTBEAT] = (self._image[Register.HEARTBEAT] + 1) & 0xFFFF
            return True

    # ---- internals (lock held) -----------------------------------------------------------------

    def _accept(self, cycle: int) -> None:
        recipe = self._image[Register.RECIPE_SELECT] if self.layout.version >= 2 else 0
        self._state.accept(cycle, recipe, time.monotonic())
        self._result.clear()
        self._update_status()
        self._changed.notify_all()

    def _finish(self, cycle: int, result: EncodedResult, *, by_link: bool = False) -> bool:
        self._state.controller_seen_at = time.monotonic()  # an answer by the link, too, restarts the liveness count
        if not self._state.finish(cycle, by_link=by_link):
            return False  # the link answered it with CYCLE_TIMEOUT already; the late result is dropped
        self._result.write(cycle, result, self._state.recipe)
        self._update_status()
        return True

    def _update_status(self) -> None:
        self._result.update_status(busy=self._state.running is not None)
