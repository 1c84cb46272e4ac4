"""The C core against the numpy reference, stage by stage, exactly."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.stereo import StereoMatcher, make_params
from cellctl.stereo import matcher as stereo

from . import stereo_reference as ref


def _params(**kw):
    p = make_params(**kw)
    return {f: getattr(p, f) for f in p.__dataclass_fields__}


def _pair(seed: int, h: int = 14, w: int = 23, shift: int = 3):
    """A random pair with a real shift (right = left moved by `shift`) plus noise."""
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h, w + shift), dtype=np.int64)
    left = base[:, shift:]
    right = base[:, :w]
    noise = rng.integers(-6, 7, (h, w))
    return left.astype(np.uint8), np.clip(right + noise, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("window", [(5, 5), (3, 3), (9, 7), (1, 3), (7, 1)])
def test_census_matches_reference(window):
    img, _ = _pair(1, 11, 17)
    np.testing.assert_array_equal(stereo.census_transform(img, window), ref.census(img, *window))


COST_CASES = [
    dict(num_disparities=7),
    dict(num_disparities=19, min_disparity=-4),
    dict(num_disparities=5, min_disparity=3, cost="census"),
    dict(num_disparities=6, cost="bt", lambda_bt=4.0),
    dict(num_disparities=16, census_window=(9, 7), census_threshold=0, lambda_census=9.0, cost_scale=100),
    dict(num_disparities=33, min_disparity=-10, census_window=(3, 3)),
    dict(num_disparities=12, bt_prefilter=0, census_smooth=0),  # the raw-intensity BT of the paper
    dict(num_disparities=12, bt_prefilter=5, lambda_bt=3.0),  # the clip bites
    dict(
        num_disparities=10, min_disparity=-3, census_smooth=1, census_window=(7, 5), census_threshold=0, bt_prefilter=63
    ),
    # ternary census: the dead band (1 = ties only, 3 = |diff| <= 2), the largest window (62 bits, 8 planes)
    dict(num_disparities=9, census_threshold=1, lambda_census=90.0),
    dict(num_disparities=14, min_disparity=-2, census_threshold=3, cost="census"),
    dict(num_disparities=8, census_threshold=2, census_window=(9, 3), census_smooth=1, lambda_census=20.0),
]


@pytest.mark.parametrize("simd", ["auto", "avx2", "scalar"])
@pytest.mark.parametrize("case", COST_CASES)
def test_cost_volume_matches_reference(case, simd):
    left, right = _pair(2, 9, 40)
    got = stereo.cost_volume(left, right, simd=simd, **case)
    np.testing.assert_array_equal(got, ref.cost_volume(left, right, _params(**case)))


@pytest.mark.parametrize("simd", ["auto", "avx2", "scalar"])
@pytest.mark.parametrize("threshold", [0, 1, 2, 4])
def test_ternary_census_cost_on_a_low_contrast_pair_matches_reference(threshold, simd):
    """Levels 100..104 only: most pairs fall in the dead band, ties and +-1 steps decide the binary bits."""
    left, right = _pair(7, 10, 33)
    left, right = (100 + left // 52).astype(np.uint8), (100 + right // 52).astype(np.uint8)
    case = dict(num_disparities=11, census_threshold=threshold, lambda_census=90.0)
    got = stereo.cost_volume(left, right, simd=simd, **case)
    np.testing.assert_array_equal(got, ref.cost_volume(left, right, _params(**case)))
    if threshold:  # the dead band changes the cost: a test of the band, not of the binary census again
        assert not np.array_equal(got, stereo.cost_volume(left, right, simd=simd, **(case | {"census_threshold": 0})))


AGG_CASES = [
    dict(num_disparities=7, paths=4),
    dict(num_disparities=9, paths=8, min_disparity=-2),
    dict(num_disparities=20, paths=4, p2_gamma=20, p1=7, p2=90),
    dict(num_disparities=17, paths=8, p2_gamma=5, cost="census", p1=3, p2=31),
    dict(num_disparities=5, paths=4, cost="bt"),
    dict(num_disparities=11, paths=4, census_smooth=1, bt_prefilter=9, p2_gamma=30),
    dict(num_disparities=10, paths=4, census_threshold=2, lambda_census=90.0),
]


@pytest.mark.parametrize("simd", ["auto", "avx2", "scalar"])
@pytest.mark.parametrize("case", AGG_CASES)
def test_aggregation_matches_reference(case, simd):
    left, right = _pair(3, 12, 26)
    got = StereoMatcher(simd=simd, **case).aggregate(left, right)
    np.testing.assert_array_equal(got, ref.aggregate(left, right, _params(**case)))


@pytest.mark.parametrize("simd", ["auto", "avx2", "scalar"])
@pytest.mark.parametrize(
    "levels,uniqueness", [(11, 0), (11, 15), (37, 0), (37, 25), (48, 60), (3, 40), (16, 0), (64, 30)]
)
@pytest.mark.parametrize("subpixel", [True, False])
@pytest.mark.parametrize("dmin", [0, -3, 4])
def test_selection_matches_reference(subpixel, dmin, levels, uniqueness, simd):
    rng = np.random.default_rng(4)
    volume = rng.integers(0, 400, (6, 21, levels)).astype(np.uint16)
    volume[:, :, 3 % levels] = rng.integers(0, 400, (6, 21))  # ties and near-ties
    volume[0, 0, :] = 5  # all equal: the smallest disparity wins
    volume[1, :, 1] = 0  # a clear winner beside random costs
    p = _params(num_disparities=levels, min_disparity=dmin, subpixel=subpixel, uniqueness=uniqueness)
    left, right = stereo.select(volume, min_disparity=dmin, subpixel=subpixel, uniqueness=uniqueness, simd=simd)
    ref_left, ref_right = ref.select(volume.astype(np.int64), p)
    if uniqueness:  # the check really rejects some pixels and keeps others
        assert 0 < np.count_nonzero(ref_left == ref.INVALID) < ref_left.size
    np.testing.assert_array_equal(left, ref_left)
    np.testing.assert_array_equal(right, ref_right)


POST_CASES = [
    dict(fill="background", median=3, weighted_median=0),
    dict(fill="none", median=3, weighted_median=0),
    dict(fill="background", median=5, lr_max_diff=0.5, weighted_median=0),
    dict(median=0, lr_max_diff=-1, weighted_median=0),
    dict(median=5, fill="none", lr_max_diff=2.0, weighted_median=0),
    dict(fill="weighted", fill_radius=2, median=0, weighted_median=0),
    dict(fill="background", median=0, weighted_median=2),
    dict(fill="weighted", fill_radius=3, median=3, weighted_median=1, wm_sigma_colour=7.0, wm_sigma_space=1.5),
    dict(fill="weighted", fill_radius=4, weighted_median=3, num_disparities=6, min_disparity=1),  # clamped levels
    dict(fill="none", weighted_median=2, wm_sigma_colour=400.0, wm_sigma_space=100.0),  # near-plain weighted median
    dict(),  # the defaults
]


def _raw_maps(h: int = 13, w: int = 30):
    rng = np.random.default_rng(5)
    raw_left = (rng.integers(0, 8, (h, w)) * 16 + rng.integers(-8, 8, (h, w))).astype(np.int16)
    raw_right = (rng.integers(0, 8, (h, w)) * 16).astype(np.int16)
    raw_right[rng.random((h, w)) < 0.1] = stereo.INVALID
    raw_right[2, :] = raw_left[2, :]  # a row that passes the check everywhere it can
    guide = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    guide[:, w // 2 :] //= 8  # two colour regions, so the weights matter
    return raw_left, raw_right, guide


@pytest.mark.parametrize("colour", [True, False])
@pytest.mark.parametrize("case", POST_CASES)
def test_postprocess_matches_reference(case, colour):
    raw_left, raw_right, guide = _raw_maps()
    if not colour:
        guide = guide[:, :, 1].copy()
    got = stereo.postprocess(raw_left, raw_right, guide, **case)
    want = ref.postprocess(raw_left.astype(np.int64), raw_right.astype(np.int64), _params(**case), guide)
    for g, r in zip(got, want):
        np.testing.assert_array_equal(g, r)


WEIGHTED_TWIN_CASES = [
    dict(),  # the defaults: fill radius 15, weighted median 3, sigma colour 12 (5 colour byte tables)
    dict(fill_radius=7, weighted_median=5, wm_sigma_colour=20.0),  # 8 colour byte tables
    dict(fill_radius=1, weighted_median=1, wm_sigma_colour=3.0),  # one table
    dict(fill="none", median=0, weighted_median=4),  # the rejected pixels reach the weighted median
    dict(fill_radius=15, weighted_median=15, wm_sigma_space=2.0, num_disparities=20, min_disparity=-4),
    dict(fill_radius=9, wm_sigma_colour=400.0),  # colour weights past 127: the packed kernel
]


@pytest.mark.parametrize("colour", [True, False])
@pytest.mark.parametrize("case", WEIGHTED_TWIN_CASES)
def test_weighted_stages_vector_kernels_equal_the_scalar_kernel(case, colour):
    """The weighted fill and median on maps wider than a vector row, with whole rows and blocks rejected,
    an invalid row and the image borders inside the windows: AVX2 (where the CPU has it) == portable."""
    h, w = 37, 83
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:h, 0:w]
    raw_left = (16 * (3 + (xx > 40) * 6 + (yy > 20) * 3) + rng.integers(-12, 13, (h, w))).astype(np.int16)
    raw_left[24:, :39] = 16 * 6  # a flat region: whole windows on one level
    raw_right = np.full((h, w), stereo.INVALID, np.int16)
    for y in range(h):
        for x in range(w):
            xr = x - (int(raw_left[y, x]) + 8) // 16
            if 0 <= xr < w:
                raw_right[y, xr] = raw_left[y, x] + rng.integers(-10, 11)
    raw_left[5:12, 30:52] = 16 * 14  # a block the check rejects
    raw_left[rng.random((h, w)) < 0.2] = 16 * 15
    raw_right[17, :] = stereo.INVALID  # a row without any measurement
    guide = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    guide[:, 41:] //= 6
    guide[20:26, :] = 90  # a flat band: equal colours, cd = 0
    if not colour:
        guide = guide[:, :, 2].copy()
    vector = stereo.postprocess(raw_left, raw_right, guide, **case)
    scalar = stereo.postprocess(raw_left, raw_right, guide, simd="scalar", **case)
    assert np.count_nonzero(vector[0] == stereo.INVALID) > h * w // 5  # the fill has work
    for v, s in zip(vector, scalar):
        np.testing.assert_array_equal(v, s)


def test_weighted_stages_change_the_result_and_need_a_matching_guide():
    raw_left, raw_right, guide = _raw_maps()
    plain = stereo.postprocess(raw_left, raw_right, guide, fill="background", median=0, weighted_median=0)
    weighted = stereo.postprocess(raw_left, raw_right, guide, fill="weighted", median=0, weighted_median=2)
    assert not np.array_equal(plain[1], weighted[1]) and not np.array_equal(plain[2], weighted[2])
    with pytest.raises(ValueError, match="guide image is"):
        stereo.postprocess(raw_left, raw_right, guide[:, :-1])


def _slanted_maps(h: int = 12, w: int = 40, dmin: int = 0, slope: float = -0.12, seed: int = 7):
    """Raw maps of a slanted plane (d = dmin + 9 + slope * x + 0.05 y, with noise) seen by both views:
    the right map holds what each left pixel predicts, so the check keeps the interior and the
    border-occluded ends fail it, as in a real pair."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    truth = dmin + 9 + slope * x + 0.05 * y
    raw_left = np.round(16 * truth + rng.integers(-4, 5, (h, w))).astype(np.int64)
    raw_right = np.full((h, w), stereo.INVALID, np.int64)
    for yy in range(h):
        for xx in range(w):
            xr = xx - (raw_left[yy, xx] + 8) // 16
            if 0 <= xr < w:
                raw_right[yy, xr] = raw_left[yy, xx] + rng.integers(-8, 9)
    raw_left[rng.random((h, w)) < 0.15] = 16 * (dmin + 1)  # mismatches the check rejects
    guide = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    return raw_left.astype(np.int16), raw_right.astype(np.int16), guide, truth


