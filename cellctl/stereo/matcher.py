"""Stereo matching: the paper's Census + Birchfield-Tomasi semi-global matcher.

A thin layer over the C core (`csrc/`, compiled by cffi into `cellctl.stereo._core`),
shaped like OpenCV's StereoSGBM: create a matcher once with its parameters,
then call `compute(left, right)` per pair.  Conventions are OpenCV's: the
images are rectified, left(x, y) matches right(x - d, y), and disparities are
in pixels.  Invalid pixels are NaN, never a placeholder value.

    from cellctl.stereo.matcher import StereoMatcher
    m = StereoMatcher(min_disparity=0, num_disparities=64)
    disp = m.compute(left, right)

The parameters are cellctl.stereo.params. The stage functions at the end (`census_transform`, `cost_volume`, `select`,
`postprocess`) run the same C code the pipeline runs, one stage at a time, for
tests and debugging.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import cv2
import numpy as np

from cellctl.stereo._core import ffi, lib
from cellctl.stereo.params import DEFAULTS, DISP_SCALE, INVALID, MatcherParams, make_params

_ERRORS = {  # what the core's error codes mean, for the messages
    lib.CC_ERR_NULL: "a required buffer is missing",
    lib.CC_ERR_SIZE: "the image size or row stride is out of range",
    lib.CC_ERR_NOMEM: "not enough memory for the cost volume",
}


@dataclass(frozen=True)
class StereoResult:
    """All stages of one match, as float32 disparities in px with NaN where invalid."""

    disparity: np.ndarray  # final map (after fill and median)
    valid: np.ndarray  # bool: measured, i.e. passed the left-right check (not filled)
    raw_left: np.ndarray  # winner-takes-all of the left view, sub-pixel
    raw_right: np.ndarray  # winner-takes-all of the right view, integer
    checked: np.ndarray  # raw_left after the left-right check
    filled: np.ndarray  # after the fill, before the medians


def to_float(fixed: np.ndarray) -> np.ndarray:
    """int16 fixed-point disparities (x16, INVALID) to float32 px with NaN (in C: numpy's masked
    assignment alone took 0.4 ms of a 450x375 match)."""
    if fixed.dtype != np.int16:  # not the core's maps: the plain definition
        out = fixed.astype(np.float32) / DISP_SCALE
        out[fixed == INVALID] = np.nan
        return out
    src = np.ascontiguousarray(fixed)
    out = np.empty(src.shape, np.float32)
    rc = lib.cc_disparity_to_float(
        ffi.cast("const int16_t *", ffi.from_buffer(src)), src.size, ffi.cast("float *", ffi.from_buffer(out))
    )
    if rc != 0:
        raise ValueError(f"disparity conversion failed (error {rc})")
    return out


def as_grey(image: np.ndarray, name: str) -> np.ndarray:
    """A C-contiguous 8-bit grey image from grey or BGR uint8 input, or a clear ValueError."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"{name} image must be a numpy array (got {type(image).__name__})")
    if image.dtype != np.uint8:
        raise ValueError(f"{name} image must be 8-bit (uint8), got {image.dtype}; convert or rescale it first")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    elif image.ndim == 3 and image.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if image.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        image = cv2.cvtColor(image, code)
    elif image.ndim != 2:
        raise ValueError(f"{name} image must be grey (HxW) or BGR (HxWx3), got shape {image.shape}")
    if image.size == 0:
        raise ValueError(f"{name} image is empty (shape {image.shape})")
    return np.ascontiguousarray(image)


def _pair(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    left, right = as_grey(left, "left"), as_grey(right, "right")
    if left.shape != right.shape:
        raise ValueError(f"left and right images differ in size: {left.shape[::-1]} vs {right.shape[::-1]} (w x h)")
    return left, right


def as_guide(image: np.ndarray, name: str = "guide") -> np.ndarray:
    """The colour image the weighted medians compare pixels in: C-contiguous BGR, or grey for grey input.

    Matching itself uses grey (the paper's cost); colour only decides which neighbours
    belong to the same surface when disparities are filled and filtered.
    """
    if isinstance(image, np.ndarray) and image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] in (3, 4):
        return np.ascontiguousarray(image[:, :, :3])
    return as_grey(image, name)


