"""The change test's per-pixel work in C (csrc/change_kernels.c), behind numpy-level functions.

Behind the stereo package, the one door to the compiled core; cellctl.vision.change calls them with its rules'
constants and keeps the numpy reference in its tests. The results are bit-identical to that numpy and OpenCV
code (csrc/change_kernels.h says how) and to themselves on any number of threads.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from cellctl.stereo._core import ffi, lib
from cellctl.stereo.kernels import ALL_THREADS, _threads

_ERRORS = {
    lib.CHK_ERR_NULL: "a required array is missing",
    lib.CHK_ERR_SIZE: "an image size, stride or window is out of range",
    lib.CHK_ERR_VALUE: "a value is not finite or out of range",
}

MAX_DIM = int(lib.CHK_MAX_DIM)
MAX_WINDOW = int(lib.CHK_MAX_WINDOW)

# Scratch space per thread of the caller, kept between calls: a fresh half-megapixel buffer costs its page faults
# (several ms) at every call.
_SCRATCH = threading.local()


@dataclass(frozen=True)
class TextureRules:
    """The constants of ChangeTest._texture's rules (cellctl.vision.change defines and explains them), with the
    fitted test's gain and offset and its variance thresholds (already squared, in DN^2)."""

    gain: float
    offset: float
    ncc_window: int
    table_ncc: float
    min_texture_gain: float
    max_texture_gain: float
    unanimous: float
    min_textured_share: float
    textured_variance: float
    still_variance: float
    fit_variance: float
    scale_agreement: float
    max_shadow_factor: float
    max_carried_factor: float
    illumination_window: int
    far_weight: float
    near_weight: float
    local_shadow_fit: bool
    min_local_fit_share: float
    raised_local_fit_share: float


def _check(rc: int, what: str) -> None:
    if rc != lib.CHK_OK:
        raise ValueError(f"{what}: {_ERRORS.get(rc, f'error {rc}')}")


def _image(image: np.ndarray, dtype: type, name: str) -> tuple[np.ndarray, int]:
    """The image as the kernel reads it (rows contiguous; a row-strided view is not copied) and its row stride
    in elements."""
    array = np.asarray(image)
    if array.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image, got shape {array.shape}")
    row_bytes = array.shape[1] * array.itemsize
    if (
        array.dtype != dtype
        or array.strides[1] != array.itemsize
        or array.strides[0] % array.itemsize
        or array.strides[0] < row_bytes
    ):
        array = np.ascontiguousarray(array, dtype)
    return array, array.strides[0] // array.itemsize if array.shape[0] > 1 else array.shape[1]


def _pair(current: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, int, np.ndarray, int]:
    """Current and reference as the kernels read them (`_image`), with their row strides; shapes must agree."""
    cur, cur_stride = _image(current, np.float32, "current")
    ref, ref_stride = _image(reference, np.float32, "reference")
    if ref.shape != cur.shape:
        raise ValueError(f"reference {ref.shape} and current {cur.shape} differ in shape")
    return cur, cur_stride, ref, ref_stride


def _kernel_scratch(need: int, height: int, width: int) -> tuple[np.ndarray, int]:
    """`_scratch` for a kernel that checks its own rules: with no size (`need` 0: bad rules or sizes) a dummy
    buffer, so the kernel itself says which argument is wrong (before it reads the scratch space)."""
    return _scratch(need, height, width) if need else (np.empty(1, np.float64), 8)