BORDER_CASES = [
    dict(num_disparities=16, border_fit=6),
    dict(num_disparities=16, border_fit=2, fill="background", median=0, weighted_median=0),
    dict(num_disparities=16, border_fit=30),  # too few points: the strip keeps the fill
    dict(num_disparities=12, border_fit=8, fill_radius=2),  # strip limited to x < 11
    dict(num_disparities=24, min_disparity=-20, border_fit=5, fill_radius=3),  # both borders
    dict(num_disparities=16, border_fit=8, fill="none"),  # no fill, no strips
]


@pytest.mark.parametrize("slope", [-0.12, 0.3, -0.4])  # 0.3 and -0.4 are steeper than the 1/4 clamp
@pytest.mark.parametrize("case", BORDER_CASES)
def test_border_fit_matches_reference(case, slope):
    dmin = case.get("min_disparity", 0)
    raw_left, raw_right, guide, _ = _slanted_maps(dmin=dmin if dmin >= 0 else -12, slope=slope)
    got = stereo.postprocess(raw_left, raw_right, guide, **case)
    want = ref.postprocess(raw_left.astype(np.int64), raw_right.astype(np.int64), _params(**case), guide)
    for g, r in zip(got, want):
        np.testing.assert_array_equal(g, r)


def test_border_fit_follows_a_slanted_surface_across_the_strip():
    raw_left, raw_right, guide, truth = _slanted_maps(h=20, w=60, slope=-0.15, seed=8)
    checked, line, _ = stereo.postprocess(
        raw_left, raw_right, guide, num_disparities=16, border_fit=12, fill="background", median=0, weighted_median=0
    )
    _, flat, _ = stereo.postprocess(
        raw_left, raw_right, guide, num_disparities=16, border_fit=0, fill="background", median=0, weighted_median=0
    )
    strip = np.zeros(checked.shape, bool)
    for y in range(checked.shape[0]):
        strip[y, : np.flatnonzero(checked[y] != stereo.INVALID)[0]] = True
    assert strip.sum() > 50
    err_line = np.abs(stereo.to_float(line) - truth)[strip]
    err_flat = np.abs(stereo.to_float(flat) - truth)[strip]
    assert err_line.max() < 0.5 and err_flat.max() > 1.0


