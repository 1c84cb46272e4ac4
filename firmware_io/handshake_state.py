"""The handshake's state and its transitions, as plain data: which cycle runs, which trigger waits for the
controller, which cycle was answered last, which one the link answered with CYCLE_TIMEOUT itself, and when
the controller was last heard from.

Pure: no lock, no registers, no clock. firmware_io.handshake.PlcHandshake owns one HandshakeState, calls it
only with its lock held, passes the time, and writes the registers a transition asks for
(firmware_io.result_image). The rules of the handshake (docs/modbus.md) read here in one place.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


@dataclass(frozen=True)
class Trigger:
    """A cycle the PLC started."""

    cycle: int  #: the number the PLC wrote, 1..65535
    received_at: float  #: time.monotonic() when the trigger write arrived; cycle time counts from here
    recipe: int = 0  #: RECIPE_SELECT when the trigger was accepted (map v2; always 0 in version 1)


class TriggerWrite(enum.Enum):
    """What a value written to TRIGGER does."""

    REPEATED = "repeated"  #: 0 (the PLC resetting its trigger) or the previous or running cycle: starts nothing
    REFUSED = "refused"  #: a different number while a cycle runs: Modbus 0x06, counted; the cycle goes on
    ACCEPTED = "accepted"  #: a new cycle


@dataclass
class HandshakeState:
    """The handshake's state; every method is one transition (the caller holds the handshake's lock)."""

    controller_seen_at: float  #: time of the controller's last call; the heartbeat's liveness counts from it
    running: int | None = None  #: the cycle accepted and not yet answered
    running_since: float | None = None
    recipe: int = 0  #: the running (or last) cycle's recipe
    last_accepted: int = 0
    link_answered: int | None = None  #: the cycle the link answered with CYCLE_TIMEOUT itself
    pending: Trigger | None = None  #: accepted, not yet taken by the controller's wait_trigger()

    def trigger_write(self, cycle: int) -> TriggerWrite:
        """What writing `cycle` to TRIGGER does now (no change of state: accept() makes it a cycle)."""
        if cycle == 0 or cycle == self.last_accepted:
            return TriggerWrite.REPEATED
        return TriggerWrite.ACCEPTED if self.running is None else TriggerWrite.REFUSED

    def accept(self, cycle: int, recipe: int, now: float) -> None:
        """`cycle` runs from `now`; its trigger waits for the controller."""
        self.running = self.last_accepted = cycle
        self.running_since = now
        self.recipe = recipe
        self.pending = Trigger(cycle, now, recipe)

    def take_pending(self) -> Trigger | None:
        """The waiting trigger, handed to the controller once."""
        trigger, self.pending = self.pending, None
        return trigger

    def overdue_for(self, now: float, cycle_timeout_s: float | None) -> float | None:
        """How long the running cycle has run, if that is longer than cycle_timeout_s; else None."""
        if self.running is None or self.running_since is None or cycle_timeout_s is None:
            return None
        age_s = now - self.running_since
        return age_s if age_s > cycle_timeout_s else None

    def answered_by_link(self, cycle: int) -> bool:
        """True if the link answered `cycle` with CYCLE_TIMEOUT itself: its late result is dropped."""
        return cycle == self.link_answered and cycle != self.running

    def finish(self, cycle: int, *, by_link: bool = False) -> bool:
        """The running cycle is answered; False for a late answer to a cycle the link answered already.

        RuntimeError for any other cycle than the running one: exactly one answer per trigger.
        """
        if self.answered_by_link(cycle):
            return False
        if cycle != self.running:
            raise RuntimeError(
                f"cannot publish cycle {cycle}: the running cycle is {self.running} "
                "(publish exactly once per trigger, with the trigger's cycle number)"
            )
        if by_link:
            self.link_answered = cycle
        self.running = self.running_since = None
        return True

    def restore(self, cycle: int) -> None:
        """After a restart: `cycle` was answered last (from the journal), so writing it again starts nothing."""
        if not 0 <= cycle <= 0xFFFF:
            raise ValueError(f"last cycle {cycle} is not a cycle number 0..65535")
        if self.last_accepted != 0 or self.running is not None:
            raise RuntimeError("restore_last_cycle() is for a fresh link, before the PLC triggered anything")
        self.last_accepted = cycle

    def heartbeat_may_advance(self, now: float, liveness_timeout_s: float | None) -> bool:
        """The heartbeat advances while a cycle runs or the controller was heard within liveness_timeout_s.

        A running cycle counts as alive because expire_overdue bounds how long it lasts.
        """
        if self.running is not None or liveness_timeout_s is None:
            return True
        return now - self.controller_seen_at <= liveness_timeout_s
