"""Stereo calibration of simulated checkerboard pairs, end to end through the CLI, and its bad inputs.

One simulated session (12 good pairs of the default rig plus a board partly outside the image and a
motion-blurred unsynchronised pair) is calibrated once per module; the tests check what came out.
"""

from __future__ import annotations

import contextlib
import io
import re
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.calib.board import Checkerboard, find_corners
from cellctl.calib.pairs import find_pairs
from cellctl.calib.zhang import calibrate_views, detect_views
from cellctl.cli import main
from cellctl.sim.checkerboard import BoardPose, BoardTexture, CheckerboardSimulator
from cellctl.sim.rig import default_rig
from cellctl.vision.calibration import Calibration
from cellctl.vision.rectification import vertical_disparity

BOARD = Checkerboard(9, 6, 30.0)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("calib")
    pairs_dir, calib = root / "pairs", root / "out" / "calib.yaml"
    assert main(["simulate", "checkerboard", "--out", str(pairs_dir), "--pairs", "12", "--seed", "3"]) == 0
    out = io.StringIO()  # capsys is per test; this fixture runs once per module
    with contextlib.redirect_stdout(out):
        status = main(["calibrate", str(pairs_dir), "--board", "9x6", "--square", "30", "-o", str(calib)])
    assert status == 0, out.getvalue()
    bad = dict(line.split() for line in (pairs_dir / "bad-pairs.txt").read_text().splitlines())
    return {
        "dir": pairs_dir,
        "calib": calib,
        "stdout": out.getvalue(),
        "estimated": Calibration.load(calib),
        "true": Calibration.load(pairs_dir / "true-calib.yaml"),
        "bad": bad,
    }


def _relative_error(estimated: float, true: float) -> float:
    return abs(estimated - true) / abs(true)


@pytest.mark.parametrize("camera", ["K1", "K2"])
def test_focal_lengths_and_principal_points_within_half_a_percent(session: dict, camera: str) -> None:
    estimated, true = getattr(session["estimated"], camera), getattr(session["true"], camera)
    for (row, col), name in zip([(0, 0), (1, 1), (0, 2), (1, 2)], ["fx", "fy", "cx", "cy"]):
        error = _relative_error(estimated[row, col], true[row, col])
        assert error < 0.005, f"{camera} {name}: {estimated[row, col]:.2f} vs {true[row, col]:.2f} ({error:.3%})"


def test_baseline_within_half_a_percent(session: dict) -> None:
    estimated, true = session["estimated"].baseline_mm, session["true"].baseline_mm
    assert _relative_error(estimated, true) < 0.005, f"baseline {estimated:.3f} mm vs {true:.3f} mm"


def test_exactly_the_bad_pairs_are_rejected(session: dict) -> None:
    rows = re.findall(r"^(\d\d)\s+(kept|rejected|skipped)\b", session["stdout"], flags=re.MULTILINE)
    assert len(rows) == 14
    assert {name for name, status in rows if status != "kept"} == set(session["bad"])
    assert set(session["bad"].values()) == {"outside", "blur"}


def test_pair_without_corners_is_named_and_skipped(session: dict) -> None:
    outside = next(name for name, kind in session["bad"].items() if kind == "outside")
    assert re.search(rf"skipping pair {outside}: no 9x6 corners found in left_{outside}", session["stdout"])


def test_error_chart_is_written_next_to_the_calibration(session: dict) -> None:
    chart = cv2.imread(str(session["calib"].with_name("calib-errors.png")))
    assert chart is not None and chart.shape[1] >= 480


