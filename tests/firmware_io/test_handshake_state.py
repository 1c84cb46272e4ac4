"""The handshake's rules as pure transitions (firmware_io.handshake_state), without registers or a clock."""

from __future__ import annotations

import pytest

from firmware_io.handshake_state import HandshakeState, Trigger, TriggerWrite


def test_a_trigger_write_is_repeated_refused_or_accepted() -> None:
    state = HandshakeState(controller_seen_at=0.0)
    assert state.trigger_write(0) is TriggerWrite.REPEATED
    assert state.trigger_write(4) is TriggerWrite.ACCEPTED
    state.accept(4, recipe=2, now=10.0)
    assert state.trigger_write(4) is TriggerWrite.REPEATED
    assert state.trigger_write(5) is TriggerWrite.REFUSED
    assert state.take_pending() == Trigger(4, 10.0, 2)
    assert state.take_pending() is None
    assert state.finish(4)
    assert state.trigger_write(4) is TriggerWrite.REPEATED
    assert state.trigger_write(5) is TriggerWrite.ACCEPTED


def test_a_cycle_the_link_answered_drops_its_late_result() -> None:
    state = HandshakeState(controller_seen_at=0.0)
    state.accept(7, recipe=0, now=1.0)
    assert state.overdue_for(now=2.0, cycle_timeout_s=1.5) is None
    assert state.overdue_for(now=3.0, cycle_timeout_s=None) is None
    assert state.overdue_for(now=3.0, cycle_timeout_s=1.5) == 2.0
    assert state.finish(7, by_link=True)
    assert state.answered_by_link(7) and state.running is None
    assert not state.finish(7)  # the controller's late answer
    with pytest.raises(RuntimeError, match="running cycle is None"):
        state.finish(8)


def test_the_heartbeat_needs_a_running_cycle_or_a_recent_controller_call() -> None:
    state = HandshakeState(controller_seen_at=0.0)
    assert state.heartbeat_may_advance(now=1.0, liveness_timeout_s=1.0)
    assert not state.heartbeat_may_advance(now=1.5, liveness_timeout_s=1.0)
    assert state.heartbeat_may_advance(now=1.5, liveness_timeout_s=None)
    state.accept(1, recipe=0, now=1.5)
    assert state.heartbeat_may_advance(now=99.0, liveness_timeout_s=1.0)


def test_restore_is_for_a_fresh_link_only() -> None:
    state = HandshakeState(controller_seen_at=0.0)
    with pytest.raises(ValueError, match="0..65535"):
        state.restore(70000)
    state.restore(12)
    assert state.trigger_write(12) is TriggerWrite.REPEATED
    with pytest.raises(RuntimeError, match="fresh link"):
        state.restore(13)
