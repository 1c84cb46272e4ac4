"""Change against the taught empty table: which pixels no longer show the table, whatever the sole's colour.

The taught reference image predicts every table pixel (its own texture, vignetting and all) up to the
camera's gain of the moment. A pixel is changed where the current image departs from that prediction by
more than the sensor noise allows. This replaces a colour discriminant between "sole colour" and "table
colour": a sole with a black rim on a dark table, a patterned table, or two-tone soles all differ from the
table's own recorded texture, and the decision is per pixel, so no window moves the edge.
"""

from __future__ import annotations

from concurrent import futures
from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.vision.workers import worker

CHANGE_SIGMAS = 4.0  # gain fit: residuals beyond this many sigmas are not table
PIXEL_SIGMAS = 3.0  # a pixel is changed beyond this many sigmas (0.3 % false flags, removed by the majority)
MIN_TABLE_PIXELS = 2000  # table pixels needed to estimate the gain and the noise
CONTRAST_WINDOW_PX = 11  # local contrast of the change: ~4 mm, narrower than a sole's rim or logo
NCC_WINDOW_PX = 7
TABLE_NCC = 0.5  # table under a shadow correlates with its reference well above this; a covered table near 0
# A shadow or extra light scales the table's own texture: by less than 1 in a shadow, a little above 1 in
# extra light. A sole's edge that happens to run along a step of the table's texture correlates with it just
# as well, but scales it by ten or more: that is not the table.
MAX_TEXTURE_GAIN = 3.0
UNANIMOUS = 0.9  # share of the windows covering a pixel that must agree (a sole pixel at the edge: ~half)
MIN_TEXTURED_SHARE = 0.3  # of the windows covering a pixel: fewer with texture to compare and there is no vote
FAINT_CONTRAST_SIGMAS = 8.0  # a change fainter than this (local contrast) may be found by texture alone
TEXTURE_SIGMAS = 2.0  # the reference has texture where its local spread exceeds this many residual sigmas
NOISE_FLOOR_DN = 0.5  # a quantised 8-bit image never has less residual noise than this


