"""What the link does on its own every heartbeat period: answer an overdue cycle with CYCLE_TIMEOUT, then advance
the heartbeat register while the controller is alive, counting the times it stopped.

The timing limits are checked here, where they are used; PlcLink passes them on and documents them. The
server thread (firmware_io.server_thread) runs `Heartbeat.run()` as a task on its event loop; every tick is
one call each to the handshake's expire_overdue() and beat(), each under the handshake's lock.
"""

from __future__ import annotations

import asyncio
import logging

from firmware_io.plc_side import PlcSide

log = logging.getLogger("firmware_io.server")  # PlcLink's log, as operators know it

MAX_PERIOD_S = 0.5  #: the documented limit of the heartbeat period (docs/modbus.md)


class Heartbeat:
    """The heartbeat and the cycle timeout of one handshake; `stalls` and `stalled` for the station and /metrics."""

    def __init__(
        self,
        handshake: PlcSide,
        period_s: float,
        liveness_timeout_s: float | None,
        cycle_timeout_s: float | None,
    ) -> None:
        if not 0 < period_s < MAX_PERIOD_S:
            raise ValueError(f"heartbeat period {period_s} s must be above 0 and below {MAX_PERIOD_S} s")
        if liveness_timeout_s is not None and liveness_timeout_s <= period_s:
            raise ValueError(f"liveness timeout {liveness_timeout_s} s must be longer than the heartbeat period")
        if cycle_timeout_s is not None and cycle_timeout_s <= 0:
            raise ValueError(f"cycle timeout {cycle_timeout_s} s must be positive")
        self._handshake = handshake
        self.period_s = period_s
        self.liveness_timeout_s = liveness_timeout_s
        self.cycle_timeout_s = cycle_timeout_s
        # Read from other threads; ints and bools are replaced atomically.
        self.stalls = 0  #: times the heartbeat stopped because the controller went silent
        self.stalled = False

    @property
    def liveness_slice_s(self) -> float:
        """How long a waiting wait_trigger() may sleep and still count as a live controller."""
        return self.period_s if self.liveness_timeout_s is None else self.liveness_timeout_s / 2

    def tick(self) -> None:
        """One period's work: expire an overdue cycle, then beat if the controller is alive."""
        expired = self._handshake.expire_overdue(self.cycle_timeout_s)
        beating = self._handshake.beat(self.liveness_timeout_s)
        if not beating and not self.stalled:
            self.stalls += 1
        self.stalled = not beating
        if expired is not None:
            log.error(
                "cycle %d: not published within cycle_timeout_s = %g s; answered CYCLE_TIMEOUT",
                expired,
                self.cycle_timeout_s,
            )

    async def run(self) -> None:
        """Tick every period until cancelled."""
        while True:
            self.tick()
            await asyncio.sleep(self.period_s)
