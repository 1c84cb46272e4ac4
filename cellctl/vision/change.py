"""Change against the taught empty table: which pixels no longer show the table, whatever the sole's colour.

The taught reference image predicts every table pixel (its own texture, vignetting and all) up to the
camera's gain of the moment. A pixel is changed where the current image departs from that prediction by
more than the sensor noise allows. This replaces a colour discriminant between "sole colour" and "table
colour": a sole with a black rim on a dark table, a patterned table, or two-tone soles all differ from the
table's own recorded texture, and the decision is per pixel, so no window moves the edge.

A cast shadow departs from the taught picture without being the sole: it darkens the table's brightness and
its texture by one factor. Windows whose texture the reference explains at such a factor are still table,
and that factor is carried to the pixels beside them, so the sole's edge in a shadow is placed against the
shadowed table, not the taught one.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.stereo import change_kernels

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
# A window is also still table where a local gain and offset explain the current window from the reference
# down to the noise (the fit's residual variance below FIT_SIGMAS^2 sigma^2), with the reference's texture
# present at a shadow's or a lamp's scale (local gain above MIN_TEXTURE_GAIN). It needs less texture than
# the correlation (a reference spread above STILL_TEXTURE_SIGMAS sigmas): a dark table in a shadow has about
# 1.5 sigma of texture in 7 px, where the correlation's threshold votes in one window of ten. A sole's window
# leaves 4-40 sigma^2 unexplained; a sole without texture has no gain on the table's.
FIT_SIGMAS = 1.5
MIN_TEXTURE_GAIN = 0.3
SCALE_AGREEMENT = 0.4  # texture gain within this share of the brightness ratio (both are the shadow's factor)
# The fit's vote and the carried factor are for shadows only (darker than taught): a black sole on a dark
# table is 1.2-1.5 times its brightness with faint texture, and a lamp's factor would let it pass as table.
MAX_SHADOW_FACTOR = 0.95
MAX_CARRIED_FACTOR = 1.1  # the unshadowed table: 1 within its noise
GONE_WINDOW_PX = 9  # ~3.5 mm
GONE_INSIDE = 0.6
STILL_TEXTURE_SIGMAS = 1.0
# Shadow-corrected residual: the illumination factor of the still table is carried over ILLUMINATION_WINDOW_PX
# (~12 mm; half that where the still table is near) to the pixels next to it, so the edge of a sole in a shadow is placed against the shadowed table.
ILLUMINATION_WINDOW_PX = 31
# The least share of still-table pixels in the whole window and in its half for the factor to be carried.
ILLUMINATION_FAR_WEIGHT = 0.05
ILLUMINATION_NEAR_WEIGHT = 0.1
# Where some of the windows covering a pixel (MIN_LOCAL_FIT_SHARE) fit the reference at a shadow's factor with
# a clear correlation, their factor replaces the carried one: two lamps' shadows overlap in a darker band
# beside the sole (3-5 mm), whose weak texture gives no still vote, and the broad shadow's factor carried
# into it left it changed (the right-image and edge checks then refused soles whose outline was right).
LOCAL_SHADOW_FIT = True
MIN_LOCAL_FIT_SHARE = 0.1  # of the NCC windows covering a pixel (5 of 49)
# On the raised sole (pixels the caller's depth puts away from the table, `raised`) the local fit speaks only
# with a majority of the windows that could fit: a black sole on a grey table is 0.5 times the table's
# brightness, and its own texture fits the table's at that factor in 10-30 % of the windows by chance (the
# shadow bands beside a sole: 10-40 %, so the rule is not used there: they lie on the table).
RAISED_LOCAL_FIT_SHARE = 0.5  # of the fit-eligible windows (reference texture above STILL_TEXTURE_SIGMAS)
# A rim (a dark band round a white sole's top edge, a light one round a black sole) departs from the taught
# table with the other sign from the sole inside it. Held against half the contrast of all the clear pixels
# round it, which the sole's far larger residual dominates, its inner 3-5 px were missed: an unchanged ring
# between the rim and the sole. A pixel whose residual has the other sign from its neighbourhood's contrast is
# no blend of the table and that change, so the half-contrast rule does not place an edge there; it is held
# against half the contrast of the clear pixels of its own sign instead (`_rim_ring`), but only on the raised
# sole (`raised`) and only where the pixels so found lie in a hole of the mask (unchanged pixels the changed
# ones enclose, not reached from the box's border). A cast shadow's contact band beside a sole is also darker
# than the table with the other sign from a white sole, but it lies on the mask's outer border, open to the
# table: the own-sign rule found it too and moved four shadow soles' outlines 1.5-3.5 mm out (session 8).
RIM_RING = True
# On the raised sole (`raised`: depth puts no table-level point within reach) a pixel the texture votes still table
# is changed all the same where its brightness changed by more than this many noise floors (`_raised_change`). A blotch
# of a black sole's own texture at about the dark table's brightness, with little texture of its own, is voted
# table, and the half-contrast test takes its pixels for the blended edge: both cameras' masks bit 1.5 mm into the
# sole over 8 mm at the same spot, the outline followed, and the result was published with a glue point 1.27 mm
# off (wide-sole 37319; docs/sole-benchmark.md, thirty-first round). The table beside a fattened depth step is
# unchanged (its residual within the noise), so depth adds nothing there; only the sign of the change that
# dominates round the pixel counts, so a cast shadow's contact band beside a white sole, darker than the table
# under the sole's fattened depth, is not taken (test_change's contact shadow failed without that). Only the veto
# is overridden, never the half-contrast test: a soft (defocused) white edge blends over pixels of the table that
# changed by many floors, under fattened depth, and counting them published soft-focus 42021 1.05 mm off.
RAISED_CHANGE_FLOORS = 2.0
# Where the caller's depth lifts a pixel onto the sole (`lifted`: a high point on it, no table-level point within
# reach), the pixel is changed unless the table's own texture still votes near it. A grey sole on a grey table
# (or on a cutting mat) differs from the taught table by 1.5-3 sigma at many of its pixels: no per-pixel test
# decides them, but the still-table vote (the taught texture present, NCC ~1) is absent on 98-99.8 % of them
# and present on 94 % of the table 3-30 px beside the sole. Beside a white sole the vote stops a few pixels
# short of the edge (its windows see the step), and a fattened table pixel there (the sole's depth dragged past
# the edge) lies within this many pixels of a vote (on 13 grey/patterned/white soles none > 1.5 px outside was
# taken). On a grey sole the vote reaches 2-5 px in (a window half on the sole correlates through its table
# half), so the fill stops that much plus this reach inside the edge: the last 2-4 mm are the pixel test's.
LIFTED_STILL_REACH_PX = 5
# The vote's absence is evidence only where the reference has texture to vote with: most windows covering the
# pixel (a dark table's faint texture gives 30-50 % textured windows, a grey or patterned table's ~95 %).
LIFTED_VOTE_SHARE = 0.7
# How much of a sole looks like the table behind it: the share of its pixels well inside its edge (ALIKE_INSET_MM)
# that the pixel test alone cannot tell from the taught table (|residual| within PIXEL_SIGMAS of noise). Where the
# sole's colour is the table's (a grey sole on the grey table or on a grey cutting mat: 3 % apart in albedo), its
# edge pixels are missed as often, in patches that follow the table's texture, and both cameras' masks come out
# ragged 1-3 mm deep: the outline cannot be confirmed, and the refusal should say why (`alike_share`,
# cellctl.vision.measurement.table_alike_share: read for an outline's refusal only, never to refuse). Over the
# 252 soles of the fresh sets 39000, 40000 and 43000 (docs/sole-benchmark.md, thirty-fourth round) every valid
# result read at most 0.0054; grey soles on grey or patterned tables 0.08-0.20, black ones on the cutting mat
# 0.03-0.09 (its dark lines), black soles under cast shadows 0.005-0.015. A refused outline is put down to the
# colours beyond MAX_TABLE_ALIKE_SHARE, four times what any valid result read.
ALIKE_INSET_MM = 3.0
MAX_TABLE_ALIKE_SHARE = 0.02


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

    def alike_share(self, current: np.ndarray, reference: np.ndarray, pixels: np.ndarray) -> float:
        """Share of `pixels` (N x 2 integer (x, y)) that the pixel test alone cannot tell from the taught table:
        |current - predicted| within PIXEL_SIGMAS of the table's noise (NaN for no pixels)."""
        if len(pixels) == 0:
            return float("nan")
        x, y = pixels[:, 0], pixels[:, 1]
        residual = current[y, x] - self.predicted(reference[y, x])
        return float(np.mean(np.abs(residual) < PIXEL_SIGMAS * self.sigma))

    def predicted(self, reference: np.ndarray) -> np.ndarray:
        """The taught table as the current exposure shows it: gain x reference + offset (a new float32 array;
        no copy of a float32 input)."""
        predicted = np.multiply(np.asarray(reference, np.float32), self.gain)
        predicted += self.offset
        return predicted

    def changed(
        self,
        current: np.ndarray,
        reference: np.ndarray,
        box: tuple[slice, slice] | None = None,
        raised: np.ndarray | None = None,
        lifted: np.ndarray | None = None,
        threads: int = change_kernels.ALL_THREADS,
    ) -> np.ndarray:
        """Bool image: pixels that no longer show the taught table (only within `box`, rows and columns, if
        given: False elsewhere; the windows reach a few pixels, so a box a few mm larger than what is read
        gives the same pixels as the whole image).

        `raised` (bool image, optional): pixels where depth puts no table within reach (the caller's depth).
        There the local shadow fit needs a majority of the windows that could fit (RAISED_LOCAL_FIT_SHARE):
        a black sole on a grey table passed as the table in a shadow. Off the raised pixels (a shadow band
        beside the sole lies on the table and is matched there) the rule is as without it.

        `lifted` (bool image, optional): pixels the caller's depth puts on the sole (a high point there, no
        table-level point within reach). There a pixel is changed unless the taught texture still votes table
        within LIFTED_STILL_REACH_PX, where the reference is textured enough for that vote (LIFTED_VOTE_SHARE)
        and no shadow is carried (a shadowed table's weakened texture need not vote): a sole that matches the
        table's brightness is found from depth and the texture, and its edge stays where the change test puts it.

        A pixel is changed when its residual exceeds half the contrast of the change around it, and at least
        PIXEL_SIGMAS of noise. Half the contrast is where a pixel half covered by the sole lies, so the edge
        sits on the sole's edge for a white sole as for a black rim on a dark table; a global threshold would
        put it a pixel out on strong contrast and cut a weakly contrasting rim off. The contrast is that of
        the change dominating the pixel's CONTRAST_WINDOW_PX window (the sign of its clearly changed pixels'
        summed residual) with the pixel's own taught table: their mean brightness less the pixel's table as
        lit now. Not the mean residual round it: where a bright line of a patterned table runs under a white
        sole's edge, the sole differs from that line by a third of its contrast with the dark table round
        it, and half the mean residual stopped the mask at the line, ~1 mm short of the edge in both cameras
        (fresh set 9200, 9215: a valid result 1.15 mm off). A pixel whose residual has the other sign (a
        shadow band or a dark rim beside a white sole) is still held against half the local contrast (the
        mean magnitude of the clear residuals): against its own darkness a shadow band would be changed up to
        the sole, with no gap for vision.shadow to tell it by. A 3 x 3 majority (median) then removes
        isolated flags and misses; a straight edge stays where it is.

        `threads`: the C kernels' OpenMP threads (0: all); the same mask on any number.
        """
        if box is not None:
            changed = np.zeros(np.shape(current), bool)
            changed[box] = self.changed(
                np.asarray(current)[box],
                np.asarray(reference)[box],
                raised=None if raised is None else raised[box],
                lifted=None if lifted is None else lifted[box],
                threads=threads,
            )
            return changed
        still_table, texture_gone, illumination, textured_share = self._texture(current, reference, raised, threads)
        # Against the table as lit now: where the still table is darker or lighter than taught (a shadow), its
        # factor is carried to the pixels beside it, so a shadowed table pixel next to the sole is not changed.
        # Then the pixel test (in C, csrc/change_kernels.c, bit-identical to the numpy formulas kept in
        # tests/vision/change_reference.py): a pixel is changed where |residual| exceeds PIXEL_SIGMAS of noise and
        # half the contrast of the dominating change with this pixel's table (docstring above). The texture
        # vote's faintness is the local contrast (the mean magnitude of the clear residuals).
        # Next to a strong step every window covering a table pixel also covers the step and correlates
        # poorly: the texture vote would move the edge out. It only speaks where the change is faint
        # (FAINT_CONTRAST_SIGMAS). Inside a changed region, though, a pixel whose texture is gone is changed
        # whatever the contrast: a sole of about the table's brightness matches the prediction at scattered
        # pixels. Inside: more than GONE_INSIDE of its GONE_WINDOW_PX neighbourhood passed the pixel test, which
        # a table pixel beside the edge (half its neighbourhood at most) never has, even where the windows along
        # a step of the table's texture lost its correlation.
        floor = PIXEL_SIGMAS * self.sigma
        residual, raw = change_kernels.residual(
            current,
            reference,
            change_kernels.ResidualRules(
                gain=self.gain,
                offset=self.offset,
                floor=floor,
                contrast_window=CONTRAST_WINDOW_PX,
                faint_contrast=FAINT_CONTRAST_SIGMAS * self.sigma,
                gone_window=GONE_WINDOW_PX,
                gone_inside=GONE_INSIDE,
            ),
            illumination,
            texture_gone,
            threads,
        )
        if lifted is not None:
            reach = 2 * LIFTED_STILL_REACH_PX + 1
            near_table = cv2.dilate(
                still_table.view(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (reach, reach))
            )
            fill = (
                lifted & (near_table == 0) & (textured_share > LIFTED_VOTE_SHARE) & (illumination > MAX_SHADOW_FACTOR)
            )
            # Not the outermost pixel of what is changed with it: a pixel partly covered by a strong step (a white
            # sole's edge) is placed by the half-contrast test, not by depth (fattened, it lifts that pixel too).
            fill &= _not_outermost(raw, fill)
            raw |= fill
        mask = np.greater(raw, still_table).view(np.uint8)  # (raw or texture gone) and not still table
        if raised is not None:
            mask |= _raised_change(raw, residual, floor, raised, still_table).view(np.uint8)
        changed = cv2.medianBlur(mask, 3) > 0
        if raised is not None and RIM_RING:
            changed |= _rim_ring(changed, residual, floor, raised, raw, still_table)
        return changed

    def _texture(
        self,
        current: np.ndarray,
        reference: np.ndarray,
        raised: np.ndarray | None = None,
        threads: int = change_kernels.ALL_THREADS,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(still table, texture gone, illumination, textured share): the table's own texture is still there,
        only darker or lighter (a shadow), or it is gone (covered by something of whatever brightness).

        Normalised cross-correlation with the reference over NCC_WINDOW_PX windows is blind to a change of
        brightness; a window only counts as table if its texture is also scaled by a shadow's or a lamp's
        factor (below MAX_TEXTURE_GAIN), not by the tenfold of a sole's edge lying along a step of the table's. Still table: nearly all the textured windows covering the pixel correlate, so a sole
        pixel next to the table, about half of whose windows lie further inside, is not vetoed. Texture
        gone: nearly none correlates, which finds a sole of the table's own brightness but does not reach
        past its edge. Only windows where the reference has texture to compare vote. A window is also still
        table where a local gain and offset explain it from the reference down to the noise (FIT_SIGMAS), at
        a gain that agrees with its brightness ratio: a dark table in shadow has too little texture for the
        correlation's threshold but not for this fit.

        Also the illumination factor (current over the taught prediction, float32, 1 where unknown) averaged
        over the still table within ILLUMINATION_WINDOW_PX, and the share of the windows covering each pixel
        where the reference has texture to vote with.
        """
        # The rules, in the kernel's order (the numpy formulas, comment by comment, in
        # tests/vision/change_reference.py, which the kernel equals bit for bit):
        # - per NCC window: means, variances and covariance of cur and ref; ncc = cov / sqrt(max(var_c var_r,
        #   1e-6)); texture gain = cov / max(var_r, 1e-6) / gain; brightness = mean_c / max(predicted(mean_r), 1)
        #   (a shadow or a lamp scales the brightness as it scales the texture, a sole's brightness has nothing to
        #   do with it); the fit's unexplained variance var_c - cov^2 / var_r.
        # - a window is table-like where textured, ncc > TABLE_NCC and the texture gain lies between
        #   MIN_TEXTURE_GAIN (a sole's own texture correlates with the table's by chance in one window in ten on
        #   the matrix's grey soles, at 0.0-0.3 of its scale) and MAX_TEXTURE_GAIN; still: more than UNANIMOUS of
        #   the textured windows covering the pixel (at least MIN_TEXTURED_SHARE of them) are, or more than
        #   UNANIMOUS of them fit (FIT_SIGMAS, at a shadow's factor that agrees with the brightness ratio); gone:
        #   fewer than 1 - UNANIMOUS are.
        # - the illumination factor: current / predicted on the still pixels whose factor is a shadow's or the
        #   unshadowed table's (MIN_TEXTURE_GAIN..MAX_CARRIED_FACTOR; a stray still pixel on a white sole, ratio
        #   ~5, or a black one on the dark table, 1.2-1.5, is not carried), averaged over ILLUMINATION_WINDOW_PX
        #   where ILLUMINATION_FAR_WEIGHT of it is still, then over its half where ILLUMINATION_NEAR_WEIGHT is (a
        #   shadow's own edge stays sharp); where LOCAL_SHADOW_FIT's confident windows (a fit that is also a
        #   clear correlation: on a uniform black sole one window in ten fits a shadow's factor by chance, the
        #   correlation does not come by chance) cover MIN_LOCAL_FIT_SHARE of the pixel's, their mean brightness
        #   ratio instead (on `raised` pixels only with RAISED_LOCAL_FIT_SHARE of the fit-eligible windows).
        # In C (csrc/change_kernels.c): ~40 full-image float32 passes and ~15 box blurs in numpy and OpenCV were
        # most of the taught cycle's background stage.
        return change_kernels.texture(current, reference, self._texture_rules(), raised, threads)

    def _texture_rules(self) -> change_kernels.TextureRules:
        """This test's gain and noise with the texture vote's constants, as the C kernel takes them."""
        return change_kernels.TextureRules(
            gain=self.gain,
            offset=self.offset,
            ncc_window=NCC_WINDOW_PX,
            table_ncc=TABLE_NCC,
            min_texture_gain=MIN_TEXTURE_GAIN,
            max_texture_gain=MAX_TEXTURE_GAIN,
            unanimous=UNANIMOUS,
            min_textured_share=MIN_TEXTURED_SHARE,
            textured_variance=(TEXTURE_SIGMAS * self.sigma) ** 2,
            still_variance=(STILL_TEXTURE_SIGMAS * self.sigma) ** 2,
            fit_variance=(FIT_SIGMAS * self.sigma) ** 2,
            scale_agreement=SCALE_AGREEMENT,
            max_shadow_factor=MAX_SHADOW_FACTOR,
            max_carried_factor=MAX_CARRIED_FACTOR,
            illumination_window=ILLUMINATION_WINDOW_PX,
            far_weight=ILLUMINATION_FAR_WEIGHT,
            near_weight=ILLUMINATION_NEAR_WEIGHT,
            local_shadow_fit=LOCAL_SHADOW_FIT,
            min_local_fit_share=MIN_LOCAL_FIT_SHARE,
            raised_local_fit_share=RAISED_LOCAL_FIT_SHARE,
        )


def _own_sign_contrast(
    residual: np.ndarray, magnitude: np.ndarray, floor: float, window: tuple[int, int]
) -> np.ndarray:
    """Per pixel the mean magnitude of the clear residuals (above `floor`) of the pixel's own sign within
    `window` (0 where there are none)."""
    own = np.zeros(np.shape(residual), np.float32)
    for sign in (1.0, -1.0):
        clear = (residual * sign > floor).astype(np.float32)
        weight = cv2.blur(clear, window)
        mean = cv2.blur(magnitude * clear, window)
        pick = (residual * sign > 0) & (weight > 0)
        own[pick] = mean[pick] / weight[pick]
    return own


def enclosed_unchanged(changed: np.ndarray) -> np.ndarray:
    """Unchanged pixels not connected (4-neighbours) to the image's border through unchanged pixels."""
    height, width = changed.shape
    padded = np.pad(changed.astype(np.uint8), 1)  # a border of unchanged pixels: the outside
    cv2.floodFill(padded, np.zeros((height + 4, width + 4), np.uint8), (0, 0), 2, flags=4)
    return padded[1:-1, 1:-1] == 0


def _raised_change(
    raw: np.ndarray, residual: np.ndarray, floor: float, raised: np.ndarray, still_table: np.ndarray
) -> np.ndarray:
    """Raised pixels the texture votes still table that changed beyond RAISED_CHANGE_FLOORS noise floors with the
    sign of the change that dominates their CONTRAST_WINDOW_PX window; not the outermost pixel of what is changed
    with them (a pixel partly covered by the sole's edge is placed by the half-contrast test, as for `lifted`). The sign:
    a cast shadow's contact band beside a white sole, under its fattened depth, is darker than the table, the
    sole brighter (test_change: the contact shadow is not taken for a rim)."""
    clear = np.where(np.abs(residual) > floor, residual, 0.0).astype(np.float32)
    dominant = cv2.boxFilter(clear, -1, (CONTRAST_WINDOW_PX, CONTRAST_WINDOW_PX), normalize=False)
    over = raised & still_table & (np.abs(residual) > RAISED_CHANGE_FLOORS * floor) & (residual * dominant > 0)
    return over & _not_outermost(raw, over)


def _not_outermost(raw: np.ndarray, added: np.ndarray) -> np.ndarray:
    """Pixels all of whose 3 x 3 neighbours pass the pixel test (`raw`) or are `added` by depth: a pixel partly
    covered by the sole's edge stays the half-contrast test's to place, not depth's (fattened, it lifts that
    pixel too)."""
    return cv2.erode((raw | added).view(np.uint8), np.ones((3, 3), np.uint8)) > 0


def _rim_ring(
    changed: np.ndarray,
    residual: np.ndarray,
    floor: float,
    raised: np.ndarray,
    raw: np.ndarray,
    still_table: np.ndarray,
) -> np.ndarray:
    """The pixels of the holes in `changed` on the raised sole whose residual exceeds half the contrast of
    their own sign (RIM_RING; a 3 x 3 majority as for the mask itself)."""
    holes = enclosed_unchanged(changed)
    holes &= raised
    found = np.zeros_like(holes)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(holes.view(np.uint8), connectivity=8)
    if count <= 1:
        return found
    window = (CONTRAST_WINDOW_PX, CONTRAST_WINDOW_PX)
    reach = CONTRAST_WINDOW_PX  # past the contrast window's half and the majority's pixel: the same result
    height, width = holes.shape
    # Per hole, in its bounding box and `reach` round it (most holes are a few pixels inside the sole).
    for label, (x, y, w, h, _) in enumerate(stats[1:], start=1):
        rows = slice(max(y - reach, 0), min(y + h + reach, height))
        cols = slice(max(x - reach, 0), min(x + w + reach, width))
        magnitude_box = np.abs(residual[rows, cols])
        own = _own_sign_contrast(residual[rows, cols], magnitude_box, floor, window)
        box = magnitude_box > np.maximum(floor, 0.5 * own)
        box |= raw[rows, cols]
        box &= ~still_table[rows, cols]
        box = cv2.medianBlur(box.view(np.uint8), 3) > 0
        found[rows, cols] |= box & (labels[rows, cols] == label)
    return found
