"""A cast shadow's dark band beside the sole, told from the sole by stereo: it lies on the table, so both cameras
see it at the table's disparity.

A lamp low beside the cell darkens a band of the table along the sole's edge (its penumbra graded over 2-4 mm,
where two lamps' shadows overlap). There the table's texture is too faint for the change test's vote
(cellctl.vision.change: the band stays changed), and the matcher, with nothing to match in it, carries the sole's
disparity out over it: the depth outline bulged 2-6 mm beyond the edge on 20 of the 25 shadowed soles of the
fresh sets (docs/sole-benchmark.md, thirty-eighth round), and the outline's checks refused them. Every lamp above
the cell casts such a band beside the walls facing away from it, narrower and often sharp-edged: the cell's own
light bars, a ring light round the lenses, one overhead lamp (forty-second round).

What the images still show is where the band lies: on the table, the same in both views once the right image is
shifted by the table's disparity, which the sole's edge and textured top are not (they stand higher, at a
larger disparity). A changed pixel is taken for shadowed table (`shadow_band`) where all of these hold:

- darker than the taught table as lit now (a shadow's factor, change.MAX_SHADOW_FACTOR, and more than the noise);
- consistent at the table's disparity: the left pixel and the right one at x - d_table differ by no more than
  the two images' noise (CONSISTENT_SIGMAS), by a 3 x 3 majority;
- darker than the sole beside it by MIN_SOLE_OVER_BAND (the lit sole casts the shadow; a dark part of a sole lies
  beside more of itself);
- within BAND_MAX_MM of the unchanged table round the sole (`_outer`), in a connected stretch of such pixels that
  meets the table the way a shadow does (`_faded_stretches`: directly, and wider than a blended edge pixel; and
  softly, as a penumbra does, or, a small lamp's sharp shadow, with the taught table's texture showing through
  it), and which depth did not measure above the table (`_raised`: a rounded edge's curve, a leaning wall).

Beside the sole's edge the sole hides a strip of the band from the other camera (up to the difference of the
sole's and the table's disparities wide), where no stereo test can speak: a band found is grown over it, through
changed pixels shadowed as the band is (`_hidden_strip`). So is a shadow the change test itself left unchanged (its
texture showed through at a shadow's factor), through pixels that are also darker than a lit sole beside them: where
the change test kept only that strip, specks of it joined the sole's region and the outline ran out over them (what
is left of such a strip can still make a spur: cellctl.vision.edge_checks.check_outline_spur). The same for the
right image against the left. Those pixels are no longer changed, and the depth points on them above the table are
the sole's disparity carried over the band (cellctl.vision.segmentation drops them from the footprint and the depth
step alike).

Not found: a band beside a sole as dark as it (a black sole on a grey table): there the band stays changed, the
outline bulges and the checks refuse it as before. Not told apart: a dark part of the sole (a rim, a black wall
leaning into view) that joins a band's stretch; a stretch of them both is taken whole or not at all, and the
outline's checks are what refuses the sole then (docs/sole-benchmark.md, forty-second round).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from cellctl.stereo.kernels import label_areas
from cellctl.vision.change import MAX_SHADOW_FACTOR, MIN_TEXTURE_GAIN, ChangeTest, enclosed_unchanged
from cellctl.vision.table import TableDisparity

# |left - right at the table's disparity| on the table: within 3 sigma of the difference's noise but for 0.3 % of
# the pixels (which the 3 x 3 majority then outvotes); a textured sole seen at the wrong disparity, often beyond.
CONSISTENT_SIGMAS = 3.0
DARKER_SIGMAS = 2.0  # below the predicted table by this many of its noise, besides the shadow's factor
# The band's width from the unchanged table: the penumbras beside the matrix's shadowed soles are 2-4 mm wide.
BAND_MAX_MM = 4.0
# The sole beside a shadow is lit: a white or grey sole 3-10 times the band's brightness, a black one on the dark
# table 2-3 times (the brightest sole pixel within the band's width of it).
MIN_SOLE_OVER_BAND = 1.6
# A penumbra's outer edge: the band fades into the table (2-5 DN per pixel beside the matrix's soles), the change
# test stops where the step is within its noise; an albedo edge steps by half its contrast or more at the mask.
SOFT_EDGE_SHARE = 0.25
# A stretch of candidates is a band where nearly all of its pixels beside the table are soft and few lie beside a
# sharp edge seen at the wrong disparity: the shadow bands of 39062 90-100 % and 0-10 %, the black rim round
# white matrix sole 39000 (as dark as a shadow's band, beside a brighter sole) 54 % and 52 %.
MIN_SOFT_SHARE = 0.8
MAX_RING_SHARE = 0.25
# A shadow's band with a sharp outer edge (one small lamp, or each of a ring's) meets the table in a step, not softly;
# it is still told from a dark part of the sole standing higher by that step's disparity (few ring pixels: the
# sharp bands beside other-lights soles 0-11 %, the black rim round 39000 53-60 %, 50-55 % counting only the
# pixels that touch the table, RING_PX) and, since a leaning black wall seen from above meets the table at its
# foot just the same (46026: 0-4 %), by the taught table's texture showing through it (correlation 0.33-0.38 in
# the deepest of those bands; 0.03-0.26 on the black walls of 39007, 46026 and 39051, a vertical one seen at a
# pointed heel).
MAX_SHARP_RING_SHARE = 0.15
MIN_SHARP_TABLE_CORRELATION = 0.3
# The strip the sole hides from the other camera is the band's where shadowed as the band beside it is: its factor
# against the taught table within this share of the band's nearby (a darker or lighter part of the sole is not).
HIDDEN_FACTOR_SHARE = 0.25
# A shadow the change test left unchanged is grown from as a band is: a stretch of that many pixels at least (a few
# mm^2); single table pixels the noise put below the shadow's threshold, scattered over the table, are no shadow.
MIN_SHADOW_PX = 50
# The changed pixels on the table's side of a stretch: those touching the table (8-neighbours; distance transform
# with the 3 x 3 mask: 1 and 1.37). Two and a half pixels took in, beside a band under a pixel or two wide (a
# penumbra thinning out along the sole), the sole's own edge across the band: on 39023 relit with the bars'
# shadows, a stretch 1 mm wide beside a black sole read 19 % of its pixels beside such an edge, past the sharp
# rule's 15 %, and the outline followed it 3.3 mm out (docs/sole-benchmark.md, forty-third round); touching, 3 %.
RING_PX = 1.5
# The bands beside three shadowed matrix soles (39039, 39059, 39062): 1.5-2.6 px wide in the mean (area over its
# pixels beside the table); the blend of a rounded black edge with the dark table (40026) 1.0-1.25 px. (The band's
# texture against the taught table's was no help: 0.1-0.54 correlation for the bands, 0.1-0.36 for that blend.)
MIN_BAND_WIDTH_MM = 0.55
OUTER_CLOSE_PX = 9  # ~3.5 mm: gaps in a sole's mask are a pixel or two; a shadow band's specks lie further apart
# Depth under a stretch: points more than MIN_RISE_MM above the table on 0-5 % of the pixels of the shadow bands of
# matrix soles 39039, 39059 and 39062; on 28-91 % of the shaded curves of rounded black edges (39054, 40054, 43054,
# no shadow) and 26 % of a black side wall leaning out into view (46026), which pass every test above.
MIN_RISE_MM = 5.0
MAX_RAISED_SHARE = 0.15
MIN_EDGE_PX = 10  # ~4 mm of edge on the table: less is a speck the outline's opening removes anyway
GAIN_STRIDE = 4  # the two images' gain on the table round the sole: every 4th pixel each way (~10^4 of them)


def _warped(image: np.ndarray, shift: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
    """`image` read at (x + shift, y) for the pixels of `box` (shift: per pixel of the box; float32, NaN off the
    image)."""
    rows = np.arange(box[0].start, box[0].stop, dtype=np.float32)
    columns = np.arange(box[1].start, box[1].stop, dtype=np.float32)
    map_x = columns[None, :] + shift
    map_y = np.repeat(rows[:, None], len(columns), axis=1)
    return cv2.remap(np.asarray(image, np.float32), map_x, map_y, cv2.INTER_LINEAR, borderValue=np.nan)


def _brightest(image: np.ndarray, mask: np.ndarray, reach_px: int) -> np.ndarray:
    """Per pixel, the brightest of the `mask` pixels within `reach_px` (a square: separable, so its cost does not grow
    with the reach); 0 where none is."""
    size = 2 * reach_px + 1
    return cv2.dilate(np.where(mask, image, 0.0).astype(np.float32), np.ones((size, size), np.uint8))


def _below_brighter_sole(image: np.ndarray, sole: np.ndarray, candidate: np.ndarray, reach_px: int) -> np.ndarray:
    """Per candidate pixel: the brightest of the sole (the changed pixels that are no candidate) within `reach_px`
    is MIN_SOLE_OVER_BAND times brighter. A shadow lies darker than the lit sole that casts it; a dark part of the
    sole itself (a black sole on a grey table) lies beside more of that sole, no brighter. A dark rim of a light
    sole does lie beside a brighter sole: its edge on the table is sharp, so no band starts on it (`_soft_edge`)."""
    return candidate & (_brightest(image, sole, reach_px) >= MIN_SOLE_OVER_BAND * image)


def _soft_edge(image: np.ndarray, table: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Per pixel: its brightness lies within SOFT_EDGE_SHARE of the brightest table pixel beside it (as taught and
    lit now, at least): a penumbra fades into the table over millimetres, while the edge of anything lying on it (a
    black sole, a dark rim) steps by most of its contrast within a pixel."""
    lit = _brightest(image, table, 1)
    return lit - image <= SOFT_EDGE_SHARE * np.maximum(lit, predicted)