@pytest.mark.parametrize("bad", [dict(uniqueness=-1), dict(uniqueness=100)])
def test_uniqueness_is_validated(bad):
    with pytest.raises(ValueError, match="uniqueness"):
        make_params(**bad)


@pytest.mark.parametrize("bad", [dict(border_fit=1), dict(border_fit=65), dict(border_fit=-1)])
def test_border_fit_is_validated(bad):
    with pytest.raises(ValueError, match="border_fit"):
        make_params(**bad)


@pytest.mark.parametrize(
    "bad",
    [
        dict(fill_radius=0),
        dict(fill_radius=16),
        dict(weighted_median=-1),
        dict(weighted_median=16),
        dict(wm_sigma_colour=0.0),
        dict(wm_sigma_space=-1.0),
        dict(fill="nearest"),
    ],
)
def test_weighted_parameters_are_validated(bad):
    with pytest.raises(ValueError, match=next(iter(bad)).split("_")[0]):
        make_params(**bad)


@pytest.mark.parametrize("colour", [False, True])
@pytest.mark.parametrize(
    "case",
    [
        dict(num_disparities=8, fill="background", median=3, weighted_median=0),
        dict(num_disparities=12, paths=8, min_disparity=-2, median=5, fill="background", weighted_median=0),
        dict(num_disparities=8, fill="weighted", fill_radius=3, median=0, weighted_median=2),
    ],
)
def test_full_pipeline_matches_reference_chain(case, colour):
    left, right = _pair(6, 15, 28)
    guide = left
    if colour:  # matching uses grey; the colour only guides the weighted stages
        guide = np.dstack([left, 255 - left, np.roll(left, 3, axis=1)])
        left = cv2.cvtColor(guide, cv2.COLOR_BGR2GRAY)
    p = _params(**case)
    raw_left, raw_right = ref.select(ref.aggregate(left, right, p), p)
    want = ref.postprocess(raw_left, raw_right, p, guide)
    result = StereoMatcher(**case).compute_detailed(guide, right)
    for got, r in zip(
        (result.raw_left, result.raw_right, result.checked, result.filled, result.disparity),
        (raw_left, raw_right) + tuple(want),
    ):
        np.testing.assert_array_equal(got, stereo.to_float(r.astype(np.int16)))
    assert np.array_equal(result.valid, want[0] != ref.INVALID)


