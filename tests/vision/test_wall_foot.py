"""A wall both cameras see alike: the image about each camera's foot reading says whether its mask ended at the
foot (the wall's face inside it) or at the top edge (the top inside it), cellctl.vision.wall_foot."""

from __future__ import annotations

import warnings

import numpy as np

from cellctl.vision.image_edge import Readings
from cellctl.vision.wall_foot import feet_confirmed, read_feet, wall_inside

PX_PER_MM = 4.0


def to_pixel(points: np.ndarray) -> np.ndarray:
    """A camera looking straight down: table x, y (mm) -> pixels, 4 per mm, the table's origin at pixel (40, 40)."""
    return 40.0 + PX_PER_MM * points[:, :2]


def scene(top_dn: float, wall_dn: float, wall_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Current image, taught reference and change mask on the table plane (x, y up to 50 mm): a textured grey table
    (60 DN), a sole's top of `top_dn` over x < -`wall_mm` and its wall's face, `wall_dn`, over the `wall_mm` up to
    the foot at x = 0 (a camera looking onto the wall: its face projects onto the table plane inside the foot)."""
    rng = np.random.default_rng(5)
    reference = np.clip(60.0 + 3.0 * rng.standard_normal((240, 240)), 0, 255).astype(np.float32)
    current = reference + 1.5 * rng.standard_normal(reference.shape).astype(np.float32)  # the sensor's noise
    x_mm = (np.arange(240) - 40.0) / PX_PER_MM
    current[:, x_mm < 0.0] = wall_dn
    current[:, x_mm < -wall_mm] = top_dn
    changed = np.zeros(reference.shape, bool)
    changed[:, x_mm < 0.0] = True
    return current, reference, changed


def outline(count: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Outline points on a straight edge x = 0 at y = 5..14 mm, the outward normal +x."""
    ring = np.column_stack([np.zeros(count), 5.0 + np.arange(count)])
    return ring, np.tile([1.0, 0.0], (count, 1))


def test_a_wall_face_darker_or_brighter_than_top_and_table_confirms_the_foot_reading() -> None:
    ring, outward = outline()
    foot, top = np.zeros(len(ring)), np.full(len(ring), 1.5)  # the same ray 1.5 mm further out at the top's height
    # The mask ended at the foot of a black wall (20 DN, under the table's 60 and the top's 110): a wall's face.
    assert wall_inside(*scene(110.0, 20.0, 1.5), to_pixel, ring, outward, foot, top).all()
    assert wall_inside(*scene(110.0, 230.0, 1.5), to_pixel, ring, outward, foot, top).all()  # a lit white wall
    # The mask ended at the top edge: inside its foot reading the top itself, then the table-like face.
    assert not wall_inside(*scene(200.0, 62.0, 1.5), to_pixel, ring, outward, foot - 1.5, top - 1.5).any()
    # A face between the top's and the table's levels tells nothing either way: unresolved, as before.
    assert not wall_inside(*scene(200.0, 120.0, 1.5), to_pixel, ring, outward, foot, top).any()
    unknown = np.full(len(ring), np.nan)
    assert not wall_inside(*scene(110.0, 20.0, 1.5), to_pixel, ring, outward, unknown, top).any()
    assert not wall_inside(*scene(110.0, 20.0, 1.5), to_pixel, ring, outward, foot, foot - 0.5).any()  # no slant
    off_image = ring + [60.0, 0.0]  # beyond the image's edge: no evidence, and no warning of an empty median
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not wall_inside(*scene(110.0, 20.0, 1.5), to_pixel, off_image, outward, foot, top).any()


def readings(foot: float, top: float, wall: bool, count: int = 10) -> Readings:
    pair = (np.full(count, foot), np.full(count, foot - 0.25))
    return pair, (np.full(count, top), np.full(count, top + 0.25)), np.full(count, wall)


def test_feet_replace_the_offsets_only_where_the_masks_cannot_tell_and_an_image_shows_the_wall() -> None:
    both = (readings(-0.9, 0.1, True), readings(-1.4, 0.1, True))  # no foot agrees with the other's top
    yes, no = np.ones(10, bool), np.zeros(10, bool)
    assert feet_confirmed(both, yes, no).all() and feet_confirmed(both, no, yes).all()  # one camera shows the face
    assert not feet_confirmed(both, no, no).any()
    paired = (readings(-0.9, 0.1, True), readings(0.0, -0.8, True))  # left foot agrees with the right top
    assert not feet_confirmed(paired, yes, yes).any()
    one_wall = (readings(-0.9, 0.1, True), readings(-1.4, 0.1, False))
    assert not feet_confirmed(one_wall, yes, yes).any()
    offsets = (np.full(10, 0.1), np.full(10, 0.1))
    confirmed = np.arange(10) < 4
    inner = read_feet(offsets, both, confirmed, 0)
    outer = read_feet(offsets, both, confirmed, 1)
    assert np.allclose(inner[0][:4], -0.9) and np.allclose(inner[1][:4], -1.4) and np.allclose(inner[0][4:], 0.1)
    assert np.allclose(outer[0][:4], -1.15) and np.allclose(outer[1][4:], 0.1)
