"""Camera backends: timestamp pairing, the simulated cameras' faults, replay, and the V4L2 backend's
pairing and reconnect logic driven through a fake capture object (no real camera exists on the test
machine, so the V4L2 calls themselves are not exercised here)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.cameras import CameraMissing, FrameTimeout, OutOfSync
from cellctl.cameras.replay import ReplayCameras
from cellctl.cameras.simulated import FRAME_PERIOD_S, SimulatedCameras
from cellctl.cameras.sync import TimedFrame, grab_synchronised
from cellctl.cameras.v4l2 import V4l2Camera, V4l2Cameras
from cellctl.service.codes import FAILURE_CODES
from firmware_io.registers import ErrorCode
from tests.sim_rig import half_size_rig


def stream(timestamps: list[float]):
    """A fake camera: returns the given timestamps in turn, and records how many were taken."""
    taken = []

    def grab() -> TimedFrame[int]:
        taken.append(timestamps[len(taken)])
        return TimedFrame(taken[-1], len(taken) - 1)

    return grab, taken


def test_pair_within_tolerance_is_taken_at_once() -> None:
    left, lt = stream([1.000, 1.033])
    right, rt = stream([1.004, 1.037])
    a, b = grab_synchronised(left, right, 0.005, 3)
    assert (a.payload, b.payload) == (0, 0) and len(lt) == len(rt) == 1


def test_older_frame_is_regrabbed_until_in_sync() -> None:
    # Right camera runs 25 ms behind: re-grabbing the left (older) frame catches up.
    left, lt = stream([1.000, 1.033, 1.066])
    right, rt = stream([1.025, 1.058])
    a, b = grab_synchronised(left, right, 0.010, 3)
    assert (a.timestamp, b.timestamp) == (1.033, 1.025) and len(lt) == 2 and len(rt) == 1


def test_right_regrabbed_when_it_is_older() -> None:
    left, _ = stream([2.030, 2.063])
    right, rt = stream([2.000, 2.033])
    a, b = grab_synchronised(left, right, 0.005, 3)
    assert (a.timestamp, b.timestamp) == (2.030, 2.033) and len(rt) == 2


def test_half_a_frame_apart_is_out_of_sync_after_regrabs() -> None:
    period = 1 / 30
    left, lt = stream([i * period for i in range(10)])
    right, rt = stream([period / 2 + i * period for i in range(10)])
    with pytest.raises(OutOfSync, match=r"16.7 ms apart after 4 re-grabs") as info:
        grab_synchronised(left, right, 0.008, 4)
    assert FAILURE_CODES[info.value.kind] is ErrorCode.CAMERAS_OUT_OF_SYNC
    assert len(lt) + len(rt) == 2 + 4


@pytest.fixture(scope="module")
def sim() -> SimulatedCameras:
    return SimulatedCameras(half_size_rig(), seeds=(1, 2), sync_tolerance_s=0.008)


def test_simulated_pairs_rotate_through_seeds_with_truth(sim: SimulatedCameras) -> None:
    first, second, third = sim.grab_pair(), sim.grab_pair(), sim.grab_pair()
    assert [f.info["seed"] for f in (first, second, third)] == [1, 2, 1]
    assert first.left.shape == (512, 640, 3) and first.left.dtype == np.uint8
    assert not np.array_equal(first.left, first.right)
    assert first.left is third.left  # cached: the scene is rendered once
    assert 200 < first.info["truth"]["length_mm"] < 320
    assert first.skew_s <= 0.008


def test_simulated_exposures_show_one_scene_with_new_noise_each() -> None:
    sim = SimulatedCameras(half_size_rig(), seeds=(1, 2), exposures=3)
    frames = sim.grab_exposures(5)  # no more than were rendered
    assert [f.info["seed"] for f in frames] == [1, 1, 1] and sim.grab_pair().info["seed"] == 2
    noise = frames[1].left.astype(np.int16) - frames[0].left.astype(np.int16)
    assert 0.5 < float(np.std(noise)) < 3.0  # the sensor's noise (~1-1.6 DN each), nothing else
    assert [f.t_left for f in frames] == sorted({f.t_left for f in frames})  # consecutive frames
    assert sim.grab_exposures(1)[0].left is frames[0].left  # the scene's first exposure is its pair


def test_simulated_further_exposures_are_the_same_scenes_next_ones() -> None:
    """A cycle that measures once more on more exposures gets the scene it grabbed, not the next seed's."""
    sim = SimulatedCameras(half_size_rig(), seeds=(1, 2), exposures=5)
    assert sim.grab_further(3) == []  # nothing grabbed yet
    first = sim.grab_exposures(2)
    further = sim.grab_further(2)
    assert [f.info["seed"] for f in first + further] == [1, 1, 1, 1]
    assert len({id(f.left) for f in first + further}) == 4  # each its own exposure
    assert [f.info["seed"] for f in sim.grab_further(4)] == [1]  # the fifth and last rendered
    assert sim.grab_further(1) == [] and sim.grab_pair().info["seed"] == 2
    sim.unplug()
    with pytest.raises(CameraMissing):
        sim.grab_further(1)


