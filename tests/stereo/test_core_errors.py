"""The C entry points themselves refuse bad arguments with an error code.

The Python layer checks its input first, so these call the core directly
through cffi, as another host program would: NULL pointers, impossible sizes
and strides, invalid parameters.  Run under AddressSanitizer by `make asan`,
they also show that nothing is read or written out of bounds on the way.
"""

from __future__ import annotations

import numpy as np
import pytest
from cellctl.stereo._core import ffi, lib

W, H = 24, 10


def _params(**fields):
    p = ffi.new("cc_params *")
    lib.cc_params_default(p)
    p.num_disparities = 8
    for name, value in fields.items():
        setattr(p, name, value)
    return p


def _u8(a):
    return ffi.cast("uint8_t *", ffi.from_buffer(a))


def _i16(a):
    return ffi.cast("int16_t *", ffi.from_buffer(a))


@pytest.fixture()
def matcher():
    handle = ffi.new("cc_matcher **")
    assert lib.cc_matcher_create(_params(), handle) == lib.CC_OK
    yield handle[0]
    lib.cc_matcher_destroy(handle[0])


IMG = np.zeros((H, W), np.uint8)
OUT = np.zeros((H, W), np.int16)


def test_create_refuses_null_and_bad_parameters():
    handle = ffi.new("cc_matcher **")
    assert lib.cc_matcher_create(ffi.NULL, handle) == lib.CC_ERR_NULL
    assert lib.cc_matcher_create(_params(), ffi.NULL) == lib.CC_ERR_NULL
    assert lib.cc_matcher_create(_params(p1=50, p2=40), handle) == lib.CC_ERR_PARAM
    assert handle[0] == ffi.NULL
    lib.cc_matcher_destroy(ffi.NULL)  # harmless
    assert lib.cc_matcher_bytes(ffi.NULL) == 0


@pytest.mark.parametrize(
    "field,value",
    [
        ("num_disparities", 0),
        ("num_disparities", 5000),
        ("census_width", 4),
        ("census_height", 9),
        ("cost_mode", 7),
        ("lambda_census", float("nan")),
        ("lambda_bt", 0.0),
        ("cost_scale", 200),
        ("p1", -1),
        ("paths", 5),
        ("median", 7),
        ("fill_mode", 9),
        ("threads", -2),
        ("simd", 3),
    ],
)
def test_params_check_names_each_problem(field, value):
    message = ffi.new("const char **")
    assert lib.cc_params_check(_params(**{field: value}), message) == lib.CC_ERR_PARAM
    assert ffi.string(message[0]).decode()  # a message for the user, never empty


def test_compute_refuses_null_pointers(matcher):
    args = dict(left=_u8(IMG), right=_u8(IMG), disp=_i16(OUT))
    for missing in args:
        a = {**args, missing: ffi.NULL}
        rc = lib.cc_matcher_compute(
            matcher,
            a["left"],
            a["right"],
            W,
            H,
            W,
            W,
            ffi.NULL,
            1,
            W,
            a["disp"],
            ffi.NULL,
            ffi.NULL,
            ffi.NULL,
            ffi.NULL,
        )
        assert rc == lib.CC_ERR_NULL, missing
    assert (
        lib.cc_matcher_compute(
            ffi.NULL, _u8(IMG), _u8(IMG), W, H, W, W, ffi.NULL, 1, W, _i16(OUT), ffi.NULL, ffi.NULL, ffi.NULL, ffi.NULL
        )
        == lib.CC_ERR_NULL
    )


