"""The change test in C (ChangeTest._texture's vote and ChangeTest.changed's pixel test) against its numpy
reference (tests/vision/change_reference.py): the same images bit for bit, and the same masks, on scenes with
every rule at work (shadows, a lamp, a sole of the table's brightness, a raised and lifted sole)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cellctl.stereo import change_kernels
from cellctl.vision import change
from cellctl.vision.change import ChangeTest

from .change_reference import changed_reference, residual_reference, texture_reference


def _scene(seed: int, shape: tuple[int, int] = (150, 190)) -> tuple[ChangeTest, np.ndarray, np.ndarray, np.ndarray]:
    """A textured table (integer grey levels, as the cameras give them) with a sole, a cast shadow with two
    lamps' overlap beside it, a lit patch and a grey patch of the table's brightness; the fitted test, current,
    reference and the sole's pixels (raised)."""
    rng = np.random.default_rng(seed)
    texture = cv2.GaussianBlur(rng.normal(0.0, 1.0, shape).astype(np.float32), (0, 0), 1.2)
    table = 60.0 + 25.0 * (seed % 3) + (2.0 + 4.0 * (seed % 2)) * texture / float(texture.std())
    reference = np.round(table + rng.normal(0.0, 1.0, shape)).clip(0, 255).astype(np.float32)
    current = table + rng.normal(0.0, 1.0, shape)
    sole = np.zeros(shape, bool)
    sole[40:110, 50:140] = True
    current[sole] = 30.0 + 150.0 * (seed % 2) + 3.0 * rng.normal(0.0, 1.0, int(sole.sum()))
    current[30:120, 140:160] *= 0.6  # a shadow beside the sole
    current[30:120, 142:150] *= 0.8  # the second lamp's shadow over it
    current[5:30, 10:60] *= 1.08  # a lamp's light
    current[120:145, 20:70] = table.mean() + rng.normal(0.0, 1.0, (25, 50))  # the table's brightness, no texture
    current = np.round(cv2.GaussianBlur(current.astype(np.float32), (0, 0), 0.7)).clip(0, 255).astype(np.float32)
    fit_on = ~cv2.dilate(sole.astype(np.uint8), np.ones((21, 21), np.uint8)).astype(bool)
    test = ChangeTest.fit(current, reference, fit_on)
    assert test is not None
    return test, current, reference, sole


def _assert_identical(got: tuple[np.ndarray, ...], want: tuple[np.ndarray, ...]) -> None:
    for name, g, w in zip(("still", "gone", "illumination", "share"), got, want, strict=True):
        assert g.dtype == w.dtype and g.shape == w.shape, name
        assert np.array_equal(g, w), f"{name}: {np.count_nonzero(g != w)} pixels differ"


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("raised", [False, True])
def test_the_kernel_equals_the_numpy_reference_bit_for_bit(seed: int, raised: bool) -> None:
    test, current, reference, sole = _scene(seed)
    got = test._texture(current, reference, sole if raised else None)
    want = texture_reference(test, current, reference, sole if raised else None)
    _assert_identical(got, want)
    # The scene exercises the rules: still table, gone texture, a carried shadow and the local fit's factors.
    still, gone, illumination, _ = got
    assert still.mean() > 0.1 and gone.any() and (illumination < 0.9).any() and (illumination != 1.0).mean() > 0.2


def test_the_kernel_reads_views_of_a_larger_image_as_their_copies() -> None:
    test, current, reference, sole = _scene(1)
    box = (slice(7, 140), slice(11, 180))
    got = test._texture(current[box], reference[box], sole[box])
    _assert_identical(got, texture_reference(test, current[box].copy(), reference[box].copy(), sole[box].copy()))


def test_non_integer_grey_levels_give_the_references_result_too() -> None:
    test, current, reference, sole = _scene(2)
    rng = np.random.default_rng(7)
    current = current + rng.normal(0.0, 0.3, current.shape).astype(np.float32)
    _assert_identical(test._texture(current, reference, sole), texture_reference(test, current, reference, sole))


def test_a_non_finite_pixel_is_refused() -> None:
    test, current, reference, _ = _scene(0)
    current[3, 4] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        test._texture(current, reference)


@pytest.mark.parametrize("seed", range(6))
def test_the_whole_change_test_equals_the_numpy_reference_pixel_for_pixel(seed: int) -> None:
    # The pixel test after the vote is in C too (change_kernels.residual): with depth's raised and lifted
    # pixels (the rim ring and the lifted fill at work) the mask is main's numpy mask, pixel for pixel.
    test, current, reference, sole = _scene(seed)
    lifted = cv2.erode(sole.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    for raised, lift in ((None, None), (sole, None), (sole, lifted)):
        got = test.changed(current, reference, raised=raised, lifted=lift)
        want = changed_reference(test, current, reference, raised, lift)
        assert np.array_equal(got, want), f"{np.count_nonzero(got != want)} pixels differ"
    assert 0.2 < got.mean() < 0.6


def test_the_pixel_test_equals_the_numpy_reference_bit_for_bit() -> None:
    test, current, reference, sole = _scene(3)
    _, gone, illumination, _ = test._texture(current, reference, sole)
    rules = change_kernels.ResidualRules(
        gain=test.gain,
        offset=test.offset,
        floor=change.PIXEL_SIGMAS * test.sigma,
        contrast_window=change.CONTRAST_WINDOW_PX,
        faint_contrast=change.FAINT_CONTRAST_SIGMAS * test.sigma,
        gone_window=change.GONE_WINDOW_PX,
        gone_inside=change.GONE_INSIDE,
    )
    residual, raw = change_kernels.residual(current, reference, rules, illumination, gone)
    want_residual, want_raw = residual_reference(test, current, reference, illumination, gone)
    assert np.array_equal(residual, want_residual) and np.array_equal(raw, want_raw)
    assert raw.any() and (raw & gone).any()


def test_the_mask_is_the_same_on_one_thread() -> None:
    test, current, reference, sole = _scene(4)
    box = (slice(10, 140), slice(20, 185))
    assert np.array_equal(
        test.changed(current, reference, box, sole, sole, threads=1), test.changed(current, reference, box, sole, sole)
    )
