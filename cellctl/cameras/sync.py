"""Pairing frames of two free-running cameras by timestamp.

USB cameras are not hardware-triggered: each streams on its own clock, so the newest frame of each is up
to one frame period apart from the other. A pair is accepted when the timestamps lie within the tolerance;
otherwise the *older* frame is replaced by that camera's next one (the other camera's frame is still the
newest of its stream), up to `max_regrabs` times, after which the pair is refused as out of sync.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from cellctl.cameras.base import OutOfSync

Payload = TypeVar("Payload")


@dataclass
class TimedFrame(Generic[Payload]):
    """A frame still in its raw form (e.g. an undecoded MJPEG buffer) and its capture time, s."""

    timestamp: float
    payload: Payload


def grab_synchronised(
    grab_left: Callable[[], TimedFrame[Payload]],
    grab_right: Callable[[], TimedFrame[Payload]],
    tolerance_s: float,
    max_regrabs: int,
) -> tuple[TimedFrame[Payload], TimedFrame[Payload]]:
    """Two frames taken within tolerance_s of each other, re-grabbing the older one; OutOfSync if none."""
    left, right = grab_left(), grab_right()
    for _ in range(max_regrabs):
        if abs(left.timestamp - right.timestamp) <= tolerance_s:
            return left, right
        if left.timestamp < right.timestamp:
            left = grab_left()
        else:
            right = grab_right()
    skew = abs(left.timestamp - right.timestamp)
    if skew <= tolerance_s:
        return left, right
    raise OutOfSync(
        f"camera frames {skew * 1000:.1f} ms apart after {max_regrabs} re-grabs "
        f"(tolerance {tolerance_s * 1000:.1f} ms): check USB bandwidth, one camera per controller port"
    )
