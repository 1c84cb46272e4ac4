"""A cast shadow's dark band beside the sole (cellctl.vision.shadow_band), on a synthetic rectified pair: a textured
table at one disparity, a round sole standing higher at a larger one, and what lies beside it. The band on the
table is found; a dark part of the sole (a black rim on a white sole, a black sole on a grey table) is not."""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.vision.change import ChangeTest
from cellctl.vision.shadow_band import TableDisparity, _hidden_strip, shadow_band

MM_PER_PX = 0.39
HEIGHT, WIDTH = 200, 260
TABLE_DISPARITY = 40.0  # the real rig's is ~150 px: only the difference matters here
SOLE_DISPARITY = 47.0  # ~20 mm above the table at the rig's distance
CENTRE, RADIUS = (130.0, 100.0), 55.0  # the sole's round top in the left image (px)
NOISE = 1.0
TEST = ChangeTest(gain=1.0, offset=0.0, sigma=NOISE)


def _texture(seed: int, scale: float, shape: tuple[int, int] = (HEIGHT, WIDTH + 200)) -> np.ndarray:
    """Smooth random texture, unit spread: the table's or the sole's own."""
    noise = np.random.default_rng(seed).normal(size=shape).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.5)
    return scale * smooth / float(smooth.std())


def _distance_from_sole(x: np.ndarray, y: np.ndarray, straight: float = 0.0) -> np.ndarray:
    """Pixels from the sole's edge (positive outside), left-image coordinates of the sole: a disc, or with
    `straight` a stadium, its sides that long either side of the centre along the image rows."""
    radius = RADIUS if not straight else RADIUS - 20.0
    return np.hypot(np.maximum(np.abs(x - CENTRE[0]) - straight, 0.0), y - CENTRE[1]) - radius