def _scratch(need: int, height: int, width: int) -> tuple[np.ndarray, int]:
    """A buffer of at least `need` bytes (0: the kernel refused the size), kept for the calling thread."""
    if need == 0:
        raise ValueError(f"image size {height} x {width} or window out of range (1..{MAX_DIM}, 3..{MAX_WINDOW})")
    buffer: np.ndarray | None = getattr(_SCRATCH, "buffer", None)
    if buffer is None or buffer.nbytes < need:
        buffer = np.empty(need // 8 + 1, np.float64)  # 8-byte aligned
        _SCRATCH.buffer = buffer
    return buffer, buffer.nbytes


def _float_ptr(array: np.ndarray):  # noqa: ANN202 - a cffi pointer
    return ffi.cast("float *", ffi.from_buffer(array))


def _view_ptr(kind: str, array: np.ndarray):  # noqa: ANN202 - a cffi pointer
    """A pointer to a row-strided view's first element (ffi.from_buffer takes contiguous buffers only); the
    caller keeps the array alive for the call."""
    return ffi.cast(kind, array.__array_interface__["data"][0])


def texture(
    current: np.ndarray,
    reference: np.ndarray,
    rules: TextureRules,
    raised: np.ndarray | None = None,
    threads: int = ALL_THREADS,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """ChangeTest._texture in C: (still table, texture gone, illumination, textured share) of `current` against
    `reference` (float32 images, finite), `raised` (bool image or None) as the rules define them."""
    cur, cur_stride, ref, ref_stride = _pair(current, reference)
    height, width = cur.shape
    raised_ptr, raised_stride = ffi.NULL, 0
    if raised is not None:
        if np.shape(raised) != cur.shape:
            raise ValueError(f"raised {np.shape(raised)} and current {cur.shape} differ in shape")
        mask, raised_stride = _image(np.asarray(raised, bool).view(np.uint8), np.uint8, "raised")
        raised_ptr = _view_ptr("const uint8_t *", mask)
    params = ffi.new(
        "chk_texture_params *",
        {
            "gain": rules.gain,
            "offset": rules.offset,
            "gain_floor": max(rules.gain, 1e-6),
            "ncc_window": rules.ncc_window,
            "table_ncc": rules.table_ncc,
            "min_texture_gain": rules.min_texture_gain,
            "max_texture_gain": rules.max_texture_gain,
            "unanimous": rules.unanimous,
            "gone_share": 1.0 - rules.unanimous,
            "min_textured_share": rules.min_textured_share,
            "textured_variance": rules.textured_variance,
            "still_variance": rules.still_variance,
            "fit_variance": rules.fit_variance,
            "scale_agreement": rules.scale_agreement,
            "max_shadow_factor": rules.max_shadow_factor,
            "max_carried_factor": rules.max_carried_factor,
            "illumination_window": rules.illumination_window,
            "far_weight": rules.far_weight,
            "near_weight": rules.near_weight,
            "local_shadow_fit": int(rules.local_shadow_fit),
            "min_local_fit_share": rules.min_local_fit_share,
            "raised_local_fit_share": rules.raised_local_fit_share,
        },
    )
    still = np.empty((height, width), np.uint8)
    gone = np.empty((height, width), np.uint8)
    illumination = np.empty((height, width), np.float32)
    share = np.empty((height, width), np.float32)
    need = int(lib.chk_texture_scratch_bytes(height, width, params, _threads(threads)))
    scratch, scratch_bytes = _kernel_scratch(need, height, width)
    rc = lib.chk_texture(
        _view_ptr("const float *", cur),
        cur_stride,
        _view_ptr("const float *", ref),
        ref_stride,
        raised_ptr,
        raised_stride,
        height,
        width,
        params,
        ffi.cast("uint8_t *", ffi.from_buffer(still)),
        ffi.cast("uint8_t *", ffi.from_buffer(gone)),
        _float_ptr(illumination),
        _float_ptr(share),
        ffi.from_buffer(scratch),
        scratch_bytes,
        _threads(threads),
    )
    _check(rc, "change texture")
    return still.view(bool), gone.view(bool), illumination, share


def box_mean(image: np.ndarray, size: int) -> np.ndarray:
    """cv2.blur(image, (size, size)) of a float32 image, bit for bit (size 3..MAX_WINDOW), on one thread."""
    src, stride = _image(image, np.float32, "image")
    height, width = src.shape
    out = np.empty((height, width), np.float32)
    scratch, scratch_bytes = _scratch(int(lib.chk_scratch_bytes(height, width, size, 1)), height, width)
    rc = lib.chk_box_mean(
        _view_ptr("const float *", src),
        stride,
        height,
        width,
        size,
        _float_ptr(out),
        ffi.from_buffer(scratch),
        scratch_bytes,
    )
    _check(rc, "box mean")
    return out


@dataclass(frozen=True)
class ResidualRules:
    """The pixel test's constants (cellctl.vision.change), with the fitted gain and offset and the thresholds in
    DN: floor = PIXEL_SIGMAS sigma, faint_contrast = FAINT_CONTRAST_SIGMAS sigma."""

    gain: float
    offset: float
    floor: float
    contrast_window: int
    faint_contrast: float
    gone_window: int
    gone_inside: float


def residual(
    current: np.ndarray,
    reference: np.ndarray,
    rules: ResidualRules,
    illumination: np.ndarray,
    gone: np.ndarray,
    threads: int = ALL_THREADS,
) -> tuple[np.ndarray, np.ndarray]:
    """ChangeTest.changed's pixel test in C after the texture vote: (residual against the table as lit now,
    float32; raw, bool) from `illumination` and texture `gone` as texture() gives them."""
    cur, cur_stride, ref, ref_stride = _pair(current, reference)
    height, width = cur.shape
    light = np.ascontiguousarray(illumination, np.float32)
    lost = np.ascontiguousarray(np.asarray(gone, bool)).view(np.uint8)
    if light.shape != cur.shape or lost.shape != cur.shape:
        raise ValueError(f"illumination {light.shape} and gone {lost.shape} must have current's shape {cur.shape}")
    params = ffi.new(
        "chk_residual_params *",
        {
            "gain": rules.gain,
            "offset": rules.offset,
            "floor": rules.floor,
            "contrast_window": rules.contrast_window,
            "faint_contrast": rules.faint_contrast,
            "gone_window": rules.gone_window,
            "gone_inside": rules.gone_inside,
        },
    )
    out = np.empty((height, width), np.float32)
    raw = np.empty((height, width), np.uint8)
    need = int(lib.chk_residual_scratch_bytes(height, width, params, _threads(threads)))
    scratch, scratch_bytes = _kernel_scratch(need, height, width)
    rc = lib.chk_residual(
        _view_ptr("const float *", cur),
        cur_stride,
        _view_ptr("const float *", ref),
        ref_stride,
        _float_ptr(light),
        ffi.cast("const uint8_t *", ffi.from_buffer(lost)),
        height,
        width,
        params,
        _float_ptr(out),
        ffi.cast("uint8_t *", ffi.from_buffer(raw)),
        ffi.from_buffer(scratch),
        scratch_bytes,
        _threads(threads),
    )
    _check(rc, "change residual")
    return out, raw.view(bool)