def _u8(a: np.ndarray) -> Any:
    return ffi.cast("const uint8_t *", ffi.from_buffer(a))


def _check(rc: int, params: MatcherParams, shape: tuple[int, int]) -> None:
    if rc == 0:
        return
    h, w = shape
    if rc == lib.CC_ERR_RANGE:
        lo, hi = params.min_disparity, params.min_disparity + params.num_disparities - 1
        raise ValueError(
            f"disparity range {lo}..{hi} does not fit an image {w} px wide; lower num_disparities or min_disparity"
        )
    if rc == lib.CC_ERR_NOMEM:
        cells = w * h * (-(-params.num_disparities // 16) * 16)
        raise MemoryError(
            f"not enough memory for a {w}x{h}x{params.num_disparities} match "
            f"(needs about {2 * cells / 2**20:.0f} MiB); reduce the image or the range"
        )
    if rc == lib.CC_ERR_PARAM:
        params.to_c()
    raise ValueError(f"matching core error {rc}: {_ERRORS.get(rc, 'unknown')} (image {w}x{h})")


class StereoMatcher:
    """Census+BT semi-global matcher; the buffers are kept between pairs of one size."""

    def __init__(self, min_disparity: int = 0, num_disparities: int = 64, **params: Any) -> None:
        self.params = make_params(min_disparity=min_disparity, num_disparities=num_disparities, **params)
        handle = ffi.new("cc_matcher **")
        rc = lib.cc_matcher_create(self.params.to_c(), handle)
        if rc != 0:
            raise MemoryError("could not create the stereo matcher")
        self._handle = ffi.gc(handle[0], lib.cc_matcher_destroy)

    def __repr__(self) -> str:
        changed = {
            f.name: getattr(self.params, f.name)
            for f in fields(self.params)
            if getattr(self.params, f.name) != DEFAULTS[f.name]
        }
        return f"StereoMatcher({', '.join(f'{k}={v!r}' for k, v in changed.items())})"

    @property
    def buffer_bytes(self) -> int:
        """Bytes held by the core's buffers (cost volume and working rows)."""
        return int(lib.cc_matcher_bytes(self._handle))

    @property
    def uses_avx2(self) -> bool:
        return bool(lib.cc_matcher_simd(self._handle))

    def compute(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Final left-view disparity, float32 HxW in px, NaN where invalid."""
        return to_float(self.compute_fixed(left, right))

    def compute_fixed(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Final disparity as OpenCV-style int16 fixed point (x16), INVALID where invalid."""
        guide = as_guide(left, "left")
        left, right = _pair(left, right)
        disp = np.empty(left.shape, np.int16)
        self._run(left, right, guide, disp)
        return disp

    def compute_detailed(self, left: np.ndarray, right: np.ndarray) -> StereoResult:
        """Every stage of the pipeline for one pair (debugging and evaluation)."""
        guide = as_guide(left, "left")
        left, right = _pair(left, right)
        maps = np.empty((5,) + left.shape, np.int16)
        self._run(left, right, guide, *maps)
        disp, raw_left, raw_right, checked, filled = (to_float(m) for m in maps)
        valid = (maps[3] != INVALID) & (maps[0] != INVALID)
        return StereoResult(disp, valid, raw_left, raw_right, checked, filled)

    def aggregate(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """The aggregated cost S, uint16 [height, width, num_disparities]."""
        left, right = _pair(left, right)
        h, w = left.shape
        out = np.empty((h, w, self.params.num_disparities), np.uint16)
        rc = lib.cc_aggregate(
            self._handle, _u8(left), _u8(right), w, h, w, w, ffi.cast("uint16_t *", ffi.from_buffer(out))
        )
        _check(rc, self.params, left.shape)
        return out

    def _run(
        self, left: np.ndarray, right: np.ndarray, guide: np.ndarray, disp: np.ndarray, *stages: np.ndarray
    ) -> None:
        h, w = left.shape
        ptrs = [ffi.cast("int16_t *", ffi.from_buffer(a)) for a in (disp, *stages)]
        ptrs += [ffi.NULL] * (5 - len(ptrs))
        channels = 1 if guide.ndim == 2 else 3
        rc = lib.cc_matcher_compute(
            self._handle, _u8(left), _u8(right), w, h, w, w, _u8(guide), channels, w * channels, *ptrs
        )
        _check(rc, self.params, left.shape)


# ---- Stage functions: one step of the pipeline each, same C code. ----


def census_transform(image: np.ndarray, window: tuple[int, int] = (5, 5)) -> np.ndarray:
    """Census bit strings (uint64 per pixel) of an 8-bit image, borders replicated."""
    img = as_grey(image, "input")
    h, w = img.shape
    out = np.empty((h, w), np.uint64)
    rc = lib.cc_census(_u8(img), w, h, w, window[0], window[1], ffi.cast("uint64_t *", ffi.from_buffer(out)))
    if rc == lib.CC_ERR_PARAM:
        raise ValueError(f"census window must be odd, at most 9x7 (got {window})")
    if rc != 0:
        raise ValueError(f"census transform failed (error {rc}) for image {w}x{h}")
    return out


def cost_volume(left: np.ndarray, right: np.ndarray, **params: Any) -> np.ndarray:
    """Fused matching cost, uint8 [height, width, num_disparities]."""
    p = make_params(**params)
    left, right = _pair(left, right)
    h, w = left.shape
    out = np.empty((h, w, p.num_disparities), np.uint8)
    rc = lib.cc_cost_volume(p.to_c(), _u8(left), _u8(right), w, h, w, w, ffi.cast("uint8_t *", ffi.from_buffer(out)))
    _check(rc, p, left.shape)
    return out


def select(volume: np.ndarray, **params: Any) -> tuple[np.ndarray, np.ndarray]:
    """Winner-takes-all of an aggregated volume: (left, right) int16 fixed-point maps."""
    p = make_params(num_disparities=volume.shape[2], **params)
    vol = np.ascontiguousarray(volume, dtype=np.uint16)
    h, w, _ = vol.shape
    left, right = np.empty((h, w), np.int16), np.empty((h, w), np.int16)
    rc = lib.cc_select(
        p.to_c(),
        ffi.cast("const uint16_t *", ffi.from_buffer(vol)),
        w,
        h,
        ffi.cast("int16_t *", ffi.from_buffer(left)),
        ffi.cast("int16_t *", ffi.from_buffer(right)),
    )
    _check(rc, p, (h, w))
    return left, right


def postprocess(
    raw_left: np.ndarray, raw_right: np.ndarray, guide: np.ndarray, **params: Any
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Left-right check, fills and medians on int16 fixed-point maps: (checked, filled, final).

    `guide` is the left image (grey or BGR) the weighted stages compare colours in.
    """
    p = make_params(**params)
    rl = np.ascontiguousarray(raw_left, dtype=np.int16)
    rr = np.ascontiguousarray(raw_right, dtype=np.int16)
    if rl.shape != rr.shape or rl.ndim != 2:
        raise ValueError(f"raw maps must be two 2-D arrays of one shape (got {rl.shape} and {rr.shape})")
    g = as_guide(guide)
    if g.shape[:2] != rl.shape:
        raise ValueError(
            f"guide image is {g.shape[1]}x{g.shape[0]} but the maps are {rl.shape[1]}x{rl.shape[0]} (w x h)"
        )
    h, w = rl.shape
    channels = 1 if g.ndim == 2 else 3
    out = [np.empty((h, w), np.int16) for _ in range(3)]
    ptr = lambda a: ffi.cast("int16_t *", ffi.from_buffer(a))  # noqa: E731
    rc = lib.cc_postprocess(p.to_c(), ptr(rl), ptr(rr), _u8(g), channels, w * channels, w, h, *(ptr(a) for a in out))
    _check(rc, p, (h, w))
    return out[0], out[1], out[2]
