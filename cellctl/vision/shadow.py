"""Cast shadows beside the sole in a camera's change mask, as the edge-offset check reads it
(cellctl.vision.edge_checks.edge_offset_pair, cellctl.vision.outline_checks; docs/measurements.md, Validity).

A lamp low beside the cell throws the sole's shadow onto the table, and where two lamps' shadows overlap a
darker band lies next to the sole. The change test (cellctl.vision.change) takes most of the shadowed table
for table (its texture at a shadow's factor), but along the boundary between two shadow levels a window sees
two factors and none fits: slivers 1-3 mm beyond the sole stay changed, separated from the sole's own
silhouette by a run of shadowed table the test did accept. The edge-offset check's step fit then puts the
sole's edge past the sliver (1.4-3.4 mm "beyond" an outline truly within 0.8 mm of the edge, on 7 matrix
soles of sets 2000-4000).

Here such samples are told from the sole along each profile the check reads, on evidence of the images
themselves, not of depth (a shadow too dark for the matcher has no depth, and a black edge band dragged to
the table's height by the matcher reads table-level as a shadow does). A changed sample is shadow where
all of these hold (`shadow_cleared`):

- detached: it lies beyond a run of at least DETACHED_GAP_MM of unchanged samples that itself lies beyond
  changed ones (the sole's silhouette is one run from the inside out; a missed pixel inside it is one pixel
  wide);
- the table darkened: its brightness over the taught table's lies within the range the unchanged table on the
  same profile beyond the silhouette shows (up to the sensor noise), below MAX_SHADOW_FACTOR of the camera's
  exposure, and the unchanged run next to the sole is that dark too;
- the table's texture: it and most of the unchanged run correlate with the taught picture along the outline
  (SHADOW_TEXTURE_NCC). A dark rim of the sole whose inner part the change test missed passes the two tests
  above exactly as a shadow does (matrix sole 2042, no shadow: 178 rim pixels without this test, 13 with it).

And the check reads a camera without its shadow samples only where the other camera's own reading finds the
edge within MAX_EDGE_OFFSET_MM of the outline (`one_camera_shadows`): the sole's edge beyond the outline is in
both cameras' silhouettes, a sliver lies where one image's windows failed.

A sole's own edge band is changed from the inside out without such a gap, so an outline short of the edge is
read as before and refused. Not handled: a shadow band the change test left changed right up to the sole's
edge (no gap), which the check still reads as the sole (2059, 3039, 3064).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cellctl.vision.change import MAX_SHADOW_FACTOR, NOISE_FLOOR_DN, PIXEL_SIGMAS
from cellctl.vision.edge_checks import EDGE_SEARCH_MM, EDGE_SEARCH_STEP_MM, MAX_EDGE_OFFSET_MM

# The unchanged run that separates a shadow's sliver from the silhouette: two pixels or more (0.39 mm per pixel
# on the table at the default rig; the change mask's 3 x 3 majority removes a single missed pixel, so a run of
# 0.75 mm of the check's 0.25 mm samples is table the change test accepted, not a hole in the sole's mask).
DETACHED_GAP_MM = 0.75
# The first samples of that run may still blend the sole's edge with the table (a pixel, 0.39 mm, and the lens's
# blur): they say nothing about the table's brightness there.
EDGE_BLEND_MM = 0.5
PHOTOMETRY_STRIDE = 4  # every 4th pixel in each direction for the exposure gain and noise (robust statistics)
# The table's own texture, darkened: per sample, the current image against the reference over the samples at
# the same offset of the outline points within TEXTURE_REACH_POINTS either side (a shadow's band runs along the
# sole's edge: 21 mm of it at one level), each less its line along the outline (the lamps' falloff is shared
# by a sole lit by the same lamps). 21 independent samples correlate by chance with a spread of about
# 1 / sqrt(21 - 3) = 0.24; SHADOW_TEXTURE_NCC is 2.5 of those. The samples 1 mm apart are 2.6 pixels apart, and
# a smooth table texture or a sole's own shading makes neighbours alike, so chance runs higher than that: a
# dark rim read 0.6-0.7 at a few of its samples on one matrix sole (2042); the shadow bands 0.5-0.95.
TEXTURE_REACH_POINTS = 10
SHADOW_TEXTURE_NCC = 0.6


def photometry(current: np.ndarray, reference: np.ndarray, changed: np.ndarray) -> tuple[float, float]:
    """(gain, sigma): the camera's exposure against the taught table (median of current / reference over the
    unchanged pixels) and the residual noise there in DN (robust spread), from a subsample."""
    s = PHOTOMETRY_STRIDE
    cur = np.asarray(current, np.float32)[::s, ::s]
    ref = np.asarray(reference, np.float32)[::s, ::s]
    table = ~changed[::s, ::s] & (ref > 1.0)
    if not np.any(table):
        return 1.0, NOISE_FLOOR_DN
    gain = float(np.median(cur[table] / ref[table]))
    residual = cur[table] - gain * ref[table]
    sigma = max(1.4826 * float(np.median(np.abs(residual - np.median(residual)))), NOISE_FLOOR_DN)
    return gain, sigma


def shadow_cleared(
    changed: np.ndarray,
    current: np.ndarray,
    reference: np.ndarray,
    outline: np.ndarray,
    outward: np.ndarray,
    levels: list[np.ndarray],
    table_to_pixel: Callable[[np.ndarray], np.ndarray],
) -> np.ndarray:
    """A copy of one camera's change mask with the shadow samples (module docstring) cleared, on the profiles
    the edge-offset check reads: along each outline point's outward normal, EDGE_SEARCH_MM either side at
    EDGE_SEARCH_STEP_MM, projected at each of `levels` (per outline point: heights in mm above the table)."""
    cleared = changed.copy()
    gain, sigma = photometry(current, reference, changed)
    steps = np.arange(-EDGE_SEARCH_MM, EDGE_SEARCH_MM + 1e-9, EDGE_SEARCH_STEP_MM)
    n, k = len(outline), len(steps)
    gap = max(int(round(DETACHED_GAP_MM / EDGE_SEARCH_STEP_MM)), 2)
    blend = int(round(EDGE_BLEND_MM / EDGE_SEARCH_STEP_MM))
    xy = outline[:, None, :] + steps[None, :, None] * outward[:, None, :]
    height, width = changed.shape
    cur_img, ref_img = np.asarray(current, np.float32), np.asarray(reference, np.float32)
    for level in levels:
        points = np.concatenate([xy.reshape(-1, 2), np.repeat(level, k)[:, None]], axis=1)
        px = np.round(table_to_pixel(points)).astype(np.int64)
        ok = (px[:, 0] >= 0) & (px[:, 0] < width) & (px[:, 1] >= 0) & (px[:, 1] < height)
        col, row = np.where(ok, px[:, 0], 0), np.where(ok, px[:, 1], 0)
        known = ok.reshape(n, k)
        on = changed[row, col].reshape(n, k) & known
        off = ~changed[row, col].reshape(n, k) & known
        ref = np.maximum(ref_img[row, col], 1.0).reshape(n, k)
        ratio = cur_img[row, col].reshape(n, k) / ref
        margin = PIXEL_SIGMAS * sigma / ref  # the sensor noise as a spread of the ratio
        shadowed = (ratio < MAX_SHADOW_FACTOR * gain) & known
        band = _detached(on, off, gap)  # changed samples beyond a gap, and the gap (n x k each)
        if band is None:
            continue
        beyond, gap_run = band
        # The unchanged table on the profile beyond the silhouette (the gap, less the samples that may blend
        # with the sole's edge, EDGE_BLEND_MM; and the table past the band): its brightness range, noise
        # included.
        settled = gap_run & (np.cumsum(gap_run, axis=1) > blend)  # the gap less its first samples
        table = settled | (off & beyond)
        inf = np.float32(np.inf)
        low = np.min(np.where(table, ratio - margin, inf), axis=1)
        high = np.max(np.where(table, ratio + margin, -inf), axis=1)
        dark_gap = ~np.any(settled & ~shadowed, axis=1)  # the table next to the sole is in shadow
        like_table = (ratio >= low[:, None]) & (ratio <= high[:, None]) & shadowed & dark_gap[:, None]
        clear = on & beyond & like_table
        if not np.any(clear):
            continue
        # The table's texture in the band and in the gap (a rim of the sole the change test missed in part is
        # as dark beside its changed part as a shadow, but it has no table texture).
        textured = _along_outline_ncc(cur_img[row, col].reshape(n, k), ref, known) > SHADOW_TEXTURE_NCC
        gap_textured = 2 * np.sum(settled & textured, axis=1) > np.sum(settled, axis=1)
        clear &= textured & gap_textured[:, None]
        flat = clear.ravel()
        cleared[row[flat], col[flat]] = False
    return cleared


def _detached(on: np.ndarray, off: np.ndarray, gap: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Per profile (rows, inside to outside): (beyond, gap_run), the samples past the first run of at least
    `gap` unchanged samples that follows a changed one, and that run itself; None where no profile has one."""
    n, k = on.shape
    if k <= gap:
        return None
    # A run of `gap` unchanged samples ending at j, with a changed sample somewhere before it.
    run = np.ones((n, k - gap + 1), bool)
    for s in range(gap):
        run &= off[:, s : k - gap + 1 + s]
    seen_on = np.cumsum(on, axis=1) > 0
    start_ok = np.zeros((n, k - gap + 1), bool)
    start_ok[:, 1:] = seen_on[:, : k - gap]  # a changed sample before the run's start
    starts = run & start_ok
    has: np.ndarray = np.asarray(starts.any(axis=1))
    if not np.any(has):
        return None
    start = np.where(has, np.argmax(starts, axis=1), k)
    index = np.arange(k)[None, :]
    # The run goes on while unchanged: its end is the first sample at or after start + gap that is not.
    after = (index >= (start + gap)[:, None]) & ~off
    end = np.where(after.any(axis=1), np.argmax(after, axis=1), k)
    gap_run = (index >= start[:, None]) & (index < end[:, None]) & has[:, None]
    beyond = (index >= end[:, None]) & has[:, None]
    return beyond, gap_run


