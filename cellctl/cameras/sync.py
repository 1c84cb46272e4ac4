"""Pairing frames of two free-running cameras by timestamp.

USB cameras are not hardware-triggered: each streams on its own clock, so the newest frame of each is up
to one frame period apart from the other. A pair is accepted when the timestamps lie within the tolerance;
otherwise the *older* frame is replaced by that camera's next one (the other camera's frame is still the
newest of its stream), up to `max_regrabs` times, after which the pair is refused as out of sync.

Frames from before the trigger: a free-running camera hands out the buffer it filled last, which may
have been exposed before the PLC's trigger (the previous sole, or an empty table). With `not_before`
(the trigger's time.monotonic(); V4L2 stamps buffers with the same CLOCK_MONOTONIC) such stale frames
are dropped and the camera's next frame taken, up to MAX_STALE_FRAMES per camera.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from cellctl.cameras.base import FrameTimeout, OutOfSync

Payload = TypeVar("Payload")

#: Stale buffers dropped per camera before giving up: the driver queue (1-4 buffers) plus the frame in flight.
MAX_STALE_FRAMES = 6


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
    not_before: float | None = None,
) -> tuple[TimedFrame[Payload], TimedFrame[Payload]]:
    """Two frames taken within tolerance_s of each other, re-grabbing the older one; OutOfSync if none.

    not_before: frames stamped earlier than this are stale and dropped (see the module docstring).
    """
    if not_before is not None:
        grab_left, grab_right = _fresh(grab_left, not_before, "left"), _fresh(grab_right, not_before, "right")
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


def _fresh(grab: Callable[[], TimedFrame[Payload]], not_before: float, side: str) -> Callable[[], TimedFrame[Payload]]:
    def grab_fresh() -> TimedFrame[Payload]:
        for _ in range(MAX_STALE_FRAMES + 1):
            frame = grab()
            if frame.timestamp >= not_before:
                return frame
        raise FrameTimeout(
            f"{side} camera delivered only frames from before the trigger ({MAX_STALE_FRAMES + 1} in a row, the "
            f"last {not_before - frame.timestamp:.3f} s early): is its timestamp clock CLOCK_MONOTONIC, is it streaming?"
        )

    return grab_fresh