@pytest.mark.parametrize(
    "w,h,sl,sr,expected",
    [
        (0, H, W, W, "CC_ERR_SIZE"),
        (W, 0, W, W, "CC_ERR_SIZE"),
        (-3, H, W, W, "CC_ERR_SIZE"),
        (W, H, W - 1, W, "CC_ERR_SIZE"),
        (W, H, W, 2, "CC_ERR_SIZE"),
        (20000, 1, 20000, 20000, "CC_ERR_SIZE"),
        (6, H, W, W, "CC_ERR_RANGE"),  # 8 disparities in an image 6 px wide
    ],
)
def test_compute_refuses_impossible_sizes(matcher, w, h, sl, sr, expected):
    rc = lib.cc_matcher_compute(
        matcher, _u8(IMG), _u8(IMG), w, h, sl, sr, ffi.NULL, 1, W, _i16(OUT), ffi.NULL, ffi.NULL, ffi.NULL, ffi.NULL
    )
    assert rc == getattr(lib, expected)


def test_guide_with_bad_channels_or_stride_is_refused(matcher):
    guide = np.zeros((H, W, 3), np.uint8)
    call = lambda ch, stride: lib.cc_matcher_compute(  # noqa: E731
        matcher,
        _u8(IMG),
        _u8(IMG),
        W,
        H,
        W,
        W,
        _u8(guide),
        ch,
        stride,
        _i16(OUT),
        ffi.NULL,
        ffi.NULL,
        ffi.NULL,
        ffi.NULL,
    )
    assert call(2, 3 * W) == lib.CC_ERR_PARAM
    assert call(3, 3 * W - 1) == lib.CC_ERR_SIZE
    assert call(3, 3 * W) == lib.CC_OK


def test_stage_entry_points_refuse_bad_arguments():
    out64 = np.zeros((H, W), np.uint64)
    p64 = ffi.cast("uint64_t *", ffi.from_buffer(out64))
    assert lib.cc_census(ffi.NULL, W, H, W, 5, 5, p64) == lib.CC_ERR_NULL
    assert lib.cc_census(_u8(IMG), W, H, W - 1, 5, 5, p64) == lib.CC_ERR_SIZE
    assert lib.cc_census(_u8(IMG), W, H, W, 6, 5, p64) == lib.CC_ERR_PARAM
    vol = np.zeros((H, W, 8), np.uint8)
    assert lib.cc_cost_volume(_params(), _u8(IMG), _u8(IMG), W, H, W, W, ffi.NULL) == lib.CC_ERR_NULL
    assert lib.cc_cost_volume(_params(p2=0), _u8(IMG), _u8(IMG), W, H, W, W, _u8(vol)) == lib.CC_ERR_PARAM
    agg = np.zeros((H, W, 8), np.uint16)
    pagg = ffi.cast("uint16_t *", ffi.from_buffer(agg))
    assert lib.cc_select(_params(), pagg, 0, H, _i16(OUT), _i16(OUT)) == lib.CC_ERR_SIZE
    assert lib.cc_select(_params(), ffi.NULL, W, H, _i16(OUT), _i16(OUT)) == lib.CC_ERR_NULL
    maps = [np.zeros((H, W), np.int16) for _ in range(3)]
    assert (
        lib.cc_postprocess(_params(), _i16(OUT), _i16(OUT), ffi.NULL, 1, W, W, H, *(_i16(m) for m in maps)) != lib.CC_OK
    )  # the weighted stages need a guide
    assert (
        lib.cc_postprocess(_params(), _i16(OUT), ffi.NULL, _u8(IMG), 1, W, W, H, *(_i16(m) for m in maps))
        == lib.CC_ERR_NULL
    )


def test_disparity_conversion_refuses_null():
    out = np.zeros(4, np.float32)
    disp = np.zeros(4, np.int16)
    assert lib.cc_disparity_to_float(ffi.NULL, 4, ffi.cast("float *", ffi.from_buffer(out))) == lib.CC_ERR_NULL
    assert lib.cc_disparity_to_float(_i16(disp), 4, ffi.NULL) == lib.CC_ERR_NULL
    assert lib.cc_disparity_to_float(_i16(disp), 0, ffi.cast("float *", ffi.from_buffer(out))) == lib.CC_OK