def test_simulated_faults_and_recovery(sim: SimulatedCameras) -> None:
    sim.unplug("right")
    with pytest.raises(CameraMissing, match="right camera"):
        sim.grab_pair()
    sim.replug()
    sim.drop_frames(1)
    with pytest.raises(FrameTimeout):
        sim.grab_pair()
    sim.skew_s = FRAME_PERIOD_S / 2
    with pytest.raises(OutOfSync):
        sim.grab_pair()
    sim.skew_s = 0.040  # more than a frame off: re-grabbing the older frame re-pairs them
    assert sim.grab_pair().skew_s <= 0.008
    sim.skew_s = 0.0
    assert sim.grab_pair().skew_s == 0.0


def test_replay_serves_pairs_in_turn(tmp_path: Path) -> None:
    for n, value in (("01", 10), ("02", 20)):
        cv2.imwrite(str(tmp_path / f"left_{n}.png"), np.full((8, 8, 3), value, np.uint8))
        cv2.imwrite(str(tmp_path / f"right_{n}.png"), np.full((8, 8, 3), value + 1, np.uint8))
    cv2.imwrite(str(tmp_path / "left_03.png"), np.zeros((8, 8, 3), np.uint8))  # no right partner: ignored
    replay = ReplayCameras(tmp_path)
    values = [int(replay.grab_pair().right[0, 0, 0]) for _ in range(3)]
    assert values == [11, 21, 11]
    assert [int(f.right[0, 0, 0]) for f in replay.grab_exposures(4)] == [21]  # a stored pair is one exposure
    assert replay.grab_further(4) == []  # and has no further ones
    assert replay.grab_pair().averaged is None
    for side, value in (("left", 12), ("right", 13)):  # the image log's mean of a cycle's exposures, beside its pair
        cv2.imwrite(str(tmp_path / f"mean{side}_02.png"), np.full((8, 8, 3), value, np.uint8))
    served = replay.grab_exposures(4)[0]
    assert served.averaged is not None and [int(m[0, 0, 0]) for m in served.averaged] == [12, 13]
    assert int(served.right[0, 0, 0]) == 21 and len(replay.pairs()) == 2
    with pytest.raises(CameraMissing, match="does not exist"):
        ReplayCameras(tmp_path / "gone").grab_pair()
    with pytest.raises(CameraMissing, match="holds no"):
        (tmp_path / "empty").mkdir()
        ReplayCameras(tmp_path / "empty").grab_pair()


def test_replay_takes_numbers_in_natural_order_as_calibrate_does(tmp_path: Path) -> None:
    for n, value in (("2", 20), ("10", 100), ("9", 90)):  # unpadded numbers: "10" sorts before "2" as text
        cv2.imwrite(str(tmp_path / f"left_{n}.png"), np.full((8, 8, 3), value, np.uint8))
        cv2.imwrite(str(tmp_path / f"right_{n}.png"), np.full((8, 8, 3), value + 1, np.uint8))
    replay = ReplayCameras(tmp_path)
    assert [int(replay.grab_pair().right[0, 0, 0]) for _ in range(3)] == [21, 91, 101]


class FakeCapture:
    """Stands in for cv2.VideoCapture on a V4L2 device: frames every 1/30 s from `start`."""

    opened: list[FakeCapture] = []

    def __init__(self, device: str, api: int, start: float = 0.0) -> None:
        self.device, self.api = device, api
        self.props: dict[int, float] = {}
        self.time = start - 1 / 30
        self.released = False
        self.fail_grab = False
        FakeCapture.opened.append(self)

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return True

    def set(self, prop: int, value: float) -> bool:
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        if prop == cv2.CAP_PROP_POS_MSEC:
            return self.time * 1000.0
        return self.props.get(prop, 0.0)

    def grab(self) -> bool:
        if self.fail_grab:
            return False
        self.time += 1 / 30
        return True

    def retrieve(self) -> tuple[bool, np.ndarray]:
        return True, np.full((4, 4, 3), int(self.time * 30) % 256, np.uint8)

    def release(self) -> None:
        self.released = True


