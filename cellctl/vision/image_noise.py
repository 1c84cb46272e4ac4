"""The sensor noise of an image, read from the image itself: what gates a measurement and names a noisy camera."""

from __future__ import annotations

import numpy as np

from cellctl.images import grey

# Noise of the rectified left grey image (DN of 8 bits, `image_noise_dn`) above which the surface is not
# measured to the cell's tolerances. Simulated sensors: 1 DN read noise reads 0.5-0.75 here (rectification
# and the grey conversion average some of it), and the measurement holds its tolerances; 6 DN read noise
# reads 2.2, and heights came out 1.1-1.3 mm off and glue points 1.9 mm off their offset, every other
# self-check passing.
MAX_IMAGE_NOISE_DN = 1.5
# A clean camera's rectified image reads under this (the simulator's normal sensor: 0.5-0.75 DN): above it, noise
# is a likely cause of stray or missing depth, and the messages say so.
CLEAN_IMAGE_NOISE_DN = 0.8
# What to do about a noisy image in the cell: a cycle measures on the mean of its exposures when one is too noisy.
NOISY_IMAGE_REMEDY = (
    "check exposure, gain and lighting, or average more exposures per cycle ([cameras] averaged_frames)"
)


def image_noise_dn(grey: np.ndarray) -> float:
    """Robust sensor noise (DN) of an image: the median absolute response of a 3 x 3 second-difference
    kernel that cancels planar brightness (Immerkaer's estimator, with a median so that the few edges and
    texture lines of a scene do not count). The kernel spans every 2nd row (rectification's interpolation
    correlates neighbouring rows and hides part of the noise from adjacent ones) and is evaluated at every
    2nd of its rows and columns (an eighth of the pixels: a few ms)."""
    g = np.asarray(np.asarray(grey)[::2], np.float32)
    height, width = g.shape

    def at(dy: int, dx: int) -> np.ndarray:
        return g[1 + dy : height - 1 + dy : 2, 1 + dx : width - 1 + dx : 2]

    # 4 a - 2 (b + c + d + e) + (f + g + h + i), the same float32 operations in the same order, in place.
    cross = np.add(at(-1, 0), at(1, 0))
    cross += at(0, -1)
    cross += at(0, 1)
    cross *= 2.0
    response = np.multiply(at(0, 0), 4.0)
    response -= cross
    corners = np.add(at(-1, -1), at(-1, 1), out=cross)
    corners += at(1, -1)
    corners += at(1, 1)
    response += corners
    return float(np.median(np.abs(response, out=response))) / 0.6745 / 6.0


# The noise averaging removed from the last exposure (`exposure_noise_dn`) above which the cycle measures on the mean of
# its exposures. The simulated sensors at four exposures, over the 336 scenes of four matrix sets: clean (read 1 DN,
# shot 0.02 DN/DN) 0.70-1.16, the brighter the scene the higher (shot noise); heavy noise 3.8-4.3. At 1.75 one
# exposure's noise is ~2 DN (four exposures), 1.5-2.5 times a clean camera's, and the mean's ~1 DN, a clean camera's
# single exposure, on which the change test's and the outline's thresholds were set; below it the last exposure is
# measured, as every earlier round did (docs/sole-benchmark.md, twenty-eighth round).
NOISY_EXPOSURES_DN = 1.75
# One clean exposure's noise on the same scale: what a mean of four exposures holds at the limit above. A mean
# noisier than this is as noisy as a clean camera's single exposure (`mean_noise_dn`).
CLEAN_EXPOSURE_NOISE_DN = NOISY_EXPOSURES_DN / float(np.sqrt(3.0))
# Raw rows the exposures' difference is read on (`exposure_noise_dn`): every 2nd row and column of a band across the
# middle of the view, where the table and usually the sole lie; ~40000 pixels, ~1-2 ms.
EXPOSURE_NOISE_ROWS = 128


def exposure_noise_dn(last: np.ndarray, mean: np.ndarray) -> float:
    """The noise the mean of a cycle's exposures removed from its last one (DN of the raw grey image, read without
    rounding): the robust spread of (last - mean) over a band of rows.

    Unlike `image_noise_dn`, the scene's texture cancels exactly (a still view differs between exposures by the
    sensor alone), so a patterned table does not read as noise, and the differences are not whole grey levels.
    For a mean of n exposures that includes the last, the spread is sigma sqrt(1 - 1/n) of one exposure's sigma
    (0.87 sigma at four, 0.71 at two; 0 for a single one): it grows with what averaging gains."""
    if np.shape(last) != np.shape(mean):
        raise ValueError(f"the last exposure ({np.shape(last)}) and the mean ({np.shape(mean)}) differ in size")
    height = np.shape(last)[0]
    top = max((height - EXPOSURE_NOISE_ROWS) // 2, 0)
    rows = slice(top, top + EXPOSURE_NOISE_ROWS, 2)
    difference = grey(np.asarray(last)[rows, ::2].astype(np.float32)) - grey(
        np.asarray(mean)[rows, ::2].astype(np.float32)
    )
    centre = float(np.median(difference))  # a lamp's flicker brightens or darkens the whole exposure a little
    return 1.4826 * float(np.median(np.abs(difference - centre)))


def mean_noise_dn(exposure_noise: float, count: int) -> float:
    """The noise of the mean of `count` exposures (count >= 2), from what averaging removed from the last of them
    (`exposure_noise_dn`, sigma sqrt(1 - 1/n)): sigma / sqrt(n) = exposure_noise / sqrt(n - 1)."""
    if count < 2:
        raise ValueError(f"a mean of {count} exposure(s) removes no noise to read")
    return exposure_noise / float(np.sqrt(count - 1))