def test_fill_interpolates_holes_on_one_surface_and_takes_the_background_across_a_step():
    row = np.full(12, stereo.INVALID, np.int16)
    row[[1, 5]] = [10 * 16, 11 * 16]  # 1 px apart: one surface, the hole follows the line
    row[[7, 11]] = [11 * 16, 20 * 16]  # 9 px apart: an occlusion, the farther (smaller) value
    raw = np.tile(row, (3, 1))
    guide = np.zeros((3, 12), np.uint8)
    opts = dict(num_disparities=24, lr_max_diff=-1, fill="background", median=0, weighted_median=0, border_fit=0)
    _, filled, _ = stereo.postprocess(raw, raw, guide, fill_interpolate=2, **opts)
    assert filled[1, 2:5].tolist() == [164, 168, 172]  # 160 + 16 * k / 4, rounded half up
    assert filled[1, 8:11].tolist() == [176, 176, 176]
    assert filled[1, 0] == 160  # before the first valid pixel: its value
    _, off, _ = stereo.postprocess(raw, raw, guide, fill_interpolate=0, **opts)
    assert off[1, 2:5].tolist() == [160, 160, 160]


@pytest.mark.parametrize(
    "bad, message",
    [
        (dict(bt_prefilter=-1), "bt_prefilter"),
        (dict(bt_prefilter=64), "bt_prefilter"),
        (dict(census_smooth=3), "census_smooth"),
        (dict(census_threshold=-1), "census_threshold"),
        (dict(census_threshold=256), "census_threshold"),
        (dict(census_threshold=1, census_window=(7, 5)), "at most 32 pixels"),
        (dict(fill_interpolate=-1), "fill_interpolate"),
        (dict(fill_interpolate=65), "fill_interpolate"),
    ],
)
def test_robust_cost_and_fill_parameters_are_validated(bad, message):
    with pytest.raises(ValueError, match=message):
        make_params(**bad)
