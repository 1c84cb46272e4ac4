"""Averaging a cycle's exposures: the last exposure stays the frame, their mean (for the surface fits) has half
the sensor's noise, and an exposure of a scene that moved is left out rather than blurred into the others."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.cameras.averaging import average_frames, frames_agree
from cellctl.cameras.base import StereoFrame
from cellctl.service.camera_health import CameraHealth


def scene(shift_px: int = 0) -> np.ndarray:
    """A textured table with a white sole on it (grey float image), the sole moved `shift_px` to the right."""
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.uniform(40, 120, (240, 320)).astype(np.float32), (0, 0), 2.0)
    image[60:180, 80 + shift_px : 240 + shift_px] = 220.0
    return image


def exposure(clean: np.ndarray, seed: int, sigma: float = 1.5, gain: float = 1.0) -> np.ndarray:
    noisy = gain * clean + sigma * np.random.default_rng(seed).standard_normal(clean.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def stereo(left: np.ndarray, right: np.ndarray, t: float) -> StereoFrame:
    return StereoFrame(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR), t, t, {"n": t})


def test_four_exposures_halve_the_noise() -> None:
    clean = scene()
    frames = [stereo(exposure(clean, k), exposure(clean, 100 + k), k) for k in range(4)]
    frame = average_frames(frames)
    assert frame.left is frames[-1].left and frame.right is frames[-1].right and frame.averaged is not None
    single = np.std(frames[0].left[..., 0] - clean)
    averaged = np.std(frame.averaged[0][..., 0] - clean)
    assert averaged < 0.6 * single  # 1/2 from the noise, the rest the 8-bit rounding
    assert np.std(frame.averaged[1][..., 0] - clean) < 0.6 * single
    assert frame.info == {"n": 3, "averaged_frames": 4} and frame.t_left == 3
    assert frame.averaged[0].dtype == np.uint8 and frame.averaged[0].shape == frames[0].left.shape


def test_an_exposure_of_a_scene_that_moved_is_left_out() -> None:
    settling = stereo(exposure(scene(shift_px=2), 0), exposure(scene(shift_px=2), 1), 0)
    still = [stereo(exposure(scene(), k), exposure(scene(), 10 + k), k) for k in (1, 2, 3)]
    frame = average_frames([settling, *still])
    assert frame.info["averaged_frames"] == 3 and frame.info["moved_frames"] == 1 and frame.averaged is not None
    expected = np.rint(np.mean([f.left.astype(np.float32) for f in still], axis=0))
    np.testing.assert_array_equal(frame.averaged[0], expected.astype(np.uint8))


@pytest.mark.parametrize(
    ("sigma", "gain", "shift", "agree"),
    [
        (1.5, 1.0, 0, True),
        (6.0, 1.0, 0, True),  # heavy sensor noise is still noise
        (1.5, 1.02, 0, True),  # a lamp's flicker: a little brighter all over
        (1.5, 1.0, 1, False),  # one pixel of movement moves the whole edge
        (1.5, 1.5, 0, False),  # a lamp switched on: another view, however evenly it changed
    ],
)
def test_frames_agree_on_noise_and_flicker_not_on_movement(sigma: float, gain: float, shift: int, agree: bool) -> None:
    first = exposure(scene(), 0, sigma)
    second = exposure(scene(shift), 1, sigma, gain)
    assert frames_agree(first, second) is agree


def test_another_view_altogether_does_not_agree() -> None:
    other = np.random.default_rng(9).integers(0, 256, (240, 320), dtype=np.uint8)
    assert not frames_agree(exposure(scene(), 0), other)


def test_an_exposure_of_another_size_is_left_out() -> None:
    small = stereo(exposure(scene(), 0)[::2, ::2], exposure(scene(), 1)[::2, ::2], 0)
    still = [stereo(exposure(scene(), k), exposure(scene(), 10 + k), k) for k in (1, 2)]
    frame = average_frames([small, *still])
    assert frame.info["averaged_frames"] == 2 and frame.info["moved_frames"] == 1


def test_one_frame_is_returned_as_it_is_and_none_is_refused() -> None:
    only = stereo(exposure(scene(), 0), exposure(scene(), 1), 0)
    assert average_frames([only]).left is only.left and average_frames([only]).averaged is None
    with pytest.raises(ValueError, match="one or more frames"):
        average_frames([])


class Exposures:
    """A FrameSource fake: `grab_exposures` hands out noisy exposures of one still scene, and records the count."""

    def __init__(self) -> None:
        self.asked: list[int] = []

    def open(self) -> None: ...

    def close(self) -> None: ...

    def grab_pair(self, not_before: float | None = None) -> StereoFrame:
        return self.grab_exposures(1, not_before)[0]

    def grab_exposures(self, count: int, not_before: float | None = None) -> list[StereoFrame]:
        self.asked.append(count)
        return [stereo(exposure(scene(), k), exposure(scene(), 50 + k), k) for k in range(count)]

    def grab_further(self, count: int) -> list[StereoFrame]:
        self.asked.append(-count)
        return [stereo(exposure(scene(), 10 + k), exposure(scene(), 60 + k), 10 + k) for k in range(count)]


def test_a_cycle_grabs_and_averages_the_configured_exposures() -> None:
    source = Exposures()
    timings: dict[str, float] = {}
    cameras = CameraHealth(source, None, averaged_frames=3)
    grabbed = cameras.averaged(cameras.grab_exposures(timings, not_before=0.0), timings)
    assert source.asked == [3] and grabbed.info["averaged_frames"] == 3 and grabbed.averaged is not None
    assert set(timings) == {"grab", "average"}


def test_further_exposures_of_a_cycle_average_with_the_first() -> None:
    """A cycle measured again on more exposures: the further pairs of the same still scene join the first in one
    mean, the last of them the frame; timed apart from the first grab."""
    source = Exposures()
    cameras = CameraHealth(source, None, averaged_frames=4)
    timings: dict[str, float] = {}
    first = cameras.grab_exposures(timings, not_before=0.0)
    further = cameras.grab_further(4, timings)
    frame = cameras.averaged(first + further, timings)
    assert source.asked == [4, -4] and frame.info["averaged_frames"] == 8 and frame.left is further[-1].left
    assert set(timings) == {"grab", "grab_further", "average"}
    four = average_frames(first)
    assert four.averaged is not None and frame.averaged is not None
    clean = scene()
    assert np.std(frame.averaged[0][..., 0] - clean) < 0.85 * np.std(four.averaged[0][..., 0] - clean)