@dataclass(frozen=True)
class ChangeTest:
    """Gain (current / reference) and residual noise of one image against its taught reference."""

    gain: float
    offset: float
    sigma: float  # DN, robust standard deviation of the residual on the table

    @classmethod
    def fit(cls, current: np.ndarray, reference: np.ndarray, table: np.ndarray) -> ChangeTest | None:
        """Fit gain and offset on pixels known to be table (bool mask, or N x 2 integer (x, y) pixels)."""
        if table.ndim == 2 and table.shape[1] == 2 and table.dtype.kind in "iu":
            x, y = table[:, 0], table[:, 1]
            cur, ref = current[y, x].astype(np.float64), reference[y, x].astype(np.float64)
        else:
            cur, ref = current[table].astype(np.float64), reference[table].astype(np.float64)
        if cur.size < MIN_TABLE_PIXELS:
            return None
        # Least squares, then once more without the pixels the first fit calls changed (a missed object).
        keep = np.ones(cur.size, bool)
        gain, offset, sigma = 1.0, 0.0, 1.0
        for _ in range(3):
            design = np.column_stack([ref[keep], np.ones(int(keep.sum()))])
            (gain, offset), *_ = np.linalg.lstsq(design, cur[keep], rcond=None)
            residual = cur - (gain * ref + offset)
            sigma = max(1.4826 * float(np.median(np.abs(residual[keep]))), NOISE_FLOOR_DN)
            keep = np.abs(residual) < CHANGE_SIGMAS * sigma
        return cls(float(gain), float(offset), sigma)

    def residual(self, current: np.ndarray, reference: np.ndarray) -> np.ndarray:
        # In place on one buffer, no copies of float32 inputs: the same float32 operations in the same order.
        predicted = np.multiply(np.asarray(reference, np.float32), self.gain)
        predicted += self.offset
        return np.subtract(np.asarray(current, np.float32), predicted, out=predicted)

    def changed(self, current: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """Bool image: pixels that no longer show the taught table.

        A pixel is changed when its residual exceeds half the local contrast of the change around it (the
        mean residual of the clearly changed pixels within CONTRAST_WINDOW_PX), and at least PIXEL_SIGMAS
        of noise. Half the local contrast is where a pixel half covered by the sole lies, so the edge sits
        on the sole's edge for a white sole as for a black rim on a dark table; a global threshold would put
        it a pixel out on strong contrast and cut a weakly contrasting rim off. A 3 x 3 majority (median)
        then removes isolated flags and misses; a straight edge stays where it is.
        """
        # The texture votes on a worker thread beside the contrast (numpy and OpenCV release the GIL): the
        # same arrays either way, in about half the time where a core is free.
        texture = worker("change-texture").submit(self._texture, current, reference)
        try:
            magnitude = np.abs(self.residual(current, reference))
            floor = PIXEL_SIGMAS * self.sigma
            clear = (magnitude > floor).astype(np.float32)
            window = (CONTRAST_WINDOW_PX, CONTRAST_WINDOW_PX)
            contrast = cv2.blur(magnitude * clear, window)
            contrast /= np.maximum(cv2.blur(clear, window), 1e-6)
            half_contrast = np.multiply(contrast, 0.5, out=clear)
            raw = magnitude > np.maximum(floor, half_contrast, out=half_contrast)
            faint = contrast < FAINT_CONTRAST_SIGMAS * self.sigma
        finally:
            futures.wait([texture])
        still_table, texture_gone = texture.result()
        # Next to a strong step every window covering a table pixel also covers the step and correlates
        # poorly: the texture vote would move the edge out. It only speaks where the change is faint.
        texture_gone &= faint
        raw |= texture_gone
        mask = np.greater(raw, still_table).view(np.uint8)  # (raw or texture gone) and not still table
        return cv2.medianBlur(mask, 3) > 0

    def _texture(self, current: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(still table, texture gone): the table's own texture is still there, only darker or lighter (a
        shadow), or it is gone (covered by something of whatever brightness).

        Normalised cross-correlation with the reference over NCC_WINDOW_PX windows is blind to a change of
        brightness; a window only counts as table if its texture is also scaled by a shadow's or a lamp's
        factor (below MAX_TEXTURE_GAIN), not by the tenfold of a sole's edge lying along a step of the table's. Still table: nearly all the textured windows covering the pixel correlate, so a sole
        pixel next to the table, about half of whose windows lie further inside, is not vetoed. Texture
        gone: nearly none correlates, which finds a sole of the table's own brightness but does not reach
        past its edge. Only windows where the reference has texture to compare vote.
        """
        # The same float32 operations in the same order as the plain formulas in the comments, in place on
        # few buffers and without copies of float32 inputs (a quarter of the time went to allocation).
        window = (NCC_WINDOW_PX, NCC_WINDOW_PX)
        cur, ref = np.asarray(current, np.float32), np.asarray(reference, np.float32)
        mean_c, mean_r = cv2.blur(cur, window), cv2.blur(ref, window)
        scratch = np.multiply(cur, cur)
        var_c = cv2.blur(scratch, window)  # blur(cur * cur) - mean_c * mean_c
        var_c -= np.multiply(mean_c, mean_c, out=scratch)
        var_r = cv2.blur(np.multiply(ref, ref, out=scratch), window)  # blur(ref * ref) - mean_r * mean_r
        var_r -= np.multiply(mean_r, mean_r, out=scratch)
        covariance = cv2.blur(np.multiply(cur, ref, out=scratch), window)  # blur(cur * ref) - mean_c * mean_r
        covariance -= np.multiply(mean_c, mean_r, out=mean_c)
        # ncc = covariance / sqrt(max(var_c * var_r, 1e-6))
        ncc = np.multiply(var_c, var_r, out=var_c)
        np.sqrt(np.maximum(ncc, 1e-6, out=ncc), out=ncc)
        np.divide(covariance, ncc, out=ncc)
        # texture_gain = covariance / max(var_r, 1e-6) / max(gain, 1e-6)
        texture_gain = np.divide(covariance, np.maximum(var_r, 1e-6, out=mean_r), out=mean_r)
        texture_gain /= max(self.gain, 1e-6)
        textured = var_r > (TEXTURE_SIGMAS * self.sigma) ** 2
        # Votes of the textured windows covering each pixel: nearly all correlate, or nearly none does.
        share = cv2.blur(textured.astype(np.float32), window)
        table_like = np.greater(ncc, TABLE_NCC)
        table_like &= texture_gain < MAX_TEXTURE_GAIN
        table_like &= textured
        agree = cv2.blur(table_like.astype(np.float32), window)
        enough = share > MIN_TEXTURED_SHARE
        still = agree > np.multiply(share, UNANIMOUS, out=scratch)
        still &= enough
        gone = agree < np.multiply(share, 1.0 - UNANIMOUS, out=scratch)
        gone &= enough
        return still, gone