def _scene(
    table_level: float,
    sole: tuple[float, float],
    rim: tuple[float, float] | None,
    shadow: bool,
    blur: float = 0.0,
    straight: float = 0.0,
    sharp: float = 0.0,
    mat: tuple[float, float] | None = None,
    sharp_right: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(left, right, taught left, changed): `sole` = (brightness, texture spread); `rim` = (width px,
    brightness) of a dark band round its top edge; `shadow`: a penumbra on the table to the sole's right, 1.5-4
    mm wide; `blur`: a lens out of focus (Gaussian sigma, px); `straight`: a stadium's half side along the rows;
    `sharp`: a small lamp's shadow on the table, that wide (px) at 0.4 of the light, its edge a step, to the
    sole's left (where the sole hides the table beside it from the right camera; `sharp_right`: to its right,
    where both cameras see it); `mat` = (width px, brightness): something dark lying on the table round the
    sole, its own faint texture."""
    table = table_level + _texture(1, 3.0)  # table coordinates: left x + 100 (room for the right view's shift)
    sole_texture = _texture(2, sole[1])
    rng = np.random.default_rng(3)
    images = []
    for disparity_table, disparity_sole in ((0.0, 0.0), (TABLE_DISPARITY, SOLE_DISPARITY)):
        y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
        table_x = x + disparity_table  # where this view's pixel meets the table, in left coordinates
        lit = np.ones_like(x)
        if shadow:
            beyond = _distance_from_sole(table_x, y)
            right_side = table_x > CENTRE[0]
            factor = np.clip(0.45 + 0.55 * (beyond - 2.0) / 8.0, 0.45, 1.0)
            lit = np.where(right_side & (beyond > -1.0), factor, 1.0)
        if sharp:
            beyond = _distance_from_sole(table_x, y)
            side = table_x > CENTRE[0] if sharp_right else table_x < CENTRE[0]
            lit = np.where(side & (beyond > -1.0) & (beyond < sharp), 0.4, lit)
        image = cv2.remap(table, table_x + 100.0, y, cv2.INTER_LINEAR) * lit
        if mat is not None:
            beyond = _distance_from_sole(table_x, y)
            own = mat[1] + cv2.remap(_texture(5, 0.3), table_x + 100.0, y, cv2.INTER_LINEAR)
            image = np.where((table_x > CENTRE[0]) & (beyond > -1.0) & (beyond < mat[0]), own, image)
        sole_x = x + disparity_sole  # the sole's point this pixel would see, in left coordinates
        inside = _distance_from_sole(sole_x, y, straight)
        top = sole[0] + cv2.remap(sole_texture, sole_x + 100.0, y, cv2.INTER_LINEAR)
        if rim is not None:
            top = np.where(inside > -rim[0], rim[1], top)
        image = np.where(inside <= 0.0, top, image)
        if blur:
            image = cv2.GaussianBlur(image, (0, 0), blur)
        images.append((image + rng.normal(scale=NOISE, size=image.shape)).astype(np.float32))
    left, right = images
    reference = cv2.remap(
        table,
        np.mgrid[0:HEIGHT, 0:WIDTH][1].astype(np.float32) + 100.0,
        np.mgrid[0:HEIGHT, 0:WIDTH][0].astype(np.float32),
        cv2.INTER_LINEAR,
    )
    # As the change test gives it: beyond 3 sigma, isolated flags removed by a 3 x 3 majority.
    changed = cv2.medianBlur((np.abs(left - reference) > 3 * NOISE).astype(np.uint8), 3) > 0
    return left, right, reference, changed


def _band(
    left: np.ndarray,
    right: np.ndarray,
    reference: np.ndarray,
    changed: np.ndarray,
    heights: np.ndarray | None = None,
    hidden_px: float = 0.0,
) -> np.ndarray:
    table = TableDisparity(0.0, 0.0, TABLE_DISPARITY)
    measured = np.full(left.shape, np.nan, np.float32) if heights is None else heights  # None: no depth beside the sole
    return shadow_band(
        changed, left, right, table, False, TEST, reference, NOISE, MM_PER_PX, lambda box: measured[box], hidden_px
    )


def _sole_mask() -> np.ndarray:
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    return _distance_from_sole(x, y) <= 0.0


def test_a_penumbra_beside_a_white_sole_is_the_table() -> None:
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=True)
    band = _band(left, right, reference, changed)
    sole = _sole_mask()
    shadowed = changed & ~sole
    assert np.count_nonzero(shadowed) > 300  # the change test's band: the case is there
    assert np.count_nonzero(band & sole) == 0
    # The right camera sees the table beside the sole, but not where the sole, higher, hides it from that view:
    # there nothing tells the band from a dark part of the sole, and it stays changed.
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    seen_by_both = _distance_from_sole(x + SOLE_DISPARITY - TABLE_DISPARITY, y) > 1.5
    assert np.count_nonzero(band & shadowed & seen_by_both) >= 0.9 * np.count_nonzero(shadowed & seen_by_both)


def _heights_beside_the_sole(changed: np.ndarray, low: float, high: float) -> np.ndarray:
    """Points measured on 60 % of the changed pixels beside the sole, at heights drawn from low..high mm."""
    rng = np.random.default_rng(4)
    heights = np.full(changed.shape, np.nan, np.float32)
    beside = changed & ~_sole_mask() & (rng.random(changed.shape) < 0.6)
    heights[beside] = rng.uniform(low, high, size=int(np.count_nonzero(beside)))
    return heights


def test_a_sharp_shadow_beside_a_white_sole_is_the_table_up_to_the_sole() -> None:
    """A small lamp's shadow steps onto the table: no penumbra, but the table's texture shows through it at one
    factor and its step lies at the table's disparity. Beside the sole, where the sole hides the band from the right
    camera, the band grows over the strip as wide as the two disparities differ, shadowed alike."""
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=False, sharp=12.0)
    sole = _sole_mask()
    shadowed = changed & ~sole
    assert np.count_nonzero(shadowed) > 300
    seen = _band(left, right, reference, changed)
    whole = _band(left, right, reference, changed, hidden_px=SOLE_DISPARITY - TABLE_DISPARITY)
    assert np.count_nonzero(seen & sole) == 0 and np.count_nonzero(whole & sole) == 0
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    hidden = _distance_from_sole(x + SOLE_DISPARITY - TABLE_DISPARITY, y) <= 0.0  # the right camera sees the sole
    assert np.count_nonzero(seen & shadowed & hidden) < 0.5 * np.count_nonzero(shadowed & hidden)
    assert np.count_nonzero(whole & shadowed) >= 0.9 * np.count_nonzero(shadowed)


def test_a_thin_sharp_shadow_is_the_table_though_the_soles_edge_lies_just_across_it() -> None:
    """A small lamp's shadow only 2 px wide beyond the sole's edge, where both cameras see it: the sole's edge, seen at
    the wrong disparity, lies a pixel or two across the band from the table, and is no edge of the band's own on the
    table's side."""
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=False, sharp=2.0, sharp_right=True)
    sole = _sole_mask()
    shadowed = changed & ~sole
    assert np.count_nonzero(shadowed) > 300
    band = _band(left, right, reference, changed)
    assert np.count_nonzero(band & sole) == 0
    assert np.count_nonzero(band & shadowed) >= 0.9 * np.count_nonzero(shadowed)