def _faded_stretches(
    candidate: np.ndarray,
    image: np.ndarray,
    outside: np.ndarray,
    predicted: np.ndarray,
    ring: np.ndarray,
    pixel_mm: float,
) -> np.ndarray:
    """The connected stretches of candidates that meet the table round the sole the way a shadow does: directly
    (few of their pixels beside changed pixels on the table's side that do not agree at the table's disparity,
    `ring`: the sharp outer edge of something standing higher, seen at the wrong disparity), and softly (most of
    their pixels beside the table within SOFT_EDGE_SHARE of it: a penumbra) or, stepping onto the table as a small
    lamp's shadow does, with fewer still beside such an edge (MAX_SHARP_RING_SHARE) and the taught table's texture
    showing through (`_table_correlation`). One soft pixel would not do: a dark rim's edge
    is soft where its contrast with the table happens to be low. And the stretch is a band, MIN_BAND_WIDTH_MM wide
    in the mean: the last pixel of a sole's edge that blends it with the table (a rounded edge's shaded curve beside
    a dark table) is not."""
    _, labels = cv2.connectedComponents(candidate.astype(np.uint8), connectivity=8)
    square = np.ones((3, 3), np.uint8)
    on_table = candidate & (cv2.dilate(outside.astype(np.uint8), square) > 0)
    on_ring = candidate & (cv2.dilate(ring.astype(np.uint8), square) > 0)
    soft = on_table & _soft_edge(image, outside, predicted)
    count = int(labels.max()) + 1
    table_count, ring_count, soft_count = (np.bincount(labels[m], minlength=count) for m in (on_table, on_ring, soft))
    soft_band = (soft_count >= MIN_SOFT_SHARE * table_count) & (
        ring_count <= MAX_RING_SHARE * (ring_count + table_count)
    )
    sharp_band = ring_count <= MAX_SHARP_RING_SHARE * (ring_count + table_count)
    sharp_band &= _table_correlation(labels, count, image, predicted) >= MIN_SHARP_TABLE_CORRELATION
    faded = (table_count >= MIN_EDGE_PX) & (soft_band | sharp_band)
    area = np.bincount(labels.ravel(), minlength=count)
    faded &= area * pixel_mm >= MIN_BAND_WIDTH_MM * np.maximum(table_count, 1)
    faded[0] = False
    return faded[labels]