def _speckle_pair(rig: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """A tilted, randomly speckled plane filling both views, imaged by `rig` (textured, unlike a board)."""
    extent = Checkerboard(40, 31, 20.0)  # only the plane's size: its printed pattern is replaced below
    simulator = CheckerboardSimulator(rig, extent, seed=5)
    outline = extent.outline()
    texel = 0.5
    rng = np.random.default_rng(5)
    shape = (int((outline[2, 1] - outline[0, 1]) / texel), int((outline[2, 0] - outline[0, 0]) / texel))
    speckle = cv2.GaussianBlur(rng.random(shape, dtype=np.float32), (0, 0), 3.0)
    speckle = (speckle - speckle.min()) / np.ptp(speckle) * 200 + 25
    rotation = cv2.Rodrigues(np.array([0.15, -0.1, 0.05]))[0]
    centre = np.array([30.0, 0.0, 560.0]) - rotation @ np.array([19.5, 15.0, 0.0]) * extent.square_mm
    pose = BoardPose(rotation, centre.reshape(3, 1))
    texture = BoardTexture(speckle, texel)
    images = []
    for side in ("left", "right"):
        image = simulator.render_image(pose, side, texture) + rng.normal(0, 2.0, rig.image_size[::-1])
        images.append(np.clip(image, 0, 255).astype(np.uint8))
    return images[0], images[1]


@pytest.fixture(scope="module")
def speckle(session: dict) -> tuple[np.ndarray, np.ndarray]:
    return _speckle_pair(session["true"])


def test_rectified_residual_vertical_disparity_below_0_3_px(session: dict, speckle: tuple) -> None:
    residual = vertical_disparity(*session["estimated"].rectify(*speckle))
    assert residual.dy.size > 500 and "warning" not in residual.summary()
    assert residual.rms < 0.3, residual.summary()


def test_vertical_disparity_warns_that_a_checkerboard_is_too_repetitive_to_measure(session: dict) -> None:
    left, right = (cv2.imread(str(session["dir"] / f"{side}_01.png")) for side in ("left", "right"))
    residual = vertical_disparity(*session["estimated"].rectify(left, right))
    assert "warning: many mismatches" in residual.summary()


def test_vertical_disparity_exposes_a_camera_knocked_after_calibration(session: dict, speckle: tuple) -> None:
    good = session["estimated"]
    knocked = cv2.Rodrigues(np.array([0.004, 0.0, 0.0]))[0] @ good.R  # 0.23 degrees about the x axis
    moved = Calibration.from_extrinsics(good.image_size, good.K1, good.D1, good.K2, good.D2, knocked, good.T)
    assert vertical_disparity(*moved.rectify(*speckle)).rms > 1.0


def test_rectify_command_writes_the_pair_and_reports_vertical_disparity(
    session: dict, speckle: tuple, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    left, right = tmp_path / "l.png", tmp_path / "r.png"
    cv2.imwrite(str(left), speckle[0])
    cv2.imwrite(str(right), speckle[1])
    assert main(["rectify", "--calib", str(session["calib"]), str(left), str(right), "-o", str(tmp_path / "out")]) == 0
    rms = float(re.search(r"RMS ([\d.]+) px", capsys.readouterr().out).group(1))
    assert rms < 0.3
    for name in ("rectified_left.png", "rectified_right.png", "side_by_side.png", "side_by_side_raw.png"):
        assert (tmp_path / "out" / name).is_file(), name
    assert cv2.imread(str(tmp_path / "out" / "side_by_side.png")).shape == (1024, 2560, 3)


def test_rectify_command_refuses_an_image_of_another_size(session: dict, tmp_path: Path, capsys) -> None:
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.zeros((480, 640), np.uint8))
    assert main(["rectify", "--calib", str(session["calib"]), str(small), str(small), "-o", str(tmp_path)]) == 2
    assert "640x480 px but the calibration is for 1280x1024 px" in capsys.readouterr().err


def test_corners_are_numbered_by_the_board_not_by_the_view(session: dict) -> None:
    image = cv2.imread(str(session["dir"] / "left_01.png"), cv2.IMREAD_GRAYSCALE)
    upright = find_corners(image, BOARD)
    turned = find_corners(cv2.rotate(image, cv2.ROTATE_180), BOARD)
    height, width = image.shape
    # Turning the image by 180 degrees moves each corner to (w-1-x, h-1-y) but must not renumber it.
    expected = np.column_stack([width - 1 - upright[:, 0], height - 1 - upright[:, 1]])
    np.testing.assert_allclose(turned, expected, atol=0.05)


def test_min_pairs_is_never_undercut_by_rejection(session: dict) -> None:
    views = detect_views(find_pairs(session["dir"]), BOARD)
    usable = sum(view.usable for view in views)
    result = calibrate_views(views, BOARD, min_pairs=usable)
    assert len(result.kept) == usable  # the blurred pair stays in: rejecting it would go below min_pairs


def _copy_pairs(source: Path, target: Path, names: list[str]) -> None:
    target.mkdir()
    for name in names:
        for side in ("left", "right"):
            shutil.copy(source / f"{side}_{name}.png", target / f"{side}_{name}.png")


def test_too_few_usable_pairs_is_an_error(session: dict, tmp_path: Path, capsys) -> None:
    few = tmp_path / "few"
    _copy_pairs(session["dir"], few, ["01", "02", "03"])
    assert main(["calibrate", str(few), "--board", "9x6", "--square", "30", "-o", str(tmp_path / "c.yaml")]) == 2
    assert "too few usable pairs: 3 of 3, at least 6 needed" in capsys.readouterr().err
    assert not (tmp_path / "c.yaml").exists()


def test_images_of_different_sizes_are_an_error(session: dict, tmp_path: Path, capsys) -> None:
    mixed = tmp_path / "mixed"
    _copy_pairs(session["dir"], mixed, ["01", "02"])
    right = cv2.imread(str(mixed / "right_02.png"))
    cv2.imwrite(str(mixed / "right_02.png"), cv2.resize(right, (640, 512)))
    assert main(["calibrate", str(mixed), "--board", "9x6", "--square", "30", "-o", str(tmp_path / "c.yaml")]) == 2
    assert "left_02.png is 1280x1024 px but right_02.png is 640x512 px" in capsys.readouterr().err


def test_lone_image_is_skipped_with_its_missing_partner_named(session: dict, tmp_path: Path) -> None:
    lone = tmp_path / "lone"
    _copy_pairs(session["dir"], lone, ["01"])
    (lone / "right_01.png").unlink()
    views = detect_views(find_pairs(lone), BOARD)
    assert views[0].problem == "right_01 image missing"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--board", "9by6", "--square", "30"], "not COLSxROWS"),
        (["--board", "7x7", "--square", "30"], "different inner-corner counts"),
        (["--board", "9x6", "--square", "0"], "square size must be positive"),
    ],
)
def test_bad_board_options_are_errors(tmp_path: Path, capsys, argv: list[str], message: str) -> None:
    assert main(["calibrate", str(tmp_path), *argv, "-o", str(tmp_path / "c.yaml")]) == 2
    assert message in capsys.readouterr().err


def test_directory_without_pairs_is_an_error(tmp_path: Path, capsys) -> None:
    assert main(["calibrate", str(tmp_path), "--board", "9x6", "--square", "30", "-o", str(tmp_path / "c.yaml")]) == 2
    assert "no left_NN.png / right_NN.png images" in capsys.readouterr().err
    assert main(["calibrate", str(tmp_path / "nowhere"), "--board", "9x6", "--square", "30", "-o", "c.yaml"]) == 2
    assert "is not a directory" in capsys.readouterr().err


def test_simulator_truth_matches_the_rig() -> None:
    """The simulated images really are what the rig sees: detected corners sit on the true projections."""
    rig = default_rig()
    simulator = CheckerboardSimulator(rig, BOARD, seed=11)
    pair = simulator.render("01")
    for side, image in (("left", pair.left), ("right", pair.right)):
        found = find_corners(image, BOARD)
        error = np.sqrt(np.mean(np.sum((found - simulator.projected_corners(pair.pose, side)) ** 2, axis=1)))
        assert error < 0.1, f"{side}: {error:.3f} px"