def _along_outline_ncc(current: np.ndarray, reference: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Per sample (outline points x offsets, closed outline): the correlation of current and reference over the
    samples at the same offset of the outline points within TEXTURE_REACH_POINTS either side, each less its
    least-squares line along the outline; 0 where any of them is unknown."""
    w = TEXTURE_REACH_POINTS
    shifts = range(-w, w + 1)
    t = np.arange(-w, w + 1, dtype=np.float64)
    count, tt = float(len(t)), float(np.dot(t, t))
    cur, ref = current.astype(np.float64), reference.astype(np.float64)
    sums = {name: np.zeros_like(cur) for name in ("c", "r", "tc", "tr", "cc", "rr", "cr")}
    complete = np.ones(known.shape, bool)
    for j, shift in zip(t, shifts, strict=True):
        c, r = np.roll(cur, -shift, axis=0), np.roll(ref, -shift, axis=0)
        complete &= np.roll(known, -shift, axis=0)
        sums["c"] += c
        sums["r"] += r
        sums["tc"] += j * c
        sums["tr"] += j * r
        sums["cc"] += c * c
        sums["rr"] += r * r
        sums["cr"] += c * r
    # Sums of products of the residuals after the line (t centred: the line's slope is S_tx / S_tt).
    cr = sums["cr"] - sums["c"] * sums["r"] / count - sums["tc"] * sums["tr"] / tt
    cc = sums["cc"] - sums["c"] ** 2 / count - sums["tc"] ** 2 / tt
    rr = sums["rr"] - sums["r"] ** 2 / count - sums["tr"] ** 2 / tt
    ncc = cr / np.sqrt(np.maximum(cc * rr, 1e-12))
    return np.where(complete, ncc, 0.0)


def one_camera_shadows(
    raw: tuple[np.ndarray, np.ndarray], cleared: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Per camera (left, right) its edge offsets (cellctl.vision.image_edge.stereo_offsets) read without the shadow
    samples where the other camera's own reading, as read from its whole mask, finds the edge within
    MAX_EDGE_OFFSET_MM of the outline (either side); elsewhere as read from the whole mask. The sole's edge
    beyond the outline is in both cameras' silhouettes (each at its own height); a cast shadow's sliver, left
    changed where the change test's windows met two shadow levels, lies where each image's windows happen to
    fail, and a dark band of the sole that the photometry alone cannot tell from a shadow (a rim on a weakly
    textured table) is seen by both."""
    result = []
    for own, own_cleared, other in ((raw[0], cleared[0], raw[1]), (raw[1], cleared[1], raw[0])):
        with np.errstate(invalid="ignore"):
            confirmed = np.isfinite(other) & (np.abs(other) <= MAX_EDGE_OFFSET_MM)
        result.append(np.where(confirmed, own_cleared, own))
    return result[0], result[1]