def _table_correlation(labels: np.ndarray, count: int, image: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """Per labelled stretch: the correlation of its brightness with the taught table's as lit now. A shadow scales
    the table's own texture; a wall or a dark part of the sole has a texture of its own."""
    flat = labels.ravel()
    n = np.maximum(np.bincount(flat, minlength=count), 1).astype(np.float64)
    a, b = image.ravel().astype(np.float64), predicted.ravel().astype(np.float64)
    mean_a, mean_b = np.bincount(flat, a, count) / n, np.bincount(flat, b, count) / n
    da, db = a - mean_a[flat], b - mean_b[flat]
    covariance = np.bincount(flat, da * db, count)
    spread = np.sqrt(np.bincount(flat, da * da, count) * np.bincount(flat, db * db, count))
    return covariance / np.maximum(spread, 1e-9)


def _raised(band: np.ndarray, heights: np.ndarray) -> np.ndarray:
    """The stretches of `band` that depth measured above the table: a point higher than MIN_RISE_MM on more than
    MAX_RAISED_SHARE of their pixels. A shadow's band has next to no texture and lies on the table: the matcher
    measures the table there, or carries the sole's disparity over a few of its pixels. A dark part of the sole
    that passes for a band, a rounded edge's shaded curve or a side wall leaning out into view, has the sole's
    texture and is measured where it stands."""
    _, labels = cv2.connectedComponents(band.astype(np.uint8), connectivity=8)
    count = int(labels.max()) + 1
    high = np.nan_to_num(heights, nan=0.0) > MIN_RISE_MM
    area = np.bincount(labels.ravel(), minlength=count)
    raised = np.bincount(labels[high], minlength=count) > MAX_RAISED_SHARE * area
    raised[0] = False
    return raised[labels]


def _outer(changed: np.ndarray) -> np.ndarray:
    """The unchanged pixels round the sole: outside the changed region once it is closed over OUTER_CLOSE_PX (a black
    sole like the table leaves unchanged patches inside its mask, some open to the table through a gap of a
    pixel or two) and its holes filled."""
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (OUTER_CLOSE_PX, OUTER_CLOSE_PX))
    closed = cv2.morphologyEx(changed.astype(np.uint8), cv2.MORPH_CLOSE, disc) > 0
    return ~closed & ~enclosed_unchanged(closed) & ~changed