def _hidden_strip_of_an_unchanged_shadow(sole: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(band found, the hidden strip the change test kept, the sole) for a small lamp's shadow to the sole's left that
    the change test left unchanged (its texture vote) but for the strip beside the edge that the right camera cannot
    see."""
    left, right, reference, changed = _scene(40.0, sole, None, shadow=False, sharp=12.0)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    beyond = _distance_from_sole(x, y)
    strip = (x < CENTRE[0]) & (beyond > 0.0) & (_distance_from_sole(x + SOLE_DISPARITY - TABLE_DISPARITY, y) <= 0.0)
    sole_mask = _sole_mask()
    kept = changed & (sole_mask | strip)
    band = _band(left, right, reference, kept, hidden_px=SOLE_DISPARITY - TABLE_DISPARITY)
    return band, kept & strip, sole_mask


def test_the_hidden_strip_of_a_shadow_the_change_test_left_unchanged_is_the_table() -> None:
    """Where the change test's texture vote took the shadow for the table, only the strip the sole hides from the
    other camera stays changed, and no band is found to grow over it: the unchanged shadow itself is grown from."""
    band, strip, sole = _hidden_strip_of_an_unchanged_shadow((200.0, 15.0))
    assert np.count_nonzero(strip) > 100
    assert np.count_nonzero(band & strip) >= 0.9 * np.count_nonzero(strip)
    assert np.count_nonzero(band & sole) == 0


def test_a_black_soles_edge_beside_an_unchanged_shadow_is_not_grown_over() -> None:
    """A sole darker than the shadow beside it: no lit sole tells the strip's pixels for a shadow, and the sole's own
    edge pixels, as dark, are not taken."""
    band, strip, sole = _hidden_strip_of_an_unchanged_shadow((10.0, 2.0))
    assert np.count_nonzero(band & sole) == 0


def test_something_dark_on_the_table_beside_the_sole_is_no_shadow() -> None:
    """As dark as a shadow, its step onto the table at the table's disparity (a leaning wall's foot, a dark mat): its
    own texture, not the table's, tells it apart."""
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=False, mat=(12.0, 16.0))
    assert np.count_nonzero(changed & ~_sole_mask()) > 300
    assert np.count_nonzero(_band(left, right, reference, changed, hidden_px=7.0)) == 0


def test_a_dark_rim_next_to_a_shadow_is_not_taken_with_it() -> None:
    """A uniform dark rim round the sole's edge (0.65 of the table's brightness) beside a small lamp's shadow (0.4):
    uniform, it agrees at the table's disparity as the band does and joins its stretch, whose brightness then no
    longer follows the table's texture: neither is taken for the table."""
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), (6.0, 26.0), shadow=False, sharp=12.0)
    band = _band(left, right, reference, changed, hidden_px=SOLE_DISPARITY - TABLE_DISPARITY)
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    rim = (_distance_from_sole(x, y) <= 0.0) & (_distance_from_sole(x, y) > -6.0)
    assert np.count_nonzero(changed & rim) > 500 and np.count_nonzero(band & rim) == 0


