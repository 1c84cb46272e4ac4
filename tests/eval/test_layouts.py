"""The 2005/2006 and 2014 Middlebury layouts, the HH4 + fill reference, the comparison and radiometric check."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.eval import comparison, layouts, middlebury, radiometric
from cellctl.eval.methods import METHODS, background_fill

NAN = np.nan


def _textured_pair(h: int, w: int, shift: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    base = cv2.GaussianBlur(rng.integers(0, 256, (h, w + shift), dtype=np.uint8), (3, 3), 0)
    left, right = base[:, :w], base[:, shift:]
    return cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)


def _write_pfm(path: Path, image: np.ndarray) -> None:
    h, w = image.shape
    with open(path, "wb") as f:
        f.write(f"Pf\n{w} {h}\n-1.0\n".encode())
        f.write(np.ascontiguousarray(image[::-1], "<f4").tobytes())


def _folder_2014(root: Path, shift: int = 6) -> Path:
    folder = root / "Synth"
    folder.mkdir(parents=True)
    left, right = _textured_pair(40, 90, shift)
    cv2.imwrite(str(folder / "im0.png"), left)
    cv2.imwrite(str(folder / "im1.png"), right)
    gt = np.full((40, 90), float(shift), np.float32)
    gt[:, :5] = np.inf  # unknown
    gt[0, 40] = 7.25  # a non-integer value survives the round trip
    _write_pfm(folder / "disp0GT.pfm", gt)
    mask = np.full((40, 90), 255, np.uint8)
    mask[:, 80:] = 128  # occluded: in "all", not in "nonocc"
    mask[:, :5] = 0
    cv2.imwrite(str(folder / "mask0nocc.png"), mask)
    (folder / "calib.txt").write_text(
        "cam0=[1 0 1; 0 1 1; 0 0 1]\ndoffs=0\nbaseline=100\nwidth=90\nheight=40\nndisp=16\n"
    )
    return folder


def test_2014_layout_reads_pfm_calib_and_masks(tmp_path: Path) -> None:
    _folder_2014(tmp_path)
    [scene] = layouts.load_dataset(tmp_path)
    assert scene.info.layout == layouts.LAYOUT_2014 and scene.info.num_disparities == 16
    assert scene.ground_truth[0, 40] == pytest.approx(7.25) and scene.ground_truth[39, 40] == 6.0
    assert np.isnan(scene.ground_truth[:, :5]).all()
    assert set(scene.regions) == {"nonocc", "all"}
    assert scene.regions["all"][:, 80:].all() and not scene.regions["nonocc"][:, 80:].any()
    # the truth scores zero; a shift by 1.5 px scores all bad
    assert middlebury.score(scene.ground_truth, scene).mean_percent == 0.0
    assert middlebury.score(scene.ground_truth + 1.5, scene).mean_percent == 100.0


def test_2014_layout_is_matched_end_to_end(tmp_path: Path) -> None:
    _folder_2014(tmp_path)
    [scene] = layouts.load_dataset(tmp_path)
    result = middlebury.run_method("proposed", METHODS["proposed"].compute, scene)
    assert result.score.bad_percent["nonocc"] < 5.0


def test_2005_layout_band_unknowns_and_range(tmp_path: Path) -> None:
    folder = tmp_path / "Flat"
    folder.mkdir()
    left, right = _textured_pair(30, 60, 4)
    cv2.imwrite(str(folder / "left.png"), left)
    cv2.imwrite(str(folder / "right.png"), right)
    gt = np.full((30, 60), 12, np.uint8)  # 4 px
    gt[:, 30] = 0  # unknown
    gt[5, 50] = 20  # 6.67 px: the largest, so ndisp = ceil(6.67) + 2 = 9
    cv2.imwrite(str(folder / "gt.png"), gt)
    [scene] = layouts.load_dataset(tmp_path)
    assert scene.info.layout == layouts.LAYOUT_2005 and scene.info.num_disparities == 9
    assert list(scene.regions) == ["all"]
    assert not scene.regions["all"][:, :9].any() and scene.regions["all"][:, 9:].all()
    disparity = np.full((30, 60), 4.0, np.float32)
    disparity[:, :9] = NAN  # inside the band: not counted
    disparity[:, 30] = NAN  # unknown truth: not counted
    disparity[0, 40] = NAN  # counted, invalid = bad
    evaluated = 30 * (60 - 9) - 30 - 1  # column 30 and the 6.67 px pixel (|4 - 6.67| > 1)
    expected = 100.0 * 2 / (evaluated + 1)
    assert middlebury.score(disparity, scene).mean_percent == pytest.approx(expected)


def test_dataset_errors_name_the_problem(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not found"):
        layouts.load_dataset(tmp_path / "nowhere")
    with pytest.raises(FileNotFoundError, match="no Middlebury scene"):
        layouts.load_dataset(tmp_path)
    _folder_2014(tmp_path)
    with pytest.raises(ValueError, match="Other.*not in"):
        layouts.load_dataset(tmp_path, ["Other"])
    (tmp_path / "Synth" / "calib.txt").write_text("width=90\n")
    with pytest.raises(ValueError, match="ndisp"):
        layouts.load_dataset(tmp_path)


def test_background_fill_takes_the_farther_neighbour() -> None:
    d = np.array([[NAN, 5.0, NAN, NAN, 9.0, NAN], [NAN, NAN, NAN, NAN, NAN, NAN]], np.float32)
    out = background_fill(d)
    np.testing.assert_array_equal(out[0], [5.0, 5.0, 5.0, 5.0, 9.0, 9.0])
    assert np.isnan(out[1]).all()


def test_radiometric_variants_change_only_the_right_image(tmp_path: Path) -> None:
    _folder_2014(tmp_path)
    [scene] = layouts.load_dataset(tmp_path)
    lut = radiometric.VARIANTS["gain"].lut()
    assert lut[0] == 0 and lut[255] == 204 and np.all(np.diff(lut.astype(int)) >= 0)
    assert radiometric.VARIANTS["gamma"].lut()[128] == round(255 * (128 / 255) ** 1.2)
    assert radiometric.VARIANTS["offset"].lut()[250] == 255
    changed = radiometric.apply(scene, radiometric.VARIANTS["all"])
    assert changed.left is scene.left and not np.array_equal(changed.right, scene.right)


def _result(method: str, scene: str, percent: float, seconds: float) -> middlebury.SceneResult:
    score = middlebury.Score({"all": percent}, 0.5)
    return middlebury.SceneResult(method, scene, np.zeros((1, 1), np.float32), score, seconds)


def test_comparison_counts_wins_means_and_time_ratio(tmp_path: Path) -> None:
    info = middlebury.SceneInfo("A", 3, 0, 8, layouts.LAYOUT_2005)
    scenes = [
        middlebury.Scene(middlebury.SceneInfo(n, 3, 0, 8, layouts.LAYOUT_2005), *([np.zeros((1, 1))] * 3), {})
        for n in ("A", "B", "C")
    ]
    assert info.name == "A"
    results = [
        _result("proposed", "A", 2.0, 1.0),
        _result("proposed", "B", 6.0, 1.0),
        _result("proposed", "C", 4.0, 1.0),
        _result("opencv-hh4-fill", "A", 3.0, 9.0),
        _result("opencv-hh4-fill", "B", 5.0, 9.0),
        _result("opencv-hh4-fill", "C", 4.0, 9.0),  # a tie is no win
        _result("opencv-hh4", "A", 9.0, 4.0),
        _result("opencv-hh4", "B", 9.0, 4.0),
        _result("opencv-hh4", "C", 9.0, 4.0),
    ]
    [summary] = comparison.summarise(results, scenes)
    assert summary.wins == 1 and summary.scenes == 3
    assert summary.ours_mean == pytest.approx(4.0) and summary.reference_mean == pytest.approx(4.0)
    assert summary.time_ratio == pytest.approx(0.25)
    text = comparison.markdown(results, scenes)
    assert "| 2005-2006 | C | 4.00 | 0.50 | 4.00 | tie |" in text and "1 of 3" in text