def test_v4l2_pairs_decodes_and_reconnects_after_unplug(tmp_path: Path) -> None:
    FakeCapture.opened = []
    devices = [tmp_path / "cam-left", tmp_path / "cam-right"]
    for device in devices:
        device.touch()
    cams = [
        V4l2Camera(str(d), size=(1280, 1024), pixel_format="MJPEG", exposure=100, gain=2, open_capture=FakeCapture)
        for d in devices
    ]
    source = V4l2Cameras(cams[0], cams[1], sync_tolerance_s=0.005, max_regrabs=3)
    frame = source.grab_pair()
    left_capture = FakeCapture.opened[0]
    assert left_capture.api == cv2.CAP_V4L2
    assert left_capture.props[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter.fourcc(*"MJPG")
    assert left_capture.props[cv2.CAP_PROP_EXPOSURE] == 100 and left_capture.props[cv2.CAP_PROP_GAIN] == 2
    assert frame.skew_s <= 0.005 and frame.info["left"] == str(devices[0])
    further = source.grab_further(2)  # a retry's further pairs: the streams' next ones
    assert len(further) == 2 and further[0].t_left < further[1].t_left and further[0].t_left > frame.t_left

    devices[1].unlink()  # right camera unplugged: its grab fails and the device node is gone
    FakeCapture.opened[1].fail_grab = True
    with pytest.raises(CameraMissing, match="unplugged"):
        source.grab_pair()
    assert left_capture.released and FakeCapture.opened[1].released  # both closed, reopened next time
    with pytest.raises(CameraMissing, match="not connected"):
        source.grab_pair()
    devices[1].touch()  # plugged in again under its stable name
    assert source.grab_pair().left.shape == (4, 4, 3)
    # Opens: the first pair, the left again during the failed attempt, then both on replug.
    assert len(FakeCapture.opened) == 5
    assert FakeCapture.opened[2].released and not any(c.released for c in FakeCapture.opened[3:])


def test_v4l2_frame_timeout_and_wrong_size(tmp_path: Path) -> None:
    device = tmp_path / "cam"
    device.touch()

    class Stalled(FakeCapture):
        def grab(self) -> bool:
            return False

    with pytest.raises(FrameTimeout, match="no frame within 0.5 s"):
        V4l2Camera(str(device), size=None, timeout_s=0.5, open_capture=Stalled).grab()

    class Small(FakeCapture):
        def get(self, prop: int) -> float:
            return 640.0 if prop in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT) else super().get(prop)

    with pytest.raises(CameraMissing, match="delivers 640x640, not the configured 1280x1024"):
        V4l2Camera(str(device), size=(1280, 1024), open_capture=Small).grab()


def test_v4l2_drops_buffers_exposed_before_the_trigger(tmp_path: Path) -> None:
    trigger = 100.0  # time.monotonic() of the PLC's trigger write
    devices = [tmp_path / "cam-left", tmp_path / "cam-right"]
    for device in devices:
        device.touch()

    class Streaming(FakeCapture):  # free-running since before the trigger: its queued buffers are old
        def __init__(self, device: str, api: int) -> None:
            super().__init__(device, api, start=trigger - 0.1)

    def source(capture: type[FakeCapture]) -> V4l2Cameras:
        cams = [V4l2Camera(str(d), size=None, open_capture=capture) for d in devices]
        return V4l2Cameras(cams[0], cams[1], sync_tolerance_s=0.005, max_regrabs=3)

    assert source(Streaming).grab_pair().t_left < trigger  # without the check: the previous sole
    frame = source(Streaming).grab_pair(not_before=trigger)
    assert frame.t_left >= trigger and frame.t_right >= trigger and frame.skew_s <= 0.005

    class Frozen(Streaming):  # timestamps never pass the trigger (wrong clock, or a stalled stream)
        def grab(self) -> bool:
            return True

    with pytest.raises(FrameTimeout, match="left camera delivered only frames from before the trigger"):
        source(Frozen).grab_pair(not_before=trigger)
