"""The change test's C kernels (cellctl.stereo.change_kernels): box means equal cv2.blur's bit for bit, the
results do not depend on the thread count, and bad arguments are refused with an error, never a crash (this
file runs under ASan and UBSan: make asan). The texture vote's rules are checked against their numpy reference
in tests/vision/test_change_kernel.py."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from cellctl.stereo import change_kernels
from cellctl.stereo.change_kernels import TextureRules

RULES = TextureRules(
    gain=0.97,
    offset=1.5,
    ncc_window=7,
    table_ncc=0.5,
    min_texture_gain=0.3,
    max_texture_gain=3.0,
    unanimous=0.9,
    min_textured_share=0.3,
    textured_variance=(2.0 * 1.3) ** 2,
    still_variance=1.3**2,
    fit_variance=(1.5 * 1.3) ** 2,
    scale_agreement=0.4,
    max_shadow_factor=0.95,
    max_carried_factor=1.1,
    illumination_window=31,
    far_weight=0.05,
    near_weight=0.1,
    local_shadow_fit=True,
    min_local_fit_share=0.1,
    raised_local_fit_share=0.5,
)


def _pair(shape: tuple[int, int], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    reference = np.round(80.0 + 8.0 * rng.normal(0.0, 1.0, shape)).astype(np.float32)
    current = reference * 0.97 + rng.normal(0.0, 1.0, shape).astype(np.float32)
    current[shape[0] // 4 : shape[0] // 2, shape[1] // 4 :] = 200.0
    current[shape[0] // 2 :, : shape[1] // 3] *= 0.6
    return current, reference


@pytest.mark.parametrize("size", [3, 5, 7, 9, 11, 15, 31])
@pytest.mark.parametrize("shape", [(120, 97), (40, 300), (9, 11)])
def test_box_mean_equals_cv2_blur_bit_for_bit(size: int, shape: tuple[int, int]) -> None:
    rng = np.random.default_rng(size)
    image = (rng.random(shape) * rng.random(shape) * 300.0).astype(np.float32)
    image[rng.random(shape) < 0.3] = 0.0
    assert np.array_equal(change_kernels.box_mean(image, size), cv2.blur(image, (size, size)))


def test_the_texture_vote_is_the_same_on_one_thread_and_on_all() -> None:
    current, reference = _pair((200, 260))
    raised = np.zeros(current.shape, bool)
    raised[50:100, 65:] = True
    one = change_kernels.texture(current, reference, RULES, raised, threads=1)
    for threads in (0, 2, 3):
        for got, want in zip(change_kernels.texture(current, reference, RULES, raised, threads), one, strict=True):
            assert np.array_equal(got, want)
    still, gone, illumination, share = one
    assert still.any() and gone.any() and (illumination != 1.0).any() and share.any()


def test_images_smaller_than_the_windows_are_computed() -> None:
    current, reference = _pair((5, 6))
    still, gone, illumination, share = change_kernels.texture(current, reference, RULES)
    assert still.shape == gone.shape == illumination.shape == share.shape == (5, 6)
    assert np.isfinite(illumination).all()


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"gain": float("nan")}, "not finite"),
        ({"offset": float("inf")}, "not finite"),
        ({"ncc_window": 1}, "out of range"),
        ({"ncc_window": 257}, "out of range"),
        ({"illumination_window": 5}, "out of range"),  # its half, 2, is no window
        ({"textured_variance": float("nan")}, "not finite"),
    ],
)
def test_bad_rules_are_refused(change: dict[str, float], match: str) -> None:
    current, reference = _pair((30, 40))
    with pytest.raises(ValueError, match=match):
        change_kernels.texture(current, reference, dataclasses.replace(RULES, **change))


def test_bad_images_are_refused() -> None:
    current, reference = _pair((30, 40))
    with pytest.raises(ValueError, match="differ in shape"):
        change_kernels.texture(current, reference[:, 1:], RULES)
    with pytest.raises(ValueError, match="2-D"):
        change_kernels.texture(current[0], reference[0], RULES)
    with pytest.raises(ValueError, match="differ in shape"):
        change_kernels.texture(current, reference, RULES, raised=np.zeros((30, 41), bool))
    with pytest.raises(ValueError, match="out of range"):
        change_kernels.texture(current[:, :0], reference[:, :0], RULES)
    for bad in (np.nan, np.inf, -np.inf):
        spoilt = reference.copy()
        spoilt[29, 39] = bad
        with pytest.raises(ValueError, match="not finite"):
            change_kernels.texture(current, spoilt, RULES)
    with pytest.raises(ValueError, match="threads"):
        change_kernels.texture(current, reference, RULES, threads=-1)
    with pytest.raises(ValueError, match="out of range"):
        change_kernels.box_mean(current, 1)
    with pytest.raises(ValueError, match="out of range"):
        change_kernels.box_mean(current, change_kernels.MAX_WINDOW + 2)


RESIDUAL = change_kernels.ResidualRules(
    gain=0.97, offset=1.5, floor=3.9, contrast_window=11, faint_contrast=10.4, gone_window=9, gone_inside=0.6
)


def test_the_pixel_test_is_the_same_on_one_thread_and_on_all() -> None:
    current, reference = _pair((200, 260))
    _, gone, illumination, _ = change_kernels.texture(current, reference, RULES)
    one = change_kernels.residual(current, reference, RESIDUAL, illumination, gone, threads=1)
    for threads in (0, 2, 3):
        for got, want in zip(
            change_kernels.residual(current, reference, RESIDUAL, illumination, gone, threads), one, strict=True
        ):
            assert np.array_equal(got, want)
    assert one[1].any() and not one[1].all()


def test_bad_pixel_test_arguments_are_refused() -> None:
    current, reference = _pair((30, 40))
    illumination, gone = np.ones((30, 40), np.float32), np.zeros((30, 40), bool)
    with pytest.raises(ValueError, match="shape"):
        change_kernels.residual(current, reference, RESIDUAL, illumination[:, 1:], gone)
    with pytest.raises(ValueError, match="shape"):
        change_kernels.residual(current, reference[1:], RESIDUAL, illumination, gone)
    spoilt = illumination.copy()
    spoilt[0, 0] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        change_kernels.residual(current, reference, RESIDUAL, spoilt, gone)
    with pytest.raises(ValueError, match="not finite"):
        change_kernels.residual(current, reference, dataclasses.replace(RESIDUAL, floor=np.inf), illumination, gone)
    with pytest.raises(ValueError, match="out of range"):
        change_kernels.residual(current, reference, dataclasses.replace(RESIDUAL, gone_window=0), illumination, gone)
