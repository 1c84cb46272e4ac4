"""What the daemon tells its observers (operator station, metrics, image log): its state and each finished cycle.

    daemon.events.subscribe(callback)     # callback(CellState | CycleDone), called in the daemon's thread
    daemon.events.state                   # the latest CellState, from any thread

The daemon publishes; it never knows who listens. Callbacks run in the daemon's thread after the PLC has its
answer, so they must be quick (the image log only queues its pictures for its own writer thread); an
exception in a callback is logged and never reaches the cycle.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from cellctl.cameras.base import StereoFrame
from cellctl.service.cycle import Measured
from cellctl.service.journal import CycleRecord

log = logging.getLogger(__name__)

#: starting: preparing cameras; ready: waiting for a trigger; busy: measuring; error: not ready (cameras or
#: calibration); stopping: finishing after a stop request.
PHASES = ("starting", "ready", "busy", "error", "stopping")


@dataclass(frozen=True)
class CellState:
    """The cell as the operator sees it."""

    phase: str = "starting"
    cameras_ok: bool = False
    calibration_ok: bool = False
    cycles_done: int = 0
    cycle: int | None = None  # the cycle being measured while busy
    since: float = field(default_factory=time.time)  # wall clock of the last change


@dataclass(frozen=True)
class CycleDone:
    """A cycle journaled and published: its record, and the pair and measurement when there were any."""

    record: CycleRecord
    frame: StereoFrame | None
    measured: Measured | None


CellEvent = CellState | CycleDone
Subscriber = Callable[[CellEvent], None]


class CellEvents:
    """Subscribers of the daemon's events, and its latest state (thread-safe)."""

    def __init__(self) -> None:
        self._subscribers: list[Subscriber] = []
        self._lock = threading.Lock()
        self._state = CellState()

    @property
    def state(self) -> CellState:
        return self._state

    def subscribe(self, callback: Subscriber) -> None:
        with self._lock:
            self._subscribers.append(callback)

    def publish(self, event: CellEvent) -> None:
        if isinstance(event, CellState):
            self._state = event
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(event)
            except Exception:  # an observer's fault must never reach the cycle
                log.exception("event subscriber %r failed", callback)