def shadow_band(
    changed: np.ndarray,
    current: np.ndarray,
    other: np.ndarray,
    table: TableDisparity,
    right: bool,
    test: ChangeTest,
    reference: np.ndarray,
    other_sigma: float,
    pixel_mm: float,
    heights: Callable[[tuple[slice, slice]], np.ndarray],
    hidden_px: float = 0.0,
) -> np.ndarray:
    """Bool image: the changed pixels of `current` that are a cast shadow's band on the table (module docstring).

    other: the other rectified image; table: the table's disparity; right: `current` is the right image;
    test, reference: `current`'s change test against its taught reference; other_sigma: the other image's noise
    (DN); pixel_mm: a pixel on the table; heights: for a box of `current`, per pixel the height (mm) of a point
    measured there above the table's level, NaN elsewhere (asked only where a band is found)."""
    band = np.zeros_like(changed)
    if not np.any(changed):
        return band
    rows, columns = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
    reach = int(np.ceil(BAND_MAX_MM / pixel_mm)) + 2
    box = (
        slice(max(int(rows[0]) - reach, 0), min(int(rows[-1]) + reach + 1, changed.shape[0])),
        slice(max(int(columns[0]) - reach, 0), min(int(columns[-1]) + reach + 1, changed.shape[1])),
    )
    window_changed = changed[box]
    cur = np.asarray(current, np.float32)
    seen = _warped(other, table.shift(box, right), box)
    outside = _outer(window_changed) & np.isfinite(seen)
    if int(np.count_nonzero(outside)) < 100:
        return band
    here = cur[box]
    sample = (slice(None, None, GAIN_STRIDE),) * 2
    gain = float(np.median(here[sample][outside[sample]])) / max(float(np.median(seen[sample][outside[sample]])), 1e-3)
    sigma = float(np.hypot(test.sigma, gain * other_sigma))
    # Per pixel, then a 3 x 3 majority: a mean over the window would let one pixel of the sole's edge beside a
    # band pixel (a strong step, seen at the wrong disparity) outvote it.
    agree = np.nan_to_num(np.abs(here - gain * seen), nan=np.inf) <= CONSISTENT_SIGMAS * sigma
    consistent = cv2.medianBlur(agree.astype(np.uint8), 3) > 0
    predicted = test.predicted(np.asarray(reference)[box])
    dark = (here < MAX_SHADOW_FACTOR * predicted) & (here < predicted - DARKER_SIGMAS * test.sigma)
    dark &= here >= MIN_TEXTURE_GAIN * predicted  # a shadow's factor, not a black rim's on a lit table
    candidate = window_changed & dark & consistent
    distance = cv2.distanceTransform((~outside).astype(np.uint8), cv2.DIST_L2, 3)
    candidate &= distance * pixel_mm <= BAND_MAX_MM
    candidate &= _below_brighter_sole(here, window_changed & ~candidate, candidate, reach)
    found = np.zeros_like(window_changed)
    if np.any(candidate):
        ring = window_changed & ~consistent & (distance <= RING_PX)
        found = _faded_stretches(candidate, here, outside, predicted, ring, pixel_mm)
    if np.any(found):
        found &= ~_raised(found, heights(box))
    if hidden_px > 0.0:
        factor = here / np.maximum(predicted, 1e-3)
        if np.any(found):
            found = _hidden_strip(found, window_changed & dark, factor, hidden_px)
        # The shadow the change test itself left unchanged (its texture vote: the table at a shadow's factor) is a
        # band just as well, whose hidden strip stays changed; grown over pixels darker than a lit sole beside them.
        unchanged = _sizeable(outside & dark, MIN_SHADOW_PX)
        if np.any(unchanged):
            allowed = window_changed & dark & ~found
            allowed = _below_brighter_sole(here, window_changed & ~allowed & ~found, allowed, reach)
            found |= _hidden_strip(unchanged, allowed, factor, hidden_px) & window_changed
    band[box] = found
    return band


