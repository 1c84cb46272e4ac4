"""The change test's texture vote and pixel test in numpy and OpenCV (main's code before the C kernels): the
reference the kernels (csrc/change_kernels.c, called by ChangeTest._texture and ChangeTest.changed) must equal
bit for bit (their float32 operations, in their order, and cv2.blur's box means). ChangeTest's docstrings give
the rules."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.change import (
    CONTRAST_WINDOW_PX,
    FAINT_CONTRAST_SIGMAS,
    FIT_SIGMAS,
    GONE_INSIDE,
    GONE_WINDOW_PX,
    ILLUMINATION_FAR_WEIGHT,
    ILLUMINATION_NEAR_WEIGHT,
    ILLUMINATION_WINDOW_PX,
    LIFTED_STILL_REACH_PX,
    LIFTED_VOTE_SHARE,
    LOCAL_SHADOW_FIT,
    MAX_CARRIED_FACTOR,
    MAX_SHADOW_FACTOR,
    MAX_TEXTURE_GAIN,
    MIN_LOCAL_FIT_SHARE,
    MIN_TEXTURE_GAIN,
    MIN_TEXTURED_SHARE,
    NCC_WINDOW_PX,
    PIXEL_SIGMAS,
    RAISED_LOCAL_FIT_SHARE,
    RIM_RING,
    SCALE_AGREEMENT,
    STILL_TEXTURE_SIGMAS,
    TABLE_NCC,
    TEXTURE_SIGMAS,
    UNANIMOUS,
    ChangeTest,
    _raised_change,
    _rim_ring,
)


def texture_reference(
    test: ChangeTest, current: np.ndarray, reference: np.ndarray, raised: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(still table, texture gone, illumination, textured share) as ChangeTest._texture defines them."""
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
    # The window's brightness against the taught prediction: a shadow or a lamp scales it as it scales
    # the texture (the fit's vote below needs both), a sole's brightness has nothing to do with it.
    brightness = test.predicted(mean_r)
    np.divide(mean_c, np.maximum(brightness, 1.0, out=brightness), out=brightness)
    covariance = cv2.blur(np.multiply(cur, ref, out=scratch), window)  # blur(cur * ref) - mean_c * mean_r
    covariance -= np.multiply(mean_c, mean_r, out=mean_c)
    # Residual variance of the local fit cur = a ref + b: var_c - covariance^2 / var_r (before var_c is reused).
    unexplained = np.divide(np.multiply(covariance, covariance), np.maximum(var_r, 1e-6))
    np.subtract(var_c, unexplained, out=unexplained)
    # ncc = covariance / sqrt(max(var_c * var_r, 1e-6))
    ncc = np.multiply(var_c, var_r, out=var_c)
    np.sqrt(np.maximum(ncc, 1e-6, out=ncc), out=ncc)
    np.divide(covariance, ncc, out=ncc)
    # texture_gain = covariance / max(var_r, 1e-6) / max(gain, 1e-6)
    texture_gain = np.divide(covariance, np.maximum(var_r, 1e-6), out=mean_r)
    texture_gain /= max(test.gain, 1e-6)
    textured = var_r > (TEXTURE_SIGMAS * test.sigma) ** 2
    # Votes of the textured windows covering each pixel: nearly all correlate, or nearly none does.
    share = cv2.blur(textured.astype(np.float32), window)
    # Nor by less than a shadow's least factor: a sole's own texture correlates with the table's by chance
    # in some windows (NCC above TABLE_NCC in one in ten on the matrix's grey soles), at 0.0-0.3 of its scale.
    in_scale = (texture_gain > MIN_TEXTURE_GAIN) & (texture_gain < MAX_TEXTURE_GAIN)
    table_like = np.greater(ncc, TABLE_NCC)
    table_like &= in_scale
    table_like &= textured
    agree = cv2.blur(table_like.astype(np.float32), window)
    enough = share > MIN_TEXTURED_SHARE
    gone = agree < np.multiply(share, 1.0 - UNANIMOUS, out=scratch)
    gone &= enough
    # Still table: the correlation's vote, or the local fit's (less texture needed, see FIT_SIGMAS).
    still = agree > np.multiply(share, UNANIMOUS, out=scratch)
    still &= enough
    fitted = var_r > (STILL_TEXTURE_SIGMAS * test.sigma) ** 2
    fitted &= unexplained < (FIT_SIGMAS * test.sigma) ** 2
    fitted &= texture_gain > MIN_TEXTURE_GAIN
    fitted &= in_scale
    fitted &= np.abs(texture_gain - brightness) < SCALE_AGREEMENT * brightness
    fitted &= brightness < MAX_SHADOW_FACTOR
    fit_share = cv2.blur(fitted.astype(np.float32), window)
    still |= fit_share > UNANIMOUS
    # The illumination factor over the still table, carried to its neighbours.
    predicted = test.predicted(ref)
    ratio = np.divide(cur, np.maximum(predicted, 1.0), out=predicted)
    # Near still table from a window of half the size (a shadow's own edge stays sharp), farther out
    # from the whole window (the band beside the sole, whose windows do not vote).
    # A shadow's factor or the unshadowed table's (~1) is carried, so the table beside a shadow keeps its
    # own; a stray still pixel on a white sole (ratio ~5) or a black one on the dark table (1.2-1.5) is not.
    plausible = (ratio > MIN_TEXTURE_GAIN) & (ratio < MAX_CARRIED_FACTOR)
    weight = (still & plausible).astype(np.float32)
    weighted = ratio * weight
    illumination = np.ones_like(ratio)
    for size, least in (
        (ILLUMINATION_WINDOW_PX, ILLUMINATION_FAR_WEIGHT),
        (ILLUMINATION_WINDOW_PX // 2, ILLUMINATION_NEAR_WEIGHT),
    ):
        weights = cv2.blur(weight, (size, size))
        near = weights >= least
        illumination[near] = cv2.blur(weighted, (size, size))[near] / weights[near]
    if LOCAL_SHADOW_FIT:
        # Where windows covering the pixel fit the reference at a shadow's factor, that factor (their mean)
        # rather than the one carried from the still table farther away: two lamps' shadows overlap in a
        # darker band beside the sole, too narrow and too weakly textured for the still vote.
        # Only windows whose fit is also a clear correlation (TABLE_NCC) speak here: on a uniform black sole
        # one window in ten fits a shadow's factor by chance, the correlation of a fit that explains the
        # table's texture does not come by chance.
        confident = np.greater(ncc, TABLE_NCC)
        confident &= fitted
        weight_fit = cv2.blur(confident.astype(np.float32), window)
        local = weight_fit >= MIN_LOCAL_FIT_SHARE
        if raised is not None:
            eligible = cv2.blur((var_r > (STILL_TEXTURE_SIGMAS * test.sigma) ** 2).astype(np.float32), window)
            local &= ~raised | (weight_fit >= RAISED_LOCAL_FIT_SHARE * eligible)
        factor = cv2.blur(np.multiply(brightness, confident, dtype=np.float32), window)
        np.divide(factor, weight_fit, out=illumination, where=local)
    return still, gone, illumination, share


def residual_reference(
    test: ChangeTest, current: np.ndarray, reference: np.ndarray, illumination: np.ndarray, texture_gone: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(residual, raw) of ChangeTest.changed's pixel test after the texture vote, in numpy and OpenCV."""
    predicted = test.predicted(reference)
    residual = np.subtract(np.asarray(current, np.float32), predicted)
    predicted *= illumination - 1.0
    residual -= predicted
    magnitude = np.abs(residual)
    floor = PIXEL_SIGMAS * test.sigma
    clear = (magnitude > floor).astype(np.float32)
    window = (CONTRAST_WINDOW_PX, CONTRAST_WINDOW_PX)
    cur = np.asarray(current, np.float32)
    brighter = (residual > floor).astype(np.float32)
    clear_share = cv2.blur(clear, window)
    contrast = cv2.blur(magnitude * clear, window)
    contrast /= np.maximum(clear_share, 1e-6)
    # The change that dominates the window (the sign of its clear residuals' sum), its brightness (the mean
    # current value of its clear pixels of that sign) against this pixel's table as lit now; the local contrast
    # where the pixel's residual has the other sign.
    dominant_brighter = cv2.blur(residual * clear, window) >= 0.0
    brighter_share = cv2.blur(brighter, window)
    brighter_current = cv2.blur(cur * brighter, window)
    clear_current = cv2.blur(cur * clear, window)
    share = np.where(dominant_brighter, brighter_share, clear_share - brighter_share)
    change = np.where(dominant_brighter, brighter_current, clear_current - brighter_current)
    change /= np.maximum(share, np.float32(1e-6))
    change -= cur - residual
    same = np.where(dominant_brighter, residual > 0.0, residual < 0.0)
    half_contrast = np.where(same, np.abs(change), contrast) * np.float32(0.5)
    raw = magnitude > np.maximum(floor, half_contrast)
    faint = contrast < FAINT_CONTRAST_SIGMAS * test.sigma
    inside = cv2.blur(raw.astype(np.float32), (GONE_WINDOW_PX, GONE_WINDOW_PX)) > GONE_INSIDE
    inside &= texture_gone
    gone = texture_gone & faint
    raw |= gone
    raw |= inside
    return residual, raw


def changed_reference(
    test: ChangeTest,
    current: np.ndarray,
    reference: np.ndarray,
    raised: np.ndarray | None = None,
    lifted: np.ndarray | None = None,
) -> np.ndarray:
    """ChangeTest.changed (no box) with the numpy texture vote and pixel test: main's code before the kernels."""
    still_table, texture_gone, illumination, textured_share = texture_reference(test, current, reference, raised)
    residual, raw = residual_reference(test, current, reference, illumination, texture_gone)
    if lifted is not None:
        reach = 2 * LIFTED_STILL_REACH_PX + 1
        near_table = cv2.dilate(
            still_table.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (reach, reach))
        )
        fill = lifted & (near_table == 0) & (textured_share > LIFTED_VOTE_SHARE) & (illumination > MAX_SHADOW_FACTOR)
        fill &= cv2.erode((raw | fill).view(np.uint8), np.ones((3, 3), np.uint8)) > 0
        raw |= fill
    mask = np.greater(raw, still_table).view(np.uint8)
    if raised is not None:
        mask |= _raised_change(raw, residual, PIXEL_SIGMAS * test.sigma, raised, still_table).view(np.uint8)
    changed = cv2.medianBlur(mask, 3) > 0
    if raised is not None and RIM_RING:
        changed |= _rim_ring(changed, residual, PIXEL_SIGMAS * test.sigma, raised, raw, still_table)
    return changed
