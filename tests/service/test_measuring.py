"""The cell measurer's warm-up beyond the measurement: what the writers draw between cycles is set up too."""

from __future__ import annotations

import types

import numpy as np
import pytest

from cellctl.cameras.base import StereoFrame
from cellctl.errors import FailureKind
from cellctl.service import measuring
from cellctl.service.cycle import Measured, Refused


def test_the_warm_up_draws_the_overlay_of_its_cycle_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """OpenCV sets up its fonts at the process's first cv2.putText (~21 ms of CPU): the warm-up draws, so that
    the image log's first overlay does not pay it beside a cycle. A measured warm-up pair draws its overlay,
    a refused one the refusal's picture (both write text)."""
    left = np.zeros((48, 64, 3), np.uint8)
    frame = StereoFrame(left, left.copy(), 0.0, 0.0)
    drawn: list[tuple[str, object]] = []
    monkeypatch.setattr(measuring, "draw_overlay", lambda image, calib, rec, m: drawn.append(("overlay", m)))
    monkeypatch.setattr(measuring, "draw_refused", lambda image, text: drawn.append(("refused", image)))
    measured = Measured(types.SimpleNamespace(), "the measurement")  # type: ignore[arg-type]
    measuring.warm_drawing(frame, object(), measured)  # type: ignore[arg-type]
    measuring.warm_drawing(frame, object(), Refused(FailureKind.NO_SOLE, "no sole"))  # type: ignore[arg-type]
    assert drawn == [("overlay", "the measurement"), ("refused", left)]


def test_the_warm_ups_refusal_picture_is_drawn_for_real() -> None:
    left = np.zeros((48, 64), np.uint8)
    measuring.warm_drawing(StereoFrame(left, left, 0.0, 0.0), None, Refused(FailureKind.NO_SOLE, "no sole"))
    assert not left.any()  # drawn on a copy, never on the grabbed frame
