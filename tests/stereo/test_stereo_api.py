"""StereoMatcher's public behaviour: input checks, determinism, sanity on real data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.eval.matcher_bench import synthetic_case
from cellctl.eval.middlebury import resolve_data_dir
from cellctl.stereo import StereoMatcher


def _scene(name: str):
    d = resolve_data_dir() / name  # a clear failure, not a skip, when ../shared is missing
    left, right = cv2.imread(str(d / "left.png")), cv2.imread(str(d / "right.png"))
    return left, right, d


def _bad_rate(disp: np.ndarray, d: Path, scale: int) -> float:
    gt = cv2.imread(str(d / "gt.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32) / scale
    mask = cv2.imread(str(d / "nonocc.png"), cv2.IMREAD_GRAYSCALE) == 255
    bad = ~(np.abs(disp - gt) <= 1.0)  # NaN counts as bad
    return float((bad & mask).sum() / mask.sum())


def test_output_shape_type_and_nan_for_invalid():
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (40, 60), dtype=np.uint8)
    m = StereoMatcher(0, 16, fill="none")
    disp = m.compute(left, np.roll(left, -3, axis=1))
    assert disp.dtype == np.float32 and disp.shape == (40, 60)
    assert np.isnan(disp).any(), "the left border cannot be matched and must be NaN without fill"
    inner = disp[5:-5, 20:-5]
    assert np.nanmedian(inner) == pytest.approx(3.0, abs=0.2)


def test_matches_bgr_in_grey_and_uses_the_colour_only_to_guide_the_weighted_stages():
    left, right, _ = _scene("tsukuba")
    m = StereoMatcher(0, 16)
    grey_left, grey_right = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    colour, grey = m.compute_detailed(left, right), m.compute_detailed(grey_left, grey_right)
    for stage in ("raw_left", "raw_right", "checked"):
        np.testing.assert_array_equal(getattr(colour, stage), getattr(grey, stage), err_msg=stage)
    assert not np.array_equal(colour.disparity, grey.disparity, equal_nan=True)
    # A BGR image whose channels are equal is the grey image, also for the weighted stages.
    grey_as_bgr = cv2.cvtColor(grey_left, cv2.COLOR_GRAY2BGR)
    np.testing.assert_array_equal(m.compute(grey_as_bgr, grey_right), grey.disparity)


def test_thread_count_and_simd_do_not_change_the_result():
    left, right, _ = _scene("venus")
    base = StereoMatcher(0, 20, threads=1, simd="scalar").compute_fixed(left, right)
    for kw in (
        dict(threads=1),
        dict(threads=2),
        dict(threads=3),
        dict(threads=2, paths=8),
        dict(simd="scalar", threads=2),
    ):
        m = StereoMatcher(0, 20, **kw)
        got = m.compute_fixed(left, right)
        if kw.get("paths") == 8:
            assert not np.array_equal(got, base)  # a real change of method does change it
        else:
            np.testing.assert_array_equal(got, base, err_msg=str(kw))


@pytest.mark.parametrize("num_disparities", [16, 40])
def test_buffer_layouts_do_not_change_the_result(num_disparities):
    # 16: the smallest per-thread scratch, which the frame preparation borrows (it once overlapped the
    # horizontal path guards); 40: cost slots padded from 48 to 64 bytes, written by adjacent stripes.
    left, right, _ = _scene("tsukuba")
    base = StereoMatcher(0, num_disparities, threads=1, simd="scalar").compute_fixed(left, right)
    for kw in (dict(threads=1), dict(threads=2), dict(threads=3), dict(simd="scalar", threads=3)):
        m = StereoMatcher(0, num_disparities, **kw)
        np.testing.assert_array_equal(m.compute_fixed(left, right), base, err_msg=str(kw))
        np.testing.assert_array_equal(m.compute_fixed(left, right), base, err_msg=f"{kw}, second call")


def test_a_volume_written_past_the_caches_gives_the_same_result():
    # 640 x 416 x 128 disparities: a 65 MiB volume, which pass 1 writes with non-temporal stores
    case = synthetic_case(640, 416, 128)
    base = StereoMatcher(0, 128, simd="scalar").compute_fixed(case.left, case.right)
    np.testing.assert_array_equal(StereoMatcher(0, 128).compute_fixed(case.left, case.right), base)


def test_repeated_calls_and_size_changes_reuse_buffers_correctly():
    left, right, _ = _scene("tsukuba")
    m = StereoMatcher(0, 16)
    first = m.compute_fixed(left, right)
    small = m.compute_fixed(left[:100, :200], right[:100, :200])
    assert small.shape == (100, 200)
    np.testing.assert_array_equal(m.compute_fixed(left, right), first)


def test_any_disparity_count_and_negative_minimum():
    left, right, d = _scene("tsukuba")
    # shifted(x) = right(x - 8): true disparities (5..14) become d - 8, some negative,
    # and a count of 15 is no multiple of anything convenient.
    shifted = np.zeros_like(right)
    shifted[:, 8:] = right[:, :-8]
    disp = StereoMatcher(-8, 15).compute(left, shifted)
    assert np.nanmin(disp) < 0
    assert _bad_rate(disp + 8, d, 16) < 0.12


def test_fewer_bad_pixels_than_opencv_hh4_on_teddy():
    left, right, d = _scene("teddy")
    ours = StereoMatcher(0, 64).compute(left, right)
    bs = 5
    sgbm = cv2.StereoSGBM_create(
        0,
        64,
        bs,
        P1=8 * 3 * bs * bs,
        P2=32 * 3 * bs * bs,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.StereoSGBM_MODE_HH4,
    )
    raw = sgbm.compute(left, right)
    theirs = np.where(raw < 0, np.nan, raw / 16.0).astype(np.float32)
    ours_rate, theirs_rate = _bad_rate(ours, d, 4), _bad_rate(theirs, d, 4)
    assert ours_rate < theirs_rate, f"ours {ours_rate:.3%} vs OpenCV HH4 {theirs_rate:.3%}"


BAD_PARAMS = [
    (dict(num_disparities=0), "num_disparities"),
    (dict(p1=20, p2=10), "p2 must be greater than p1"),
    (dict(p1=10, p2=10), "p2 must be greater than p1"),
    (dict(lambda_census=float("nan")), "lambda_census"),
    (dict(lambda_bt=-1.0), "lambda_bt"),
    (dict(census_window=(4, 5)), "census_width"),
    (dict(census_window=(9, 9)), "census_height"),
    (dict(paths=6), "paths"),
    (dict(median=4), "median"),
    (dict(cost="sad"), "cost must be one of"),
    (dict(fill="nearest"), "fill must be one of"),
    (dict(num_disparities=12.5), "whole number"),
    (dict(lr_max_diff=float("inf")), "lr_max_diff"),
    (dict(threads=-1), "threads"),
    (dict(block_size=5), "unknown matcher parameter"),
]


@pytest.mark.parametrize("kw,message", BAD_PARAMS)
def test_bad_parameters_raise_clear_errors(kw, message):
    with pytest.raises(ValueError, match=message):
        StereoMatcher(**kw)


def _img(h=20, w=30, dtype=np.uint8):
    return np.zeros((h, w), dtype)


BAD_IMAGES = [
    ((_img(), _img(20, 31)), "differ in size"),
    ((_img(dtype=np.float32), _img()), "8-bit"),
    ((_img(0, 0), _img(0, 0)), "empty"),
    ((np.zeros((4, 5, 2), np.uint8), np.zeros((4, 5, 2), np.uint8)), "grey"),
    (([[1, 2]], _img()), "numpy array"),
    ((_img(20, 10), _img(20, 10)), "does not fit an image 10 px wide"),
]


@pytest.mark.parametrize("images,message", BAD_IMAGES)
def test_bad_images_raise_clear_errors(images, message):
    with pytest.raises(ValueError, match=message):
        StereoMatcher(0, 16).compute(*images)


def test_range_entirely_outside_the_image_is_rejected():
    with pytest.raises(ValueError, match="does not fit"):
        StereoMatcher(40, 8).compute(_img(), _img())
    with pytest.raises(ValueError, match="does not fit"):
        StereoMatcher(-50, 8).compute(_img(), _img())


def test_tiny_images_work():
    one = np.full((1, 1), 7, np.uint8)
    assert StereoMatcher(0, 1).compute(one, one).shape == (1, 1)
    two = np.array([[10, 200]], np.uint8)
    disp = StereoMatcher(0, 2, median=0).compute(two, two)
    assert disp.shape == (1, 2)


@pytest.mark.parametrize("shape", [(375, 450), (3, 5), (1, 1), (9, 7)])
def test_to_float_is_the_fixed_point_value_with_nan_for_invalid(shape):
    from cellctl.stereo import INVALID, to_float

    rng = np.random.default_rng(3)
    fixed = rng.integers(-32768, 32768, shape).astype(np.int16)
    fixed[rng.random(shape) < 0.2] = INVALID
    want = fixed.astype(np.float32) / 16
    want[fixed == INVALID] = np.nan
    got = to_float(fixed)
    assert got.dtype == np.float32 and got.shape == shape
    assert got.tobytes() == want.tobytes()
    assert to_float(fixed.T).tobytes() == np.ascontiguousarray(want.T).tobytes()  # any layout
    assert to_float(fixed.astype(np.int32)).tobytes() == want.tobytes()  # other integer types: the same