def _sizeable(mask: np.ndarray, least: int) -> np.ndarray:
    """The 8-connected stretches of `mask` with at least `least` pixels (areas counted in C, as
    cellctl.vision.footprint.largest_component counts them: OpenCV's statistics cost several times the labelling)."""
    count, labels = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    keep = label_areas(labels, count) >= least
    keep[0] = False
    return keep[labels]


def _hidden_strip(band: np.ndarray, allowed: np.ndarray, factor: np.ndarray, hidden_px: float) -> np.ndarray:
    """The band grown over the dark changed pixels next to it, by at most `hidden_px`: the strip beside the sole's
    edge that the sole hides from the other camera (no stereo test can confirm it there), shadowed as the band is
    (its factor against the taught table within HIDDEN_FACTOR_SHARE of the band's nearby)."""
    square = np.ones((3, 3), np.uint8)
    reach = 2 * int(np.ceil(hidden_px)) + 1
    window = np.ones((reach, reach), np.uint8)
    band_factor = np.where(band, factor, 0.0).astype(np.float32)
    highest = cv2.dilate(band_factor, window)
    lowest = -cv2.dilate(np.where(band, -factor, -np.inf).astype(np.float32), window)
    allowed = allowed & (factor <= highest * (1.0 + HIDDEN_FACTOR_SHARE))
    allowed &= factor >= lowest * (1.0 - HIDDEN_FACTOR_SHARE)
    grown = band.copy()
    for _ in range(int(np.ceil(hidden_px))):
        wider = (cv2.dilate(grown.view(np.uint8), square) > 0) & allowed
        if not np.any(wider & ~grown):
            break
        grown |= wider
    return grown
