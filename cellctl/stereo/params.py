"""The matcher's parameters: one dataclass, the defaults read from the C core (`cc_params_default`), and the
checks a caller's overrides pass before the core validates them itself (`cc_params_check`).

Which fields are converted on the way to C, and which are whole or real numbers, follows from the dataclass:
a new parameter is one field here (and one in csrc/cellctl_core.h), not an entry in several lists.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, get_type_hints

import numpy as np

from cellctl.stereo._core import ffi, lib

DISP_SCALE = lib.CC_DISP_SCALE
INVALID = lib.CC_INVALID

_COSTS = {"census_bt": lib.CC_COST_CENSUS_BT, "census": lib.CC_COST_CENSUS, "bt": lib.CC_COST_BT}
_FILLS = {"none": lib.CC_FILL_NONE, "background": lib.CC_FILL_BACKGROUND, "weighted": lib.CC_FILL_WEIGHTED}
_SIMD = {"auto": lib.CC_SIMD_AUTO, "scalar": lib.CC_SIMD_SCALAR, "avx2": lib.CC_SIMD_AVX2}


@dataclass(frozen=True)
class MatcherParams:
    """Every parameter of the matcher; the defaults are the tuned ones of the C core."""

    min_disparity: int
    num_disparities: int
    census_window: tuple[int, int]  # (width, height), odd, up to 9x7
    census_smooth: int  # 0: census of the pixels, 1: of their 3x3 sums (robust in flat regions)
    census_threshold: int  # 0: binary census; t > 0: ternary, pairs closer than t levels are "similar"
    cost: str  # "census_bt" (the paper), "census" or "bt"
    lambda_census: float  # rho scale of the Hamming distance, bits
    lambda_bt: float  # rho scale of the BT cost, levels of the BT image
    bt_prefilter: int  # BT image: 0 raw grey, 1..63 horizontal Sobel clipped to +-cap (OpenCV's preFilterCap)
    cost_scale: int  # each rho term is quantised to 0..cost_scale
    p1: int  # penalty of a 1 px disparity step
    p2: int  # penalty of larger steps (p2 > p1)
    p2_gamma: int  # 0: constant P2; > 0: P2 lowered across intensity edges
    paths: int  # 4 (the paper) or 8
    subpixel: bool  # parabola refinement
    uniqueness: int  # % margin of the best cost over costs > 1 level away, else invalid; 0 = off
    lr_max_diff: float  # left-right tolerance in px; negative disables the check
    fill: str  # "weighted" (background, then colour-weighted median), "background" or "none"
    median: int  # 0, 3 or 5
    fill_interpolate: int  # fill: runs between valid pixels this close (px) follow a line, 0 = off
    fill_radius: int  # window radius (px) of the weighted fill, 1..15
    border_fit: int  # fill: border-occluded strips follow a line fitted to this many px, 0 = off
    weighted_median: int  # window radius (px) of the final colour-weighted median, 0 = off
    wm_sigma_colour: float  # weighted medians: colour scale, summed |dB| + |dG| + |dR|
    wm_sigma_space: float  # weighted medians: distance scale, px
    threads: int  # 0: all cores
    simd: str  # "auto", "scalar" or "avx2" (the AVX2 kernels even where AVX-512 ones could run)

    def to_c(self) -> Any:
        """The C struct, after the core's own validation (ValueError naming the problem)."""
        p = ffi.new("cc_params *")
        lib.cc_params_default(p)
        for name in _SAME_IN_C:
            setattr(p, name, getattr(self, name))
        p.census_width, p.census_height = self.census_window
        p.cost_mode = _choice("cost", self.cost, _COSTS)
        p.subpixel = int(self.subpixel)
        p.lr_max_diff = -1 if self.lr_max_diff < 0 else round(self.lr_max_diff * DISP_SCALE)
        p.fill_mode = _choice("fill", self.fill, _FILLS)
        p.simd = _choice("simd", self.simd, _SIMD)
        message = ffi.new("const char **")
        if lib.cc_params_check(p, message) != 0:
            raise ValueError(f"invalid matcher parameter: {ffi.string(message[0]).decode()}")
        return p


# Converted on the way to the C struct cc_params (another name, unit or type there); every other field is
# stored under the same name and unit, and is checked by its type here: one list, the dataclass.
_CONVERTED = frozenset({"census_window", "cost", "subpixel", "lr_max_diff", "fill", "simd"})
_TYPES = get_type_hints(MatcherParams)
_SAME_IN_C = tuple(f.name for f in fields(MatcherParams) if f.name not in _CONVERTED)
_INTS = tuple(name for name, kind in _TYPES.items() if kind is int)
_FLOATS = tuple(name for name, kind in _TYPES.items() if kind is float)


def _c_defaults() -> dict[str, Any]:
    p = ffi.new("cc_params *")
    lib.cc_params_default(p)
    costs, fills = {v: k for k, v in _COSTS.items()}, {v: k for k, v in _FILLS.items()}
    return {name: getattr(p, name) for name in _SAME_IN_C} | dict(
        census_window=(p.census_width, p.census_height),
        cost=costs[p.cost_mode],
        subpixel=bool(p.subpixel),
        lr_max_diff=p.lr_max_diff / DISP_SCALE,
        fill=fills[p.fill_mode],
        simd="auto",
    )


DEFAULTS: dict[str, Any] = _c_defaults()


def _choice(name: str, value: str, options: dict[str, int]) -> int:
    if value not in options:
        raise ValueError(f"{name} must be one of {', '.join(options)} (got {value!r})")
    return options[value]


def _as_int(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        if isinstance(value, (float, np.floating)) and math.isfinite(value) and float(value).is_integer():
            return int(value)
        raise ValueError(f"{name} must be a whole number (got {value!r})")
    return int(value)


def _as_float(name: str, value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number (got {value!r})") from None
    if not math.isfinite(out):
        raise ValueError(f"{name} must be a finite number (got {value!r})")
    return out


def make_params(**overrides: Any) -> MatcherParams:
    """MatcherParams from the defaults and keyword overrides, type-checked."""
    unknown = set(overrides) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown matcher parameter(s): {', '.join(sorted(unknown))}")
    v = {**DEFAULTS, **overrides}
    window = v["census_window"]
    if not (isinstance(window, (tuple, list)) and len(window) == 2):
        raise ValueError(f"census_window must be (width, height) (got {window!r})")
    for name in _INTS:
        v[name] = _as_int(name, v[name])
    for name in _FLOATS:
        v[name] = _as_float(name, v[name])
    v["census_window"] = (_as_int("census_window", window[0]), _as_int("census_window", window[1]))
    v["subpixel"] = bool(v["subpixel"])
    params = MatcherParams(**v)
    params.to_c()  # validate now, not at the first pair
    return params
