"""Calibration: the rectified geometry it promises, its YAML file and its errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.sim.rig import default_rig
from cellctl.vision.calibration import REQUIRED_KEYS, Calibration


@pytest.fixture(scope="module")
def rig() -> Calibration:
    return default_rig()


def _scene_points() -> np.ndarray:
    """Points spread over the table region in front of the rig, left camera frame, mm."""
    xs, ys, zs = np.meshgrid(np.linspace(-150, 200, 6), np.linspace(-150, 150, 5), [450.0, 550.0, 650.0])
    return np.stack([xs.ravel(), ys.ravel(), zs.ravel()], axis=1)


def _project(points: np.ndarray, K: np.ndarray, D: np.ndarray, R: np.ndarray, T: np.ndarray) -> np.ndarray:
    projected, _ = cv2.projectPoints(points, cv2.Rodrigues(R)[0], T, K, D)
    return projected.reshape(-1, 2)


def test_rectified_pair_has_equal_rows_positive_disparity_and_q_gives_millimetres(rig: Calibration) -> None:
    points = _scene_points()
    left = rig.rectify_points_left(_project(points, rig.K1, rig.D1, np.eye(3), np.zeros(3)))
    right = rig.rectify_points_right(_project(points, rig.K2, rig.D2, rig.R, rig.T))
    disparity = left[:, 0] - right[:, 0]
    np.testing.assert_allclose(left[:, 1], right[:, 1], atol=1e-3)
    assert np.all(disparity > 0)
    homogeneous = rig.Q @ np.column_stack([left, disparity, np.ones(len(points))]).T
    reconstructed = (homogeneous[:3] / homogeneous[3]).T
    # Q gives the point in the rectified left camera frame, i.e. rotated by R1 from the raw left frame.
    np.testing.assert_allclose(reconstructed, points @ rig.R1.T, atol=1e-3)


def test_rectify_moves_image_content_where_rectify_points_says(rig: Calibration) -> None:
    width, height = rig.image_size
    raw = np.zeros((height, width), np.uint8)
    spot = np.array([1000.0, 200.0])
    cv2.circle(raw, (int(spot[0]), int(spot[1])), 6, 255, -1)
    rectified, _ = rig.rectify(raw, raw)
    moments = cv2.moments(rectified.astype(np.float32))
    centroid = np.array([moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]])
    np.testing.assert_allclose(centroid, rig.rectify_points_left(spot)[0], atol=0.1)


def _textured_raw(rig: Calibration, seed: int = 3) -> np.ndarray:
    """A smooth random texture (a few DN per pixel, as a sole's): sampling positions 1/32 px apart differ by
    a few hundredths of a DN on it, the 8-bit rounding by up to half a DN."""
    width, height = rig.image_size
    noise = np.random.default_rng(seed).random((height, width, 3)).astype(np.float32) * 255
    smooth = cv2.GaussianBlur(noise, (0, 0), 3.0)
    return np.clip((smooth - smooth.mean()) * 8 + 128, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("side", ["left", "right"])
def test_rectify_grey_is_rectify_without_the_rounding(rig: Calibration, side: str) -> None:
    raw = _textured_raw(rig)
    fine = rig.rectify_grey(raw, side)
    # `rectify`'s own sampling positions (its fixed-point maps as float maps) on the float grey image.
    map_x, map_y = cv2.convertMaps(*rig._rectify_map(side), cv2.CV_32FC1)
    exact = cv2.remap(cv2.cvtColor(raw.astype(np.float32), cv2.COLOR_BGR2GRAY), map_x, map_y, cv2.INTER_LINEAR)
    np.testing.assert_allclose(fine, exact, atol=1e-3)
    # `rectify` then `grey` round twice: within a grey level of the fine values, and ~0.35 DN apart.
    rounded = rig.rectify(raw, raw)[0 if side == "left" else 1]
    difference = fine - cv2.cvtColor(rounded, cv2.COLOR_BGR2GRAY).astype(np.float32)
    assert np.abs(difference).max() <= 1.0 + 1e-3
    assert 0.2 < float(np.std(difference)) < 0.5


def test_rectify_grey_moves_image_content_where_rectify_points_says(rig: Calibration) -> None:
    width, height = rig.image_size
    raw = np.zeros((height, width), np.uint8)
    spot = np.array([300.0, 800.0])
    cv2.circle(raw, (int(spot[0]), int(spot[1])), 6, 255, -1)
    moments = cv2.moments(rig.rectify_grey(raw, "right"))
    centroid = np.array([moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]])
    np.testing.assert_allclose(centroid, rig.rectify_points_right(spot)[0], atol=0.1)


@pytest.mark.parametrize(
    "box",
    [(slice(100, 400), slice(200, 900)), (slice(0, 40), slice(0, 50)), (slice(990, 1024), slice(1230, 1280))],
)
def test_rectify_grey_of_a_box_is_that_box_of_the_whole(rig: Calibration, box: tuple[slice, slice]) -> None:
    raw = _textured_raw(rig, 4)
    for side in ("left", "right"):
        np.testing.assert_allclose(rig.rectify_grey(raw, side, box), rig.rectify_grey(raw, side)[box], atol=1e-3)
    assert rig.rectify_grey(raw, "left", (slice(5, 5), slice(0, 10))).shape == (0, 10)


def test_rectify_grey_refuses_a_wrong_size_and_side(rig: Calibration) -> None:
    with pytest.raises(ValueError, match="640x480"):
        rig.rectify_grey(np.zeros((480, 640, 3), np.uint8), "left")
    with pytest.raises(ValueError, match="'left' or 'right'"):
        rig.rectify_grey(_textured_raw(rig), "middle")


def test_baseline_and_focal_length_of_the_simulated_rig(rig: Calibration) -> None:
    assert rig.baseline_mm == pytest.approx(60.0)
    assert rig.focal_px == pytest.approx(rig.P2[0, 0])
    assert -rig.P2[0, 3] / rig.P2[0, 0] == pytest.approx(rig.baseline_mm)
    # 300 mm of sole at the 550 mm working distance spans well over half the image width.
    assert 0.5 < 300.0 * rig.focal_px / 550.0 / rig.image_size[0] < 0.75


def test_save_then_load_gives_the_same_calibration(rig: Calibration, tmp_path: Path) -> None:
    original = Calibration.from_extrinsics(rig.image_size, rig.K1, rig.D1, rig.K2, rig.D2, rig.R, rig.T, rms=0.123)
    path = tmp_path / "calib.yaml"
    original.save(path)
    loaded = Calibration.load(path)
    assert loaded.image_size == original.image_size
    assert loaded.rms == pytest.approx(0.123)
    for key in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_array_equal(getattr(loaded, key), getattr(original, key), err_msg=key)


def _write_keys(path: Path, rig: Calibration, keys: tuple[str, ...]) -> None:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    values = {"image_width": rig.image_size[0], "image_height": rig.image_size[1]}
    for key in keys:
        storage.write(key, values[key] if key in values else getattr(rig, key))
    storage.release()


def test_file_with_only_the_eight_required_keys_loads_and_derives_the_rest(rig: Calibration, tmp_path: Path) -> None:
    path = tmp_path / "minimal.yaml"
    _write_keys(path, rig, REQUIRED_KEYS)
    text = path.read_text()
    assert "P1" not in text and "Q" not in text
    loaded = Calibration.load(path)
    assert loaded.rms is None
    for key in ("R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_allclose(getattr(loaded, key), getattr(rig, key), atol=1e-9, err_msg=key)


@pytest.mark.parametrize("missing", ["image_height", "D2", "T"])
def test_file_missing_a_required_key_names_the_key_and_the_file(rig: Calibration, tmp_path: Path, missing: str) -> None:
    path = tmp_path / "incomplete.yaml"
    _write_keys(path, rig, tuple(key for key in REQUIRED_KEYS if key != missing))
    with pytest.raises(ValueError) as error:
        Calibration.load(path)
    assert missing in str(error.value) and str(path) in str(error.value)


def test_file_with_some_but_not_all_derived_keys_is_refused(rig: Calibration, tmp_path: Path) -> None:
    path = tmp_path / "partial.yaml"
    _write_keys(path, rig, (*REQUIRED_KEYS, "R1", "P1"))
    with pytest.raises(ValueError, match=r"lacks R2, P2, Q"):
        Calibration.load(path)


def test_unreadable_and_absent_files_give_clear_errors(tmp_path: Path) -> None:
    garbage = tmp_path / "garbage.yaml"
    garbage.write_text("K1: [1, 2\n  - {\n")
    with pytest.raises(ValueError, match="not valid OpenCV FileStorage YAML"):
        Calibration.load(garbage)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        Calibration.load(tmp_path / "absent.yaml")


def test_malformed_matrix_is_refused(rig: Calibration, tmp_path: Path) -> None:
    path = tmp_path / "bad-k.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", 1280)
    storage.write("image_height", 1024)
    storage.write("K1", np.eye(2))
    for key in ("D1", "K2", "D2", "R", "T"):
        storage.write(key, getattr(rig, key))
    storage.release()
    with pytest.raises(ValueError, match=r"K1 must be 3x3"):
        Calibration.load(path)


def test_image_of_the_wrong_size_is_refused(rig: Calibration) -> None:
    with pytest.raises(ValueError, match=r"image is 640x480 px but the calibration is for 1280x1024 px"):
        rig.check_image(np.zeros((480, 640), np.uint8))
    with pytest.raises(ValueError, match="640x480"):
        rig.rectify(np.zeros((1024, 1280), np.uint8), np.zeros((480, 640, 3), np.uint8))


def test_swapped_cameras_are_refused(rig: Calibration) -> None:
    # Right camera 60 mm to the LEFT of the left one: disparities would be negative.
    with pytest.raises(ValueError, match="swap the LEFT and RIGHT"):
        Calibration.from_extrinsics(rig.image_size, rig.K1, rig.D1, rig.K2, rig.D2, np.eye(3), [60.0, 0.0, 0.0])


def test_deployed_simulated_rig_file_is_the_default_rig(rig: Calibration) -> None:
    deployed = Calibration.load(Path(__file__).resolve().parents[2] / "deploy" / "sim-calib.yaml")
    for key in ("K1", "D1", "K2", "D2", "R", "T", "P1", "P2", "Q"):
        np.testing.assert_allclose(getattr(deployed, key), getattr(rig, key), atol=1e-12, err_msg=key)


def _with(rig: Calibration, path: Path, **changes: np.ndarray) -> Path:
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", rig.image_size[0])
    storage.write("image_height", rig.image_size[1])
    for key in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        storage.write(key, changes.get(key, getattr(rig, key)))
    storage.release()
    return path


def test_stored_rectification_contradicting_the_extrinsics_is_refused(rig: Calibration, tmp_path: Path) -> None:
    assert Calibration.load(_with(rig, tmp_path / "same.yaml")).baseline_mm == pytest.approx(rig.baseline_mm)
    other = default_rig()
    turned = cv2.Rodrigues(np.array([0.0, 0.05, 0.0]))[0] @ rig.R1
    wide_q = rig.Q.copy()
    wide_q[3, 2] *= 2  # half the baseline: every depth twice as far
    for changes, named in [({"R1": turned}, "R1"), ({"Q": wide_q}, "Q"), ({"T": other.T * 1.5}, "P2")]:
        with pytest.raises(ValueError, match=rf"stored .*{named}.* contradict K1, D1, K2, D2, R, T: remove"):
            Calibration.load(_with(rig, tmp_path / "bad.yaml", **changes))


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("T", np.zeros((3, 1)), "same place"),
        ("K1", np.zeros((3, 3)), "not a camera matrix"),
        ("K2", np.diag([1e30, 1e30, 1.0]), "not a camera matrix"),
    ],
)
def test_impossible_intrinsics_and_baseline_are_refused(
    rig: Calibration, tmp_path: Path, key: str, value: np.ndarray, message: str
) -> None:
    path = tmp_path / "impossible.yaml"
    _write_keys(path, rig, tuple(k for k in REQUIRED_KEYS if k != key))
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_APPEND)
    storage.write(key, value)
    storage.release()
    with pytest.raises(ValueError, match=message):
        Calibration.load(path)


def test_camera_identities_round_trip(rig: Calibration, tmp_path: Path) -> None:
    from dataclasses import replace

    path = tmp_path / "ids.yaml"
    replace(rig, cameras=("usb-A_SN1-video-index0", "usb-A_SN2-video-index0")).save(path)
    assert Calibration.load(path).cameras == ("usb-A_SN1-video-index0", "usb-A_SN2-video-index0")
    rig.save(path)
    assert Calibration.load(path).cameras is None
