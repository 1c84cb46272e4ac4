"""The sole's step in the raw images against the outline (cellctl.vision.edge_step): a dark band at the foot that
both change masks took for sole."""

from __future__ import annotations

import numpy as np

from cellctl.errors import FailureKind
from cellctl.vision.edge_step import (
    INNER_STEP_RUN,
    STEP_SAMPLES_MM,
    check_inner_step,
    inner_steps,
    step_profiles,
)

SOLE_DN, TABLE_DN, BAND_DN = 58.0, 44.0, 36.0


def _profile(
    edge_mm: float,
    band_mm: float = 0.0,
    noise: float = 0.0,
    seed: int = 0,
    band_dn: float = BAND_DN,
    table_dn: float = TABLE_DN,
) -> np.ndarray:
    """A black sole (brighter than its shadowed table) whose edge lies `edge_mm` from the outline (-: inside), a
    darker band `band_mm` wide beyond it, then the table: grey levels at STEP_SAMPLES_MM, blurred like a lens."""
    fine = np.arange(-6.0, 4.0, 0.05)
    level = np.where(fine < edge_mm, SOLE_DN, np.where(fine < edge_mm + band_mm, band_dn, table_dn))
    blur = np.exp(-0.5 * (np.arange(-20, 21) * 0.05 / 0.2) ** 2)  # ~0.5 px of lens blur at 0.4 mm per pixel
    blurred = np.convolve(level, blur / blur.sum(), mode="same")
    samples = np.interp(STEP_SAMPLES_MM, fine, blurred)
    return samples + np.random.default_rng(seed).normal(0.0, noise, samples.shape)


def test_an_outline_on_the_sole_edge_shows_its_step_at_the_outline() -> None:
    """On the edge, beside a plain table or a dark band beyond it (a shadow the outline left out), with the sensor's
    noise: no point flagged."""
    profiles = np.array(
        [_profile(0.0, noise=1.0, seed=k) for k in range(20)]
        + [_profile(0.25, 1.5, noise=1.0, seed=k) for k in range(20)]
        + [_profile(-0.25, noise=1.0, seed=k) for k in range(20)]
    )
    assert not inner_steps(profiles).any()


def test_an_outline_along_a_dark_band_beside_the_sole_is_flagged() -> None:
    """The outline on the band's outer edge, the sole's step 1.5-2 mm inside it (matrix sole 39016): flagged; a
    sole's own faint texture step inside, under INNER_STEP_MIN_DN, is not."""
    band = np.array([_profile(-edge, edge, noise=1.0, seed=k) for k, edge in enumerate(np.linspace(1.25, 2.0, 20))])
    assert inner_steps(band).all()
    faint = (band - TABLE_DN) * 0.15 + TABLE_DN  # the same band at a contrast of a few grey levels only
    assert not inner_steps(faint).any()
    # A band brighter than sole and table is no shadow: the narrow top of a light rim on a black sole (47038 of set
    # 47000: black 64, rim 165, cutting mat 100-120), the rim's inner step the strongest.
    rim = [_profile(-edge, edge, 1.0, k, band_dn=165.0, table_dn=115.0) for k, edge in enumerate((1.5, 2.0))]
    assert not inner_steps(np.array(rim)).any()
    dark_rim = [_profile(-edge, edge, 1.0, k, band_dn=20.0, table_dn=30.0) for k, edge in enumerate((1.5, 2.0))]
    assert inner_steps(np.array(dark_rim)).all()  # a band darker than both sides, its outer step weak: flagged
    off = band.copy()
    off[:, :3] = np.nan  # the profile leaves the image
    assert not inner_steps(off).any()


def test_a_stretch_both_cameras_show_is_refused() -> None:
    n = 200
    left, right = np.zeros(n, bool), np.zeros(n, bool)
    left[50 : 50 + INNER_STEP_RUN] = right[50 : 50 + INNER_STEP_RUN] = True
    problem = check_inner_step(left, right)
    assert problem is not None and problem.kind is FailureKind.OUTLINE_INCONSISTENT
    assert f"along {INNER_STEP_RUN} mm from outline point 50" in problem.reason
    right[52] = False  # the cameras agree on runs of 2 and 2 only
    assert check_inner_step(left, right) is None
    only_left = np.zeros(n, bool)
    only_left[10:40] = True
    assert check_inner_step(only_left, np.zeros(n, bool)) is None
    wrapped = np.zeros(n, bool)
    wrapped[-3:] = wrapped[:3] = True  # a stretch across the closed outline's start
    assert check_inner_step(wrapped, wrapped) is not None


def test_profiles_are_sampled_along_the_normals_at_the_level() -> None:
    """A vertical step in a synthetic image, read through a projection of 0.4 mm per pixel that shifts with height:
    the samples cross it where the geometry puts it."""
    image = np.full((200, 300), TABLE_DN, np.float32)
    image[:, :150] = SOLE_DN
    ring = np.array([[60.0, 40.0], [60.0, 41.0]])  # table mm; x = 60 mm is pixel 150 at height 0
    outward = np.array([[1.0, 0.0], [1.0, 0.0]])

    def to_pixel(points: np.ndarray) -> np.ndarray:
        return np.column_stack([points[:, 0] / 0.4 - points[:, 2], points[:, 1] / 0.4])

    flat = step_profiles(ring, outward, np.zeros(2), image, to_pixel)
    assert flat.shape == (2, len(STEP_SAMPLES_MM))
    crossing = STEP_SAMPLES_MM[np.argmax(flat[0] < 0.5 * (SOLE_DN + TABLE_DN))]
    assert -0.25 <= crossing <= 0.5
    raised = step_profiles(ring, outward, np.full(2, 2.0), image, to_pixel)  # 2 px left at 2 mm: the step 0.8 mm out
    crossing = STEP_SAMPLES_MM[np.argmax(raised[0] < 0.5 * (SOLE_DN + TABLE_DN))]
    assert 0.5 <= crossing <= 1.25
    off = step_profiles(ring + [[500.0, 0.0]], outward, np.zeros(2), image, to_pixel)
    assert np.isnan(off).all()