def test_the_hidden_strip_grows_only_over_the_bands_own_light() -> None:
    """The strip the sole hides from the other camera is taken where it is shadowed as the band beside it is (within
    HIDDEN_FACTOR_SHARE of its factor), at most `hidden_px` wide: a darker or brighter part of the sole is not."""
    band = np.zeros((20, 40), bool)
    band[:, :10] = True
    factor = np.full(band.shape, 0.4, np.float32)
    factor[:, 16:] = 0.7  # beyond 6 px of the band's light: a dark part of the sole, lit
    allowed = np.ones(band.shape, bool)
    grown = _hidden_strip(band, allowed, factor, 8.0)
    assert grown[:, :16].all() and not grown[:, 16:].any()
    assert not _hidden_strip(band, allowed, np.full(band.shape, 0.4, np.float32), 3.0)[:, 13:].any()


def test_depth_at_the_tables_level_on_a_band_leaves_it_the_table() -> None:
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=True)
    found = _band(left, right, reference, changed)
    measured = _band(left, right, reference, changed, _heights_beside_the_sole(changed, 1.0, 3.0))
    assert np.count_nonzero(found) > 300
    assert np.array_equal(measured, found)


def test_a_stretch_depth_measured_above_the_table_is_the_sole_not_a_band() -> None:
    # A side wall leaning out into view or a rounded edge's shaded curve, as dark and uniform as a shadow's band:
    # depth finds it above the table.
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), None, shadow=True)
    wall = _band(left, right, reference, changed, _heights_beside_the_sole(changed, 1.0, 15.0))
    assert np.count_nonzero(wall) == 0


def test_a_black_rim_of_a_white_sole_is_not_a_shadow() -> None:
    # As dark against the table as a shadow's band (0.45), as uniform, and beside a brighter sole: its sharp edge on
    # the table, seen at the wrong disparity where it crosses the image rows, tells it apart.
    left, right, reference, changed = _scene(40.0, (200.0, 15.0), (10.0, 18.0), shadow=False)
    assert np.count_nonzero(changed & ~_sole_mask()) < 50
    assert np.count_nonzero(_band(left, right, reference, changed)) == 0


def test_a_black_sole_on_a_grey_table_is_not_a_shadow() -> None:
    left, right, reference, changed = _scene(100.0, (50.0, 2.0), None, shadow=False)
    assert np.count_nonzero(_band(left, right, reference, changed)) == 0


def test_a_soft_edged_black_sole_on_a_grey_table_is_not_a_shadow() -> None:
    # Out of focus, its edge fades into the table like a penumbra, and along the image rows a shift along the edge
    # changes nothing: only the lit sole a shadow's band lies beside, missing here, tells it apart.
    left, right, reference, changed = _scene(100.0, (55.0, 2.0), None, shadow=False, blur=2.5, straight=60.0)
    assert np.count_nonzero(_band(left, right, reference, changed)) == 0


def test_a_black_sole_on_a_grey_table_keeps_its_edge_beside_a_shadow() -> None:
    left, right, reference, changed = _scene(100.0, (50.0, 2.0), None, shadow=True)
    assert np.count_nonzero(_band(left, right, reference, changed) & _sole_mask()) == 0


def test_a_right_pixels_shift_lands_on_the_left_pixel_of_the_same_table_point() -> None:
    table = TableDisparity(0.012, -0.004, 150.0)  # a tilted plane: the disparity changes along x
    box = (slice(10, 40), slice(300, 360))
    y, x = np.mgrid[box].astype(np.float64)
    left_x = x + table.shift(box, right=True)
    np.testing.assert_allclose(left_x - (table.a * left_x + table.b * y + table.c), x, atol=1e-3)
    np.testing.assert_allclose(table.shift(box, right=False), -table.values(box), atol=1e-4)
