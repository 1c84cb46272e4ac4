"""The stop request on its own: which triggers are aborted, and the link's linger after it."""

from __future__ import annotations

import time

from cellctl.service.stopping import STOP_LINGER_S, StopRequest
from firmware_io.handshake import Trigger


def test_triggers_before_the_first_request_are_measured_and_later_ones_aborted() -> None:
    stop = StopRequest()
    before = Trigger(1, time.monotonic())
    assert not stop.requested and not stop.aborts(before)
    stop.request()
    after = Trigger(2, time.monotonic())
    stop.request()  # a second request keeps the first one's time
    assert stop.requested
    assert not stop.aborts(before) and stop.aborts(after)


class _Link:
    """wait_trigger() hands out one late trigger, then nothing until the timeout."""

    def __init__(self) -> None:
        self.late = [Trigger(9, time.monotonic())]

    def wait_trigger(self, timeout_s: float | None = None) -> Trigger | None:
        if self.late:
            return self.late.pop()
        time.sleep(timeout_s or 0.0)
        return None


def test_linger_answers_a_late_trigger_and_ends_after_the_linger_time() -> None:
    answered: list[int] = []
    started = time.monotonic()
    StopRequest().linger(_Link(), lambda trigger: answered.append(trigger.cycle))  # type: ignore[arg-type]
    assert answered == [9]
    assert STOP_LINGER_S <= time.monotonic() - started < STOP_LINGER_S + 2.0
