"""Stopping the service (Daemon.request_stop, e.g. SIGTERM) without leaving the PLC without an answer.

A cycle triggered before the stop request is finished and published; a trigger that arrives once stopping
has begun is answered with CYCLE_ABORTED, not measured. The link then keeps serving for STOP_LINGER_S, so
the PLC can read that last answer, and closes.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from firmware_io.handshake import Trigger
from firmware_io.server import PlcLink

#: After a stop request, how long the Modbus link still serves so the PLC can read the last answer.
STOP_LINGER_S = 0.5


class StopRequest:
    """A stop asked for from any thread, and when: what decides whether a trigger is measured or aborted."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self._at = math.inf  # time.monotonic() of the first request

    def request(self) -> None:
        """Thread-safe; a second request keeps the time of the first."""
        self._at = min(self._at, time.monotonic())
        self._event.set()

    @property
    def requested(self) -> bool:
        return self._event.is_set()

    def aborts(self, trigger: Trigger) -> bool:
        """True for a trigger received once stopping had begun: it is answered CYCLE_ABORTED."""
        return trigger.received_at >= self._at

    def linger(self, link: PlcLink, answer: Callable[[Trigger], None]) -> None:
        """Serve STOP_LINGER_S longer: the PLC reads the last answer, and a trigger arriving now is answered."""
        deadline = time.monotonic() + STOP_LINGER_S
        while (left := deadline - time.monotonic()) > 0:
            late = link.wait_trigger(timeout_s=left)
            if late is not None:
                answer(late)
