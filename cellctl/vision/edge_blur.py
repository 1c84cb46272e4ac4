"""How soft the cameras' images are at the sole's edge: a lens out of focus, or softer than the simulator's.

Blur spreads the band where the sole's edge mixes with what lies beyond it (the table, or the wall one camera
sees). The glue path runs 2 mm inside the edge and its patch fits (cellctl.vision.surface) reach 4 mm round
it, so that band lies inside their patches; its pixels match neither the top nor the table. On sharp images
the mask the fits use (`sole_region.sole_mask`) drops the one edge pixel that mixes; on soft ones the mixed
band is 2-3 pixels wide, and the glue path's own heights ran 0.7-1.7 mm off over 20-40 mm stretches while the
heights 6 mm further in were right (the soft-focus variation; docs/sole-benchmark.md, twenty-ninth round).

The reading: along the sole's edge (a band round the sole's mask), at the pixels of strongest gradient, the
gradient after a further Gaussian blur of REBLUR_PX over the gradient before it (the median). A step blurred
by sigma keeps sigma / sqrt(sigma^2 + REBLUR_PX^2) of its peak gradient: the sharper the edge, the more the
further blur takes. Texture and the step's contrast cancel in the ratio. Each camera reads its own image; the
right one's band is the left one's moved by the sole's median disparity.
"""

from __future__ import annotations

import cv2
import numpy as np

REBLUR_PX = 1.0
EDGE_BAND_PX = 6  # either side of the sole mask's border: the edge lies within it where the mask is short or long
STRONGEST_SHARE = 0.1  # the band's pixels of strongest gradient read (the edge itself, not the texture beside it)
# The simulator's cameras (lens blur 0.5 px, the edges supersampled) read 0.65-0.71 on the default rig (70 soles of
# every look of set 32000 but the two below; the highest a glossy tall sole, 0.707) and 0.60-0.65 on the distorted
# one; cameras defocused by 0.3-0.5 px more read 0.71-0.74, by 1.2 px 0.83 (soft-focus set 42000). Edges soft in the
# scene read soft too (rounded top edges 0.76-0.83, sloped walls 0.66-0.73): the wider band left out costs their
# fits pixels, no more. Above this the images are soft at the sole's edge.
SOFT_EDGE_RATIO = 0.71


def edge_blur_ratio(image: np.ndarray, band: np.ndarray) -> float:
    """The median over `band`'s STRONGEST_SHARE of pixels by gradient of the gradient's magnitude after a Gaussian
    blur of REBLUR_PX over before it (a dilation by one pixel lets a peak moved by the blur count); NaN where
    the band is empty or flat. `image` and `band` are the same crop."""
    if not np.any(band):
        return float("nan")
    crop = np.asarray(image, np.float32)
    before, after = _peak_gradient(crop)[band], _peak_gradient(cv2.GaussianBlur(crop, (0, 0), REBLUR_PX))[band]
    strong = (before >= np.quantile(before, 1.0 - STRONGEST_SHARE)) & (before > 0.0)
    if not np.any(strong):
        return float("nan")
    return float(np.median(after[strong] / before[strong]))


def edge_band(mask: np.ndarray) -> np.ndarray:
    """The pixels within EDGE_BAND_PX of `mask`'s border."""
    kernel = np.ones((2 * EDGE_BAND_PX + 1,) * 2, np.uint8)
    m = mask.astype(np.uint8)
    return cv2.dilate(m, kernel) > cv2.erode(m, kernel)


def soft_edges(left: np.ndarray, right: np.ndarray, mask: np.ndarray, disparity_px: float) -> bool:
    """Whether either camera's image is soft at the sole's edge (`edge_blur_ratio` over SOFT_EDGE_RATIO): `mask` the
    sole's pixels in the rectified left image, `disparity_px` the sole's median disparity (the right image shows
    left(x, y) at x - disparity). Read on the crop round the sole only (~10 ms)."""
    x, y, width, height = cv2.boundingRect(mask.astype(np.uint8))
    if width == 0 or height == 0:
        return False
    margin, shift = EDGE_BAND_PX + 4, int(round(disparity_px))
    top, bottom = max(y - margin, 0), min(y + height + margin, mask.shape[0])
    first, last = max(x - margin, shift, 0), min(x + width + margin, mask.shape[1])
    if last <= first:
        return False
    band = edge_band(mask[top:bottom, first:last])
    ratios = (
        edge_blur_ratio(left[top:bottom, first:last], band),
        edge_blur_ratio(right[top:bottom, first - shift : last - shift], band),
    )
    return any(np.isfinite(r) and r > SOFT_EDGE_RATIO for r in ratios)


def _peak_gradient(image: np.ndarray) -> np.ndarray:
    gx = cv2.Sobel(image, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(image, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.dilate(cv2.magnitude(gx, gy), np.ones((3, 3), np.uint8))
