"""The variation matrix: each variation renders what it claims, its truth is analytic, combinations are
deterministic and exclusive, and the matrix benchmark judges a tiny set. Renders use the half-size rig."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
import pytest

from cellctl.cli import main
from cellctl.errors import FailureKind
from cellctl.eval.sole_bench import (
    SoleBenchRow,
    declared_draft,
    glue_line_steep,
    measure_scene,
    outline_error,
    retried_note,
    wall_height_true,
)
from cellctl.eval.sole_matrix import TOLERANCES, acceptance, bench_matrix, judge
from cellctl.sim.look import VARIATIONS, SceneLook, fair_refusals, look_for, rig_refusals
from cellctl.sim.matrix import (
    END_VARIATIONS,
    MATRIX_COLOURS,
    MATRIX_ENTRIES,
    MatrixSole,
    combined_soles,
    matrix_soles,
)
from cellctl.sim.render import SceneRenderer
from cellctl.sim.scene import SoleScene
from cellctl.sim.sole import SoleModel, SolePose, SoleShape
from cellctl.sim.sole_profile import FOOT_MM, LIP_FADE_MM, EdgeProfile, EndShape
from cellctl.vision.sole_result import MeasurementRefused
from tests.sim_rig import half_size_rig, write_half_size_rig


def shape_with(look: SceneLook, seed: int = 3) -> SoleShape:
    return SoleShape.random(np.random.default_rng(seed), look)


def grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64)


# ---- the registry and the matrix ----------------------------------------------------------------------


def test_looks_combine_deterministically_and_exclusively() -> None:
    look = look_for(("pointed-toe", "gain-low", "rounded-edge"), 7)
    assert look == look_for(("pointed-toe", "gain-low", "rounded-edge"), 7)
    assert look.toe == "pointed" and 0.80 <= look.right_gain <= 0.85 and 3.0 <= look.top_edge_radius_mm <= 5.0
    assert look_for(("gain-low",), 8).right_gain != look.right_gain
    assert look_for((), 7) == SceneLook()
    with pytest.raises(ValueError, match="both set toe"):
        look_for(("pointed-toe", "square-toe"), 7)
    with pytest.raises(ValueError, match="unknown variation"):
        look_for(("purple-sole",), 7)
    assert FailureKind.TOO_FEW_POINTS in fair_refusals(("pointed-toe", "heavy-noise"))
    assert fair_refusals(("pointed-toe", "rim")) == frozenset()


def test_matrix_visits_every_entry_with_colours_and_ends_mixed() -> None:
    soles = matrix_soles(2 * len(MATRIX_ENTRIES), first_seed=40)
    assert [s.primary for s in soles[: len(MATRIX_ENTRIES)]] == list(MATRIX_ENTRIES)
    assert soles == matrix_soles(2 * len(MATRIX_ENTRIES), first_seed=40)
    assert {s.color for s in soles} == set(MATRIX_COLOURS)
    assert "camouflage" in VARIATIONS and not any("camouflage" in s.variations for s in soles)
    # Every entry meets more than one colour over two rounds, and ends are mixed into other entries.
    for name in MATRIX_ENTRIES:
        assert len({s.color for s in soles if s.primary == name}) == 2
    assert sum(any(v in END_VARIATIONS for v in s.variations[1:]) for s in soles) >= len(MATRIX_ENTRIES) // 2
    for sole in soles:
        sole.look  # every combination the matrix makes is a valid one  # noqa: B018


def test_combined_soles_each_carry_every_listed_variation() -> None:
    """`bench-sole --combined`: a combination the matrix draws only by chance (a flat sole with a leaning wall),
    on every sole, colours rotating."""
    soles = combined_soles(6, 12000, ("flat", "sloped-wall"))
    assert [s.seed for s in soles] == list(range(12000, 12006))
    assert all(s.variations == ("flat", "sloped-wall") for s in soles)
    assert [s.color for s in soles] == list(MATRIX_COLOURS) * 2
    for sole in soles:
        assert sole.look.height == "flat" and 8.0 <= sole.look.wall_slope_deg <= 20.0
    assert len({s.look.wall_slope_deg for s in soles}) == len(soles)  # drawn per seed
    with pytest.raises(ValueError, match="both set height"):
        combined_soles(2, 0, ("flat", "tall"))
    with pytest.raises(ValueError, match="unknown variation"):
        combined_soles(2, 0, ("flat", "purple-sole"))


def test_a_moulds_draft_leans_from_the_table_outside_the_matrix() -> None:
    """`draft`: the wall leans 1-6 degrees from the table itself (no vertical foot), named only; the bench states
    it as a recipe would with --declared-walls (`declared_draft`), and a lean above a foot cannot be stated."""
    soles = combined_soles(6, 17000, ("draft",))
    for sole in soles:
        assert 1.0 <= sole.look.wall_slope_deg <= 6.0 and sole.look.wall_foot_mm == 0.0
    assert "draft" not in MATRIX_ENTRIES and not VARIATIONS["draft"].in_matrix
    with pytest.raises(ValueError, match="both set wall_slope_deg"):
        combined_soles(2, 0, ("draft", "sloped-wall"))
    rig = half_size_rig()
    drafted = SoleScene.random(1, "white", rig, soles[0].look)
    assert declared_draft(drafted) == soles[0].look.wall_slope_deg
    assert declared_draft(SoleScene.random(1, "white", rig, SceneLook())) == 0.0
    above_a_foot = SceneLook(wall_slope_deg=12.0, wall_foot_mm=3.0)
    assert declared_draft(SoleScene.random(1, "white", rig, above_a_foot)) is None


# ---- geometry: ends and edges ---------------------------------------------------------------------------


def test_pointed_end_is_a_wedge_with_the_drawn_tip_radius() -> None:
    shape = shape_with(SceneLook(toe="pointed"))
    end = shape.toe_end
    assert 35.0 <= end.wedge_deg <= 60.0 and 1.0 <= end.tip_radius <= 5.0
    r, half = end.tip_radius, np.radians(end.wedge_deg / 2)
    tangent = r * (1 - np.sin(half))
    d = np.array([0.05, 0.2, 0.5]) * tangent
    # Near the apex the half-width is the tip circle's; where the circle ends the sides leave at the
    # wedge's angle (then curve out to the full width: an ogive).
    for medial in (True, False):
        np.testing.assert_allclose(shape.half_width(shape.length - d, medial), np.sqrt(r * r - (r - d) ** 2), rtol=1e-6)
    near = tangent + np.array([0.001, 0.002])
    slope = np.diff(shape.half_width(shape.length - near, True)) / np.diff(near)
    assert slope[0] == pytest.approx(np.tan(half), rel=1e-2)
    model = SoleModel(shape, SolePose(0.0, 0.0, 0.0, False))
    assert model.outline_table()[:, 0].max() == pytest.approx(shape.length / 2, abs=1e-6)


@pytest.mark.parametrize("kind", ["square", "cusped", "round"])
def test_end_caps_reach_the_tip_and_differ(kind: str) -> None:
    end = EndShape.draw(kind, np.random.default_rng(1))
    t = np.array([0.0, 0.01, 0.1, 1.0])
    cap = end.cap(t)
    assert cap[0] == 0.0 and cap[-1] == pytest.approx(1.0)
    ellipse = np.sqrt(1 - (1 - t) ** 2)
    if kind == "square":
        assert cap[1] > ellipse[1]  # blunter than round
    elif kind == "cusped":
        assert cap[1] < ellipse[1]  # sharper, concave sides
    else:
        np.testing.assert_allclose(cap, ellipse)


def test_rounded_edge_profile_and_its_normals() -> None:
    profile = EdgeProfile(0.0, 4.0)
    top, bottom = np.full(4, 25.0), np.zeros(4)
    z = profile.height(np.array([0.0, 2.0, 4.0, 9.0]), top, bottom)
    np.testing.assert_allclose(z, [21.0, 21.0 + np.sqrt(16 - 4), 25.0, 25.0])
    shape = replace(shape_with(SceneLook()), edge=profile)
    model = SoleModel(shape, SolePose(5.0, -3.0, 30.0, True))
    # A point about 2 mm inside the lateral edge at mid-length: on the fillet, whose surface leans out by
    # asin((r - d) / r) at distance d from the outline (plus the top's own slope of a degree or two).
    u = np.array([0.5 * shape.length])
    edge_v = shape.centre_line(u) - shape.half_width(u, False)
    xy = model.pose.to_table(np.column_stack([u, edge_v + 2.0]), shape.length)
    d = shape.edge_distance(u, edge_v + 2.0)[0]
    assert 1.5 < d <= 2.0
    tilt = np.degrees(np.arccos(model.top_normal_at(xy)[0, 2]))
    assert tilt == pytest.approx(np.degrees(np.arcsin((4 - d) / 4)), abs=2.0)
    plain = SoleModel(replace(shape, edge=EdgeProfile()), model.pose)
    drop = plain.top_height_at(xy)[0] - model.top_height_at(xy)[0]
    assert drop == pytest.approx(4 - np.sqrt(16 - (4 - d) ** 2), abs=1e-6)


def test_a_cupsoles_lip_raises_the_top_towards_the_outline() -> None:
    """`lipped-edge` (named only): a smoothstep rise of lip_mm over lip_width_mm, level at both of its ends, in the
    truth's heights and normals and in the mesh the renderer casts rays at."""
    profile = EdgeProfile(lip_mm=3.0, lip_width_mm=8.0)
    z = profile.height(np.array([0.0, 4.0, 8.0, 20.0]), np.full(4, 25.0), np.zeros(4))
    np.testing.assert_allclose(z, [28.0, 26.5, 25.0, 25.0])
    look = look_for(("lipped-edge",), 3)
    assert 1.5 <= look.top_lip_mm <= 4.0 and 5.0 <= look.top_lip_width_mm <= 12.0
    assert "lipped-edge" not in MATRIX_ENTRIES
    with pytest.raises(ValueError, match="lip"):
        SceneLook(top_lip_mm=2.0)
    shape = replace(shape_with(SceneLook()), edge=profile, cross_curvature=0.0)  # the top level across
    model = SoleModel(shape, SolePose(5.0, -3.0, 30.0, True))
    u = np.array([0.5 * shape.length])
    edge_v = shape.centre_line(u) - shape.half_width(u, False)
    xy = model.pose.to_table(np.column_stack([u, edge_v + 2.0]), shape.length)
    d = shape.edge_distance(u, edge_v + 2.0)[0]
    plain = SoleModel(replace(shape, edge=EdgeProfile()), model.pose)
    t = 1.0 - d / 8.0
    assert model.top_height_at(xy)[0] - plain.top_height_at(xy)[0] == pytest.approx(3.0 * t * t * (3 - 2 * t))
    # 2 mm in, the lip adds a slope of 6 t (1 - t) x 3 / 8 (about 0.4: 20 degrees) to the top's own, across the edge.
    lipped, level = (-n[0, :2] / n[0, 2] for n in (model.top_normal_at(xy), plain.top_normal_at(xy)))
    assert np.linalg.norm(lipped - level) == pytest.approx(6 * t * (1 - t) * 3.0 / 8.0, rel=0.02)
    _assert_mesh_is_the_surface(SoleModel(shape_with(replace(look, height="tall")), SolePose(0.0, 0.0, 20.0, False)))
    # `heel-cup`: the lip round the heel only, faded out over LIP_FADE_MM beyond its share of the length.
    cup = look_for(("heel-cup",), 3)
    assert 0.25 <= cup.top_lip_heel_share <= 0.35 and "heel-cup" not in MATRIX_ENTRIES
    cupped = replace(shape, edge=EdgeProfile(lip_mm=3.0, lip_width_mm=8.0, lip_reach_mm=0.3 * shape.length))
    u = np.array([0.2, 0.3, 0.6]) * shape.length + np.array([0.0, LIP_FADE_MM / 2, 0.0])
    edge_v = cupped.centre_line(u) - cupped.half_width(u, False)
    rise = cupped.surface_height(u, edge_v + 0.01) - shape.top_height(u, edge_v + 0.01)
    np.testing.assert_allclose(rise, [3.0, 1.5, 0.0], atol=0.05)


def test_sloped_wall_rises_from_its_foot() -> None:
    profile = EdgeProfile(15.0, 0.0)
    dist = np.array([0.0, 3.0, 50.0])
    z = profile.height(dist, np.full(3, 30.0), np.zeros(3))
    np.testing.assert_allclose(z, [FOOT_MM, FOOT_MM + 3.0 / np.tan(np.radians(15.0)), 30.0])
    # A wall leaning from the table up (no vertical foot): the outline is where it meets the table.
    from_table = EdgeProfile(15.0, 0.0, foot_mm=0.0).height(dist, np.full(3, 30.0), np.zeros(3))
    np.testing.assert_allclose(from_table, [0.0, 3.0 / np.tan(np.radians(15.0)), 30.0])


def test_sloped_walls_lean_from_the_table_up_to_a_four_mm_foot() -> None:
    feet = [look_for(("sloped-wall",), seed).wall_foot_mm for seed in range(40)]
    assert 0.0 <= min(feet) < 0.5 and FOOT_MM - 0.5 < max(feet) <= FOOT_MM
    assert SceneLook().wall_foot_mm == FOOT_MM  # other looks keep the foot every sloped wall had before


def test_mesh_follows_the_edge_profile() -> None:
    look = SceneLook(toe="pointed", heel="square", wall_slope_deg=12.0, top_edge_radius_mm=4.0, height="tall")
    _assert_mesh_is_the_surface(SoleModel(shape_with(look), SolePose(0.0, 0.0, 20.0, False)))


def _assert_mesh_is_the_surface(model: SoleModel) -> None:
    """Rays cast down at the model's mesh 1-15 mm inside its outline hit its top surface's true heights."""
    vertices, triangles, _ = model.mesh()
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(triangles)
    scene.add_triangles(mesh)
    outline = model.outline_table(300)
    centroid = outline.mean(axis=0)
    # Probes 1-15 mm inside the outline, on the profile, all round the sole.
    inward = centroid - outline
    inward /= np.linalg.norm(inward, axis=1, keepdims=True)
    probes = np.vstack([outline + d * inward for d in (1.0, 3.0, 6.0, 15.0)])
    rays = np.column_stack([probes, np.full(len(probes), 300.0), np.zeros((len(probes), 2)), -np.ones(len(probes))])
    hit_z = 300.0 - scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"].numpy()
    true_z = model.top_height_at(probes)
    inside = np.isfinite(hit_z)
    assert inside.mean() > 0.95
    assert np.median(np.abs(hit_z - true_z)[inside]) < 0.05
    assert np.percentile(np.abs(hit_z - true_z)[inside], 95) < 0.3


@pytest.mark.parametrize(("height", "heel_range"), [("flat", (5.0, 8.0)), ("tall", (38.0, 52.0))])
def test_height_classes(height: str, heel_range: tuple[float, float]) -> None:
    for seed in range(4):
        truth = SoleModel(shape_with(SceneLook(height=height), seed), SolePose(0, 0, 0, False)).truth()
        low, high = heel_range
        assert low <= max(truth.heel_height_mm, truth.toe_height_mm) <= high


@pytest.mark.parametrize(("variation", "low", "high"), [("small-sole", 170.0, 240.0), ("large-sole", 300.0, 340.0)])
def test_sole_sizes_outside_the_matrix(variation: str, low: float, high: float) -> None:
    """The matrix's soles are 240-300 mm long; small-sole and large-sole draw other lengths from the same shapes
    (the true length is the model's, so within a mm of the drawn one), and a plain look draws as it always did."""
    lengths = []
    for seed in range(6):
        shape = shape_with(look_for((variation,), seed), seed)
        lengths.append(SoleModel(shape, SolePose(0, 0, 0, False)).truth().length_mm)
    assert low - 1.0 <= min(lengths) and max(lengths) <= high + 1.0
    assert variation not in MATRIX_ENTRIES and not fair_refusals((variation,))
    # The plain draws of every earlier session (the rendered matrices' soles): the size switch took no draw.
    assert [shape_with(SceneLook(), seed).length for seed in range(3)] == pytest.approx(
        [278.218, 270.709, 255.697], abs=1e-3
    )
    with pytest.raises(ValueError, match="size"):
        SceneLook(size="huge")


@pytest.mark.parametrize(("variation", "low", "high"), [("narrow-sole", 0.28, 0.32), ("wide-sole", 0.40, 0.46)])
def test_sole_widths_outside_the_matrix(variation: str, low: float, high: float) -> None:
    """The ball's width as a share of the length: 34-38 % in the matrix, narrower or wider here."""
    for seed in range(6):
        shape = shape_with(look_for((variation,), seed), seed)
        assert low <= 2 * shape.ball_half_width / shape.length <= high
        assert 2 * shape_with(SceneLook(), seed).ball_half_width / shape.length == pytest.approx(0.36, abs=0.021)
    assert variation not in MATRIX_ENTRIES and not fair_refusals((variation,))


def test_a_waisted_sole_cuts_its_arch_deeper_on_a_curved_last() -> None:
    """The waisted sole's arch cuts 38-50 % of the ball's half-width in on the medial side and its toe swings 3-6 %
    of the length over; its waist is narrower than the plain draw's of the same seed, and a plain look draws as it
    always did (the switch takes no draw)."""
    for seed in range(6):
        plain = shape_with(SceneLook(), seed)
        waisted = shape_with(look_for(("waisted-sole",), seed), seed)
        assert 0.38 <= waisted.medial_arch / waisted.ball_half_width <= 0.50
        assert 0.10 <= waisted.lateral_arch / waisted.ball_half_width <= 0.20
        assert 0.03 <= waisted.toe_shift / waisted.length <= 0.06
        u = np.linspace(0.3, 0.6, 31) * waisted.length
        waist = np.min(waisted.half_width(u, True) + waisted.half_width(u, False))
        assert waist < np.min(plain.half_width(u, True) + plain.half_width(u, False)) - 0.05 * waisted.ball_half_width
        assert waist > 0.5 * waisted.ball_half_width  # still a sole, not two
    assert [round(shape_with(SceneLook(), seed).medial_arch, 3) for seed in range(3)] == [13.38, 13.218, 11.491]
    assert "waisted-sole" not in MATRIX_ENTRIES and not fair_refusals(("waisted-sole",))
    with pytest.raises(ValueError, match="waist"):
        SceneLook(waist="hourglass")


def test_a_sprung_toe_lifts_the_forefoot_off_the_table() -> None:
    """A running shoe's toe spring: the underside 10-16 mm off the table at the toe's height point (the matrix's 1-8),
    the forefoot as thick as the plain draw's there, so the toe stands higher by the extra lift."""
    for seed in range(6):
        plain = shape_with(SceneLook(), seed)
        sprung = shape_with(look_for(("sprung-toe",), seed), seed)
        toe_point = np.array([0.9 * sprung.length])
        lift = float(sprung.underside(toe_point)[0])
        assert 10.0 <= lift <= 16.0 and float(plain.underside(toe_point)[0]) <= 8.0 + 1e-9
        middle = sprung.centre_line(toe_point)
        thickness = sprung.top_height(toe_point, middle) - sprung.underside(toe_point)
        assert thickness == pytest.approx(plain.top_height(toe_point, middle) - plain.underside(toe_point))
        assert sprung.underside(np.array([0.5 * sprung.length]))[0] == 0.0  # the heel and waist lie on the table
    assert "sprung-toe" not in MATRIX_ENTRIES and not fair_refusals(("sprung-toe",))


@pytest.mark.parametrize(("variation", "low", "high"), [("dished-top", -6.0, -3.0), ("domed-top", 2.0, 4.0)])
def test_a_dished_or_domed_top_curves_across_the_sole(variation: str, low: float, high: float) -> None:
    """The top's edge at the ball stands |c| above (dished) or below (domed) its middle, 3-6 or 2-4 mm, where the
    matrix's tops curve within 1.5 mm; the sole keeps its edge thickness, and the later draws are the plain ones."""
    for seed in range(6):
        shape = shape_with(look_for((variation,), seed), seed)
        assert low <= shape.cross_curvature <= high
        u = np.array([0.7 * shape.length])
        middle = shape.centre_line(u)
        edge = middle + shape.half_width(u, True)
        rise = shape.top_height(u, edge) - shape.top_height(u, middle)
        across = shape.half_width(u, True) / (1.05 * shape.ball_half_width)
        assert rise == pytest.approx(-shape.cross_curvature * across**2)
        assert shape.top_height(u, edge) - shape.underside(u) >= 5.0 - 1e-9  # sole.MIN_EDGE_THICKNESS_MM
        assert shape.length == shape_with(SceneLook(), seed).length
    assert variation not in MATRIX_ENTRIES and not fair_refusals((variation,))


# ---- appearance -----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rim_gain_noise() -> tuple[SoleScene, object]:
    look = look_for(("rim", "gain-low", "heavy-noise"), 11)
    scene = SoleScene.random(11, "white", half_size_rig(), look)
    return scene, scene.render()


def test_gain_darkens_the_right_camera(rim_gain_noise) -> None:  # noqa: ANN001
    scene, pair = rim_gain_noise
    ratio = grey(pair.right).mean() / grey(pair.left).mean()
    assert ratio == pytest.approx(scene.look.right_gain, abs=0.03)
    assert ratio < 0.9


def test_rim_is_dark_round_a_white_sole(rim_gain_noise) -> None:  # noqa: ANN001
    _, pair = rim_gain_noise
    mask = pair.sole_mask_left.astype(np.uint8)
    image = cv2.GaussianBlur(grey(pair.left), (0, 0), 1.5)  # heavy noise: compare local means
    band = (cv2.erode(mask, np.ones((3, 3), np.uint8)) > 0) & ~(
        cv2.erode(mask, np.ones((5, 5), np.uint8), iterations=1) > 0
    )
    interior = cv2.erode(mask, np.ones((31, 31), np.uint8)) > 0
    assert np.median(image[band]) < 50 < 120 < np.median(image[interior])


def test_heavy_noise_is_heavy(rim_gain_noise) -> None:  # noqa: ANN001
    scene, pair = rim_gain_noise
    plain = SoleScene.random(11, "white", half_size_rig(), replace(scene.look, noise="normal")).render()
    table = ~(cv2.dilate(pair.sole_mask_left.astype(np.uint8), np.ones((41, 41), np.uint8)) > 0)
    # The same scene with normal noise differs only by noise: ~1.3 DN per channel normally, ~6.5 DN heavy.
    difference = pair.left.astype(np.float64) - plain.left.astype(np.float64)
    assert np.std(difference[table]) > 4.0
    assert abs(np.mean(difference[table])) < 0.5


def test_moderate_noise_scales_the_sensors_noise() -> None:
    """Two exposures of one scene differ by the sensor alone; with moderate noise by noise_scale times as much."""
    from cellctl.sim.render_cache import render_exposures

    look = look_for(("moderate-noise",), 11)
    assert 1.5 <= look.noise_scale <= 3.5 and look.noise == "normal"
    spreads = []
    for scale in (1.0, look.noise_scale):
        scene = SoleScene.random(11, "grey", half_size_rig(), replace(look, noise_scale=scale))
        first, second = render_exposures(scene, [0, -1])
        spreads.append(np.std(first.left.astype(np.float64) - second.left.astype(np.float64)))
    assert spreads[1] / spreads[0] == pytest.approx(look.noise_scale, rel=0.1)


def test_soft_focus_blurs_each_camera_by_its_own_amount() -> None:
    """Each camera's image loses fine contrast by its own drawn defocus: the sharper camera keeps more of the
    table's texture gradient, both keep less than an in-focus pair of the same scene."""
    look = look_for(("soft-focus",), 5)
    assert 0.3 <= look.left_defocus_px <= 1.2 and 0.3 <= look.right_defocus_px <= 1.2
    assert look.left_defocus_px != look.right_defocus_px

    def sharpness(image: np.ndarray) -> float:
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY).astype(np.float64)
        return float(np.mean(np.abs(cv2.Laplacian(grey, cv2.CV_64F))))

    sharp = SoleScene.random(5, "white", half_size_rig(), replace(look, left_defocus_px=0.0, right_defocus_px=0.0))
    soft = SoleScene.random(5, "white", half_size_rig(), look)
    sharp_pair, soft_pair = sharp.render(), soft.render()
    left, right = (
        sharpness(soft_pair.left) / sharpness(sharp_pair.left),
        sharpness(soft_pair.right) / sharpness(sharp_pair.right),
    )
    assert left < 0.95 and right < 0.95
    assert (left < right) == (look.left_defocus_px > look.right_defocus_px)


def test_dim_exposure_darkens_both_cameras_by_the_drawn_factor() -> None:
    look = look_for(("dim-exposure",), 7)
    assert 0.4 <= look.exposure_scale <= 0.8
    bright = SoleScene.random(7, "white", half_size_rig(), replace(look, exposure_scale=1.0)).render()
    dim = SoleScene.random(7, "white", half_size_rig(), look).render()
    for a, b in ((dim.left, bright.left), (dim.right, bright.right)):
        assert float(np.mean(a)) / float(np.mean(b)) == pytest.approx(look.exposure_scale, rel=0.05)


def test_side_light_casts_the_soles_shadow() -> None:
    look = SceneLook(shadows=True, height="tall")
    scene = SoleScene.random(2, "black", half_size_rig(), look)
    renderer = SceneRenderer(scene.calib, scene.camera_pose, scene.sole, "black", 2, look)
    assert scene.sole is not None
    outline = scene.sole.outline_table(400)
    side_light = renderer.lights[-1]
    # Table points just beyond the outline on the side away from the side light are in its shadow;
    # points on the side facing it are lit.
    centre = outline.mean(axis=0)
    direction = (outline - centre) / np.linalg.norm(outline - centre, axis=1, keepdims=True)
    to_light = (side_light[:2] - centre) / np.linalg.norm(side_light[:2] - centre)
    facing = direction @ to_light
    beyond = outline + 3.0 * direction
    points = np.column_stack([beyond, np.zeros(len(beyond))])
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))
    lit = renderer.rays.unshadowed(points, normals, np.ones(len(points), bool), renderer.lights)
    # The outline is concave at the arch, so only the clearest cases are asserted: the point most facing the
    # light is lit, the one most turned away is not, and the far side is mostly in shadow.
    assert lit[-1][np.argmax(facing)] and not lit[-1][np.argmin(facing)]
    assert lit[-1][facing < -0.7].mean() < 0.1
    assert lit[0].mean() > lit[-1].mean()  # the high LED bars throw far shorter shadows


def test_camouflaged_sole_has_the_tables_colour() -> None:
    from cellctl.sim.appearance import TABLES, ColourScheme

    look = look_for(("camouflage",), 1)
    scheme = ColourScheme.draw(np.random.default_rng(0), "black", look, shape_with(look))
    assert scheme.base == TABLES["grey"].albedo_bgr and look.table == "grey"
    assert fair_refusals(("camouflage",)) == {FailureKind.COLOURS_TOO_SIMILAR}


def test_faint_texture_is_the_same_pattern_fainter() -> None:
    """faint-texture scales the sole's texture octaves (the same draws: the pattern stays, its contrast drops) and
    leaves the albedo; out of the matrix, its fair refusals are the lost surface's."""
    from cellctl.sim.appearance import SOLE_MATERIALS, Texture, sole_material

    look = look_for(("faint-texture",), 4)
    assert 0.5 <= look.texture_contrast <= 0.65 and "faint-texture" not in MATRIX_ENTRIES
    plain, faint = sole_material("black", SceneLook()), sole_material("black", look)
    assert faint.albedo_bgr == plain.albedo_bgr
    textures = [
        Texture.fractal(np.random.default_rng(1), (0.0, 0.0), (60.0, 40.0), 0.2, m.octaves) for m in (plain, faint)
    ]
    deviation = [t.image - t.image.mean() for t in textures]
    np.testing.assert_allclose(deviation[1].std() / deviation[0].std(), look.texture_contrast, rtol=0.02)
    assert np.corrcoef(deviation[0].ravel(), deviation[1].ravel())[0, 1] > 0.999
    assert fair_refusals(("faint-texture",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}
    assert plain is SOLE_MATERIALS["black"]  # the default look renders exactly as before the variation existed


def test_ambient_occlusion_darkens_the_table_at_the_foot_over_about_the_wall_height() -> None:
    """ambient-occlusion: beside the sole the table gets the room's light less the share of the sky the sole hides,
    about half at its foot, fading over about the wall's height (so further beside the tall heel than the thin
    toe), none under the sole or far away; out of the matrix, measurable (no fair refusal)."""
    from cellctl.sim.occlusion import sky_fraction
    from cellctl.sim.rig import default_rig

    look = look_for(("ambient-occlusion",), 3)
    assert 0.6 <= look.ambient_occlusion <= 1.0 and "ambient-occlusion" not in MATRIX_ENTRIES
    assert fair_refusals(("ambient-occlusion",)) == frozenset()
    sole = SoleScene.random(5, "black", default_rig(), SceneLook()).sole
    assert sole is not None
    outline = sole.footprint_table()
    centre = outline.mean(axis=0)
    axis = np.linalg.svd(outline - centre, full_matrices=False)[2][0]
    along = (outline - centre) @ axis
    ends = {}
    for name, index in (("heel", int(np.argmin(along))), ("toe", int(np.argmax(along)))):
        out = outline[index] - centre
        out /= np.linalg.norm(out)
        steps = np.array([-10.0, 0.3, 2.0, 5.0, 10.0, 20.0, 40.0, 140.0])
        ends[name] = sky_fraction(sole, outline[index] + steps[:, None] * out, 1.0)
        heights = sole.top_height_at(outline[index] - 5.0 * out[None, :])
        assert ends[name][0] == 1.0 and ends[name][-1] > 0.97  # under the sole; far away
        assert 0.5 <= ends[name][1] < 0.6 and np.all(np.diff(ends[name][1:]) > 0)
        ends[name] = (ends[name], float(heights[0]))
        foot = outline[index : index + 1] + 0.3 * out
        half = sky_fraction(sole, foot, 0.5)
        np.testing.assert_allclose(1.0 - half, 0.5 * (1.0 - sky_fraction(sole, foot, 1.0)), rtol=1e-5)
    (heel, heel_height), (toe, toe_height) = ends["heel"], ends["toe"]
    if heel_height < toe_height:
        heel, toe = toe, heel
    assert np.all(heel[3:7] < toe[3:7])  # the taller end's band reaches further
    assert SceneLook().ambient_occlusion == 0.0  # the default look renders exactly as before the variation existed
    with pytest.raises(ValueError, match="ambient occlusion"):
        SceneLook(ambient_occlusion=1.5)


def test_satin_is_a_broad_sheen_that_differs_between_the_views() -> None:
    """satin replaces the material's weak specular lobe by a broad one: under the cell's bars it lights most of a
    flat top (gloss only a quarter of it, in small saturated spots), adds more than half a black sole's diffuse
    light, and two eyes 60 mm apart see it differently, several times as much as the material's own lobe; albedo
    and texture stay. Out of the matrix, its fair refusals are the lost surface's."""
    from cellctl.sim.appearance import LIGHTS_MM, SOLE_MATERIALS, sole_material
    from cellctl.sim.render import AMBIENT, _lighting

    look = look_for(("satin",), 5)
    assert 0.12 <= look.sheen_weight <= 0.30 and 12.0 <= look.sheen_shininess <= 50.0
    assert "satin" not in MATRIX_ENTRIES
    assert fair_refusals(("satin",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}
    x, y = np.meshgrid(np.linspace(-140.0, 140.0, 57), np.linspace(-60.0, 60.0, 25))
    top = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 25.0)])
    up = np.tile([0.0, 0.0, 1.0], (len(top), 1))

    def radiance(look: SceneLook) -> tuple[np.ndarray, np.ndarray, float]:
        """(left and right eyes' radiance, specular part seen from the left, diffuse mean) of a black top."""
        material = sole_material("black", look)
        seen = []
        for eye in ([-30.0, 0.0, 550.0], [30.0, 0.0, 550.0]):
            shininess = np.full(len(top), material.shininess, np.float32)
            diffuse, highlight = _lighting(top, up, np.array(eye), shininess, LIGHTS_MM, np.ones(2))
            seen.append((material.albedo_bgr[1] * (AMBIENT + diffuse), material.specular * highlight))
        difference = np.abs(sum(seen[0]) - sum(seen[1]))
        return difference, seen[0][1], float(seen[0][0].mean())

    plain_difference, _, _ = radiance(SceneLook())
    satin_difference, sheen, diffuse = radiance(look)
    _, gloss, _ = radiance(SceneLook(gloss=True))
    assert np.mean(sheen > sheen.max() / 2) > 0.9 and np.mean(gloss > gloss.max() / 2) < 0.5
    assert sheen.max() > 0.5 * diffuse
    assert satin_difference.mean() > 3.0 * plain_difference.mean()
    satin = sole_material("black", look)
    assert satin.albedo_bgr == SOLE_MATERIALS["black"].albedo_bgr and satin.octaves == SOLE_MATERIALS["black"].octaves
    assert SceneLook().sheen_weight == 0.0  # the default look renders exactly as before the variation existed
    with pytest.raises(ValueError, match="sheen"):
        SceneLook(sheen_weight=0.2)


def test_any_heading_turns_the_sole_across_the_image_rows() -> None:
    """The matrix's soles lie along the image rows (within 35 degrees, either way round); any-heading draws the
    whole circle, so some lie across them. Out of the matrix, judged like any entry."""

    def off_rows(look: SceneLook) -> np.ndarray:
        yaws = [SoleScene.random(seed, "white", half_size_rig(), look).sole.pose.yaw_deg for seed in range(24)]  # type: ignore[union-attr]
        return np.abs((np.asarray(yaws) + 90.0) % 180.0 - 90.0)  # 0: along the rows, 90: across

    assert off_rows(SceneLook()).max() <= 35.0
    across = off_rows(look_for(("any-heading",), 0))
    assert across.max() > 60.0 and "any-heading" not in MATRIX_ENTRIES and not fair_refusals(("any-heading",))


def test_other_rigs_keep_the_cameras_and_change_the_baseline() -> None:
    from cellctl.sim.rig import BASELINE_MM, NARROW_BASELINE_MM, WIDE_BASELINE_MM, default_rig, rig_for

    baseline = {name: float(np.linalg.norm(rig_for(name).T)) for name in ("default", "wide", "narrow")}
    assert baseline == pytest.approx({"default": BASELINE_MM, "wide": WIDE_BASELINE_MM, "narrow": NARROW_BASELINE_MM})
    np.testing.assert_array_equal(rig_for("wide").K1, default_rig().K1)
    assert look_for(("wide-rig",), 0).rig == "wide" and look_for(("narrow-rig",), 0).rig == "narrow"
    assert fair_refusals(("narrow-rig",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}


def test_coarse_and_fine_rigs_see_the_same_field_through_fewer_or_more_pixels() -> None:
    """The `coarse` and `fine` rigs are the default's cameras with 0.75 and 1.25 times the pixels along each side:
    a table point lands on the same place of the field, its pixel position scaled about the pixel grid's corner."""
    from cellctl.sim.render import project, rig_pose
    from cellctl.sim.rig import COARSE_SCALE, FINE_SCALE, default_rig, rig_for

    points = np.array([[0.0, 0.0, 0.0], [140.0, -90.0, 0.0], [-150.0, 60.0, 45.0]])
    default = default_rig()
    for name, scale, size in (("coarse", COARSE_SCALE, (960, 768)), ("fine", FINE_SCALE, (1600, 1280))):
        rig = rig_for(name)
        assert rig.image_size == size
        for side in ("left", "right"):
            expected = (project(default, rig_pose(default), side, points) + 0.5) * scale - 0.5
            np.testing.assert_allclose(project(rig, rig_pose(rig), side, points), expected, atol=1e-6)
    assert look_for(("coarse-rig",), 0).rig == "coarse" and look_for(("fine-rig",), 0).rig == "fine"
    assert fair_refusals(("coarse-rig",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}
    assert not fair_refusals(("fine-rig",))


def test_near_and_far_rigs_see_the_same_table_from_another_height() -> None:
    """The `near` and `far` rigs are mounted lower and higher with lenses that keep the table's field (within the
    tilt's and the baseline's offsets), so what changes is how far a raised point moves in the image (the views'
    obliqueness), and the depth range a line would set holds the table with room for the tallest sole."""
    from cellctl.sim.render import project, rig_pose
    from cellctl.sim.rig import depth_range_for, rig_for, rig_height_for

    table = np.array([[0.0, 0.0, 0.0], [150.0, 100.0, 0.0], [-150.0, -100.0, 0.0]])
    raised = table + [0.0, 0.0, 40.0]

    def seen(name: str, points: np.ndarray) -> np.ndarray:
        calib = rig_for(name)
        return project(calib, rig_pose(calib, rig_height_for(name)), "left", points)

    parallax = {}
    for name in ("near", "default", "far"):
        assert np.abs(seen(name, table) - seen("default", table)).max() < 25.0  # 2 % of the image
        parallax[name] = float(np.linalg.norm(seen(name, raised)[1:] - seen(name, table)[1:], axis=1).mean())
        low, high = depth_range_for(name)
        assert low <= rig_height_for(name) - 60.0 and rig_height_for(name) + 20.0 <= high
    assert parallax["near"] > 1.2 * parallax["default"] > 1.2**2 * parallax["far"]
    assert look_for(("near-rig",), 0).rig == "near" and look_for(("far-rig",), 0).rig == "far"
    assert fair_refusals(("far-rig",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}


def test_off_image_sole_is_cut_by_an_image_edge_and_refused_for_it() -> None:
    """An end of the sole crosses an image's edge (by at most OFF_IMAGE_PX): no valid length exists, and the only
    right answer is the border refusal, which the measurement gives."""
    from cellctl.sim.scene import OFF_IMAGE_PX

    look = look_for(("off-image",), 5)
    scene = SoleScene.random(5, "white", half_size_rig(), look)
    assert not scene.in_view(0.0) and scene.in_view(-OFF_IMAGE_PX)
    assert fair_refusals(("off-image",)) == {FailureKind.SOLE_AT_BORDER}
    (result,) = bench_matrix([MatrixSole(5, "white", ("off-image",))], half_size_rig())
    assert result.verdict == "fair refusal" and result.row.failure == FailureKind.SOLE_AT_BORDER.value


def test_light_table_is_a_white_plate_outside_the_matrix() -> None:
    from cellctl.sim.appearance import SOLE_MATERIALS, TABLES

    look = look_for(("light-table",), 2)
    assert look.table == "light" and "light-table" not in MATRIX_ENTRIES
    assert min(TABLES["light"].albedo_bgr) > max(SOLE_MATERIALS["white"].albedo_bgr)  # brighter than any sole
    left = grey(SoleScene.random(2, "black", half_size_rig(), look).render().left)
    assert np.median(left) > 150  # the plate fills most of the view


def test_other_lights_keep_the_tables_exposure_and_shade_the_walls_otherwise() -> None:
    """other-lights draws a layout the cell never had, out of the matrix and judged like any entry. The renderer
    normalises each layout to the same light at the table's origin, so exposure holds; a side bar lights the
    walls facing it and shades those turned away, which the bars (one each side) never do."""
    from cellctl.sim.appearance import lights

    drawn = {look_for(("other-lights",), seed).lighting for seed in range(20)}
    assert drawn == {"shadowed-bars", "ring", "overhead", "side"} and "other-lights" not in MATRIX_ENTRIES
    assert not fair_refusals(("other-lights",))
    for lighting in ("shadowed-bars", "ring", "overhead", "side"):
        assert lights(SceneLook(lighting=lighting))[1].sum() == pytest.approx(2.0)
    assert lights(SceneLook(lighting="side", shadows=True))[0].shape == (3, 3)  # the shadows' lamp as well
    from cellctl.sim.render import AMBIENT, _lighting

    def diffuse(look: SceneLook, normals: np.ndarray) -> np.ndarray:
        positions, power = lights(look)
        points, eye = np.zeros((len(normals), 3)), np.array([0.0, 0.0, 550.0])
        return _lighting(points, normals, eye, np.ones(len(normals)), positions, power)[0]

    up, facing, away = np.eye(3)[2], np.eye(3)[0], -np.eye(3)[0]  # the table; walls facing +x and -x
    for look in (SceneLook(), SceneLook(lighting="ring"), SceneLook(lighting="side", light_azimuth_deg=0.0)):
        assert diffuse(look, up[None])[0] == pytest.approx(1.0 - AMBIENT, rel=1e-5)  # the same exposure
    bars = diffuse(SceneLook(), np.array([facing, away]))
    assert bars[0] == pytest.approx(bars[1], rel=1e-5)  # the bars light both sides alike
    side = diffuse(SceneLook(lighting="side", light_azimuth_deg=0.0), np.array([facing, away]))
    assert side[0] > 0.3 and side[1] == 0.0  # the side bar lights one side's walls only
    ring = diffuse(SceneLook(lighting="ring"), np.array([facing]))
    assert ring[0] < 0.5 * bars[0]  # a ring round the lenses grazes the walls
    with pytest.raises(ValueError, match="lighting"):
        SceneLook(lighting="sun")
    with pytest.raises(ValueError, match="ambient"):
        SceneLook(ambient_scale=0.0)


def test_a_matrix_sole_relit_keeps_everything_but_its_lights() -> None:
    """`cellctl bench-sole --matrix --lighting NAME`: the same soles, only their lights replaced (the matrix's bars
    cast no shadow; shadowed-bars are the same bars casting theirs), also over a variation that sets the lights."""
    for sole in matrix_soles(30, 500)[:30]:
        relit = replace(sole, lighting="shadowed-bars")
        assert relit.look == replace(sole.look, lighting="shadowed-bars") and relit.label == sole.label
    lit = MatrixSole(7, "grey", ("other-lights",))
    assert replace(lit, lighting="ring").look == replace(lit.look, lighting="ring")
    assert MatrixSole(7, "grey", ("plain",)).look.lighting == "bars"


def test_a_matrix_sole_through_another_rig_keeps_its_scene_and_gains_the_rigs_fair_refusals() -> None:
    """`cellctl bench-sole --matrix --rig NAME`: the same soles shot through other cameras, also over a variation
    that sets the rig; a coarse rig's surface refusals become fair, a fine rig's add none."""
    for sole in matrix_soles(30, 500)[:30]:
        coarse = replace(sole, rig="coarse")
        assert coarse.look == replace(sole.look, rig="coarse") and coarse.label == sole.label
        assert coarse.fair_refusals == sole.fair_refusals | {
            FailureKind.TOO_FEW_POINTS,
            FailureKind.SURFACE_NOT_MEASURED,
        }
        assert replace(sole, rig="fine").fair_refusals == sole.fair_refusals
    distorted = MatrixSole(7, "grey", ("distorted-rig",))
    assert replace(distorted, rig="fine").look == replace(distorted.look, rig="fine")
    with pytest.raises(ValueError, match="rig must be one of"):
        rig_refusals("pinhole")


def test_knurled_top_repeats_along_its_axes_out_of_the_matrix() -> None:
    """knurled-top multiplies the sole's texture by a grid of bumps: the same brightness one period along either
    axis of the grid, other brightness half a period along; out of the matrix, a lost surface is a fair refusal."""
    from cellctl.sim.appearance import Texture

    look = look_for(("knurled-top",), 6)
    assert 1.5 <= look.knurl_period_mm <= 4.0 and 0.06 <= look.knurl_contrast <= 0.15
    assert "knurled-top" not in MATRIX_ENTRIES
    assert fair_refusals(("knurled-top",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}
    flat = Texture(np.ones((400, 400), np.float32), (0.0, 0.0), 0.1)
    knurl = flat.with_knurl(3.0, 30.0, 0.12)
    axis = np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0))])
    start = 21.75 * axis + 12.75 * np.array([-axis[1], axis[0]])  # a quarter period past whole ones on both axes
    along = [knurl.sample(*(start + k * 3.0 * axis)[:, None]) for k in (0.0, 0.5, 1.0, 2.0)]
    assert along[0] == pytest.approx(along[2], abs=0.01) and along[0] == pytest.approx(along[3], abs=0.01)
    assert abs(float(along[0][0] - along[1][0])) > 0.1  # half a period along: the other sign of the bump
    assert SceneLook().knurl_period_mm == 0.0  # the default look renders as before the variation existed
    with pytest.raises(ValueError, match="knurl"):
        SceneLook(knurl_period_mm=2.0, knurl_contrast=1.5)


def test_patterned_table_has_strong_contrast() -> None:
    rng = np.random.default_rng(0)
    from cellctl.sim.appearance import table_texture

    plain, patterned = table_texture(rng, SceneLook()), table_texture(rng, SceneLook(table="patterned"))
    assert patterned.image.std() > 2.5 * plain.image.std()


# ---- the matrix benchmark -------------------------------------------------------------------------------


def _row(**errors: float) -> SoleBenchRow:
    values = {name: 0.0 for name in TOLERANCES} | errors
    return SoleBenchRow(1, "white", 250.0, True, None, seconds=1.0, **values)  # type: ignore[arg-type]


def test_judging_valid_and_refused_results() -> None:
    sole = MatrixSole(1, "white", ("heavy-noise",))
    assert judge(sole, _row()).verdict == "right"
    wrong = judge(sole, _row(length_error_mm=-1.2, glue_normal_error_max_deg=6.0))
    assert wrong.verdict == "WRONG" and wrong.out_of_tolerance == ("length_error_mm", "glue_normal_error_max_deg")
    refused = SoleBenchRow(1, "white", 250.0, False, "few", *(None,) * 6, 1.0, "heavy-noise", "too_few_points")
    assert judge(sole, refused).verdict == "fair refusal"
    assert judge(MatrixSole(1, "white", ("logo",)), refused).verdict == "missed"
    no_sole = replace(refused, failure=FailureKind.NO_SOLE.value)
    assert judge(sole, no_sole).verdict == "missed"
    too_close = replace(refused, failure=FailureKind.ENDS_TOO_CLOSE_TO_CALL.value, half_area_difference_true=0.05)
    assert judge(sole, too_close).verdict == "fair refusal"
    assert judge(sole, replace(too_close, half_area_difference_true=0.09)).verdict == "missed"
    # A glue line on a wall steeper than the glue contract: the self-checks' refusals are right, others not.
    sloped = MatrixSole(1, "white", ("sloped-wall",))
    on_wall = replace(refused, failure=FailureKind.OUTLINE_INCONSISTENT.value, glue_line_steep_true=0.5)
    assert judge(sloped, on_wall).verdict == "fair refusal"
    assert judge(sloped, replace(on_wall, failure=FailureKind.SURFACE_NOT_MEASURED.value)).verdict == "fair refusal"
    assert judge(sloped, replace(on_wall, glue_line_steep_true=0.02)).verdict == "missed"
    assert judge(sloped, replace(on_wall, failure=FailureKind.NO_SOLE.value)).verdict == "missed"
    assert judge(sloped, replace(_row(), glue_line_steep_true=0.5)).verdict == "right"  # measured right stays right
    # A wall too low to confirm the outline: right where the true wall is that low, whatever the variations.
    low = replace(refused, failure=FailureKind.WALL_TOO_LOW.value, wall_height_true_mm=7.2)
    assert judge(sole, low).verdict == "fair refusal"
    assert judge(sole, replace(low, wall_height_true_mm=21.0)).verdict == "missed"
    # A sole of its table's colour: "colours too similar" is right, from the materials, whatever the variations.
    alike = replace(refused, failure=FailureKind.COLOURS_TOO_SIMILAR.value)
    assert judge(MatrixSole(1, "grey", ("grey-table",)), alike).verdict == "fair refusal"
    assert judge(MatrixSole(1, "grey", ("patterned-table",)), alike).verdict == "fair refusal"
    assert judge(MatrixSole(1, "black", ("grey-table",)), alike).verdict == "missed"
    assert judge(MatrixSole(1, "grey", ("plain",)), alike).verdict == "missed"  # on the dark table
    # A glue line on a light sole's dark rim cannot be measured: the surface's refusals are right, others not.
    surface = replace(refused, failure=FailureKind.SURFACE_NOT_MEASURED.value)
    assert judge(MatrixSole(1, "white", ("rim",)), surface).verdict == "fair refusal"
    assert judge(MatrixSole(1, "grey", ("rim",)), refused).verdict == "fair refusal"  # too few points
    assert judge(MatrixSole(1, "black", ("rim",)), surface).verdict == "missed"  # its rim is light and measured
    assert judge(MatrixSole(1, "white", ("rim",)), alike).verdict == "missed"
    results = [judge(sole, _row()), judge(sole, refused)]
    assert acceptance(results).measured_fraction == 0.5 and not acceptance(results).passed


@pytest.mark.parametrize(("height", "low", "high"), [("flat", 6.0, 8.0), ("normal", 20.0, 36.0), ("tall", 40.0, 52.0)])
def test_the_true_wall_height_is_the_heel_of_the_model(height: str, low: float, high: float) -> None:
    # The 90th percentile of the true top 6 mm inside the outline: the heel's height (the top's cross curvature
    # adds up to 2 mm), from the model alone.
    for seed in range(3):
        scene = SoleScene.random(seed, "white", half_size_rig(), SceneLook(height=height))
        assert low <= wall_height_true(scene) <= high


def test_missed_outline_refusals_are_counted_by_their_outlines_truth() -> None:
    sole = MatrixSole(1, "white", ("logo",))
    refused = SoleBenchRow(1, "white", 250.0, False, "off", *(None,) * 6, 1.0, "logo", "outline_inconsistent")
    off, near = replace(refused, outline_error_max_mm=2.5), replace(refused, outline_error_max_mm=0.4)
    other = replace(off, failure=FailureKind.SURFACE_NOT_MEASURED.value)
    results = [judge(sole, row) for row in (off, near, other, refused)]
    assert [r.verdict for r in results] == ["missed"] * 4  # the verdict stays: a measurable sole not measured
    assert acceptance(results).missed == 4 and acceptance(results).missed_outline_off == 1


def test_outline_error_is_the_refused_outlines_farthest_point_from_the_truth() -> None:
    scene = SoleScene.random(7, "white", half_size_rig())
    assert scene.sole is not None
    truth = scene.sole.footprint_table()
    rectified_to_raw = np.eye(4)
    rectified_to_raw[:3, :3] = scene.calib.R1.T
    camera_to_table = scene.camera_pose @ rectified_to_raw  # the measured table frame is the scene's own
    assert np.allclose(scene.table_from_measured(camera_to_table), np.eye(4))
    shifted = truth + np.array([1.5, 0.0])  # the whole outline 1.5 mm along x: its farthest point ~1.5 mm off
    refused = MeasurementRefused(
        FailureKind.OUTLINE_INCONSISTENT, "off", 100, outline=shifted, camera_to_table=camera_to_table
    )
    assert outline_error(scene, refused) == pytest.approx(1.5, abs=0.05)
    assert outline_error(scene, replace(refused, outline=truth)) == pytest.approx(0.0, abs=0.05)
    assert outline_error(scene, replace(refused, outline=None)) is None


@pytest.mark.parametrize(
    ("look", "low", "high"),
    [
        (SceneLook(), 0.0, 0.0),  # vertical walls: the glue line is on the top
        (SceneLook(wall_slope_deg=12.0), 0.3, 1.0),  # a 12 degree wall rising 4 mm per mm: the line runs up it
        (SceneLook(wall_slope_deg=12.0, height="flat"), 0.0, 0.0),  # 2 mm of wall: the line stays on the top
        (SceneLook(top_edge_radius_mm=5.0), 0.0, 0.0),  # a 5 mm fillet is 37 degrees steep 2 mm in
    ],
)
def test_true_glue_line_on_a_wall_steeper_than_the_contract(look: SceneLook, low: float, high: float) -> None:
    scene = SoleScene.random(7, "white", half_size_rig(), look)
    assert low <= glue_line_steep(scene) <= high


def test_matrix_bench_runs_on_a_tiny_set() -> None:
    soles = [MatrixSole(21, "black", ("pointed-toe", "gain-high"))]
    results = bench_matrix(soles, half_size_rig())
    assert len(results) == 1 and results[0].verdict in ("right", "WRONG", "fair refusal", "missed")
    row = results[0].row
    assert row.variations == "pointed-toe+gain-high"
    assert row.length_true_mm == pytest.approx(
        SoleScene.random(21, "black", half_size_rig(), soles[0].look).sole.truth().length_mm  # type: ignore[union-attr]
    )


def test_a_sole_asked_taught_but_measured_untaught_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the empty table cannot be taught the bench measures as an untaught cell would; its row and the report
    must say so, or a reader takes the untaught cell's figures for the taught one's."""
    import cellctl.eval.sole_matrix as sole_matrix
    from cellctl.vision.reconstruction import SoleReconstructor

    monkeypatch.setattr(
        sole_matrix,
        "taught_reconstructor",
        lambda calib, scene, cache=None, depth_range_mm=None: SoleReconstructor(calib),
    )
    results = bench_matrix([MatrixSole(21, "white", ("plain",))], half_size_rig(), taught=True)
    assert results[0].row.variations == "plain+untaught"
    assert "1 of them measured untaught, their empty table not taught: 21." in sole_matrix.matrix_markdown(results, "x")


def test_bench_sole_matrix_command_lists_and_rejects(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench-sole", "--matrix", "--variations", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in VARIATIONS)
    assert main(["bench-sole", "--matrix", "--variations", "purple-sole"]) == 2
    assert "unknown variation 'purple-sole'" in capsys.readouterr().err
    assert main(["bench-sole", "--variations", "rim"]) == 2


@pytest.mark.slow  # a full-size scene and four empty-table exposures (the half-size rig is too coarse to teach)
def test_a_simulated_scene_is_taught_then_measured(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The cell's workflow on a simulated scene: its empty table taught, then the sole measured against it;
    without the taught table (or --untaught) measure stops with the remedy."""
    scene = tmp_path / "scene"
    args = ["simulate", "sole", "--out", str(scene), "--seed", "6", "--empty", "4"]
    assert main(args) == 0 and (scene / "empty_4_left.png").exists() and (scene / "empty_4_right.png").exists()
    pair = [str(scene / "left.png"), str(scene / "right.png")]
    assert main(["measure", "--calib", str(scene / "calib.yaml"), *pair]) == 2
    assert "teach the empty fixture first" in capsys.readouterr().err
    empties = sorted(str(path) for path in scene.glob("empty_*.png"))  # as `DIR/empty_*.png` lists them
    assert main(["teach", "--calib", str(scene / "calib.yaml"), *empties]) == 0
    capsys.readouterr()
    assert main(["measure", "--calib", str(scene / "calib.yaml"), "--json", *pair]) == 0
    out = json.loads(capsys.readouterr().out)
    truth = json.loads((scene / "truth.json").read_text())
    assert out["valid"] and abs(out["length_mm"] - truth["length_mm"]) < 1.0  # measured against the taught table


def test_simulate_sole_applies_variations(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calib = write_half_size_rig(tmp_path)
    args = ["simulate", "sole", "--out", str(tmp_path / "scene"), "--seed", "6", "--color", "grey"]
    assert main([*args, "--calib", str(calib), "--variations", "rim,square-toe"]) == 0
    truth = json.loads((tmp_path / "scene" / "truth.json").read_text())
    assert truth["look"]["colours"] == "rim" and truth["look"]["toe"] == "square"
    assert truth["sole_shape"]["toe_end"]["kind"] == "square"
    assert "rim,square-toe" in capsys.readouterr().out
    assert main([*args, "--variations", "purple-sole"]) == 2
    assert "unknown variation" in capsys.readouterr().err


def test_distorted_rig_bends_straight_lines_and_is_the_looks_rig() -> None:
    from cellctl.sim.rig import default_rig, distorted_rig

    def corner_shift(calib) -> float:  # noqa: ANN001
        # How far the lens moves the image corner from where a pinhole camera would put it, in pixels.
        corner = np.array([[[0.0, 0.0]]])
        ideal = cv2.undistortPoints(corner, calib.K1, calib.D1, P=calib.K1).reshape(2)
        return float(np.linalg.norm(ideal - corner.reshape(2)))

    assert corner_shift(distorted_rig()) > 4 * corner_shift(default_rig()) > 40.0
    scene = SoleScene.random(3, "white", look=look_for(("distorted-rig",), 3))
    np.testing.assert_allclose(scene.calib.D1, distorted_rig().D1)


def test_a_measurement_that_raises_is_a_crash_not_the_end_of_the_run() -> None:
    class Raising:
        def reconstruct(
            self, left: np.ndarray, right: np.ndarray, surface: object = None, exposures: object = None
        ) -> None:
            raise np.linalg.LinAlgError("Singular matrix")

    scene = SoleScene.random(5, "white", half_size_rig())
    row = measure_scene(Raising(), scene)  # type: ignore[arg-type]
    assert not row.valid and row.reason is not None and "LinAlgError" in row.reason
    assert judge(MatrixSole(5, "white", ("plain",)), row).verdict == "CRASH"
    assert not acceptance([judge(MatrixSole(5, "white", ("plain",)), row)]).passed


def test_a_refusal_naming_more_exposures_is_measured_again_on_them_as_the_cycle_does(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The bench follows the cycle ([cameras] retry_averaged_frames): a refusal for the glue heights' precision
    that names more exposures is measured once more on eight; the row says so and times both; at 0, never."""
    import cellctl.eval.sole_bench as sole_bench

    counts: list[int] = []

    class Counting:
        def reconstruct(self, left: np.ndarray, right: np.ndarray, surface: object, exposures: int) -> int:
            counts.append(exposures)
            return exposures

    def coarse_on_four(reconstruction: int, wall_draft_deg: float | None = None) -> MeasurementRefused:
        more = 8 if reconstruction < 8 else None
        return MeasurementRefused(
            FailureKind.SURFACE_NOT_MEASURED, f"coarse on {reconstruction}", 0, more_exposures=more
        )

    monkeypatch.setattr(sole_bench, "measure_sole", coarse_on_four)
    scene = SoleScene.random(5, "black", half_size_rig())
    row = measure_scene(Counting(), scene)  # type: ignore[arg-type]
    assert counts == [4, 8] and row.retried_on == 8 and row.reason == "coarse on 8"
    assert "measured again on 8 exposures, 0 valid then: 5." in retried_note([row])
    counts.clear()
    row = measure_scene(Counting(), scene, retry_frames=0)  # type: ignore[arg-type]
    assert counts == [4] and row.retried_on is None and row.reason == "coarse on 4" and retried_note([row]) == ""


def test_the_distorted_rigs_images_and_rectification_leave_no_vertical_disparity() -> None:
    # Issue 11 (held-out 4022, black on the distorted rig): the glue heights' error is NOT the rectification.
    # The renderer's rays come from the iterative inverse of the distortion (raycast._undistort); the
    # rectification maps use the forward model. Both must agree to a hundredth of a pixel over the whole image,
    # corners included (140 px of distortion there), and table points seen by both cameras must land on the
    # same rectified row.
    from cellctl.sim.raycast import _undistort
    from cellctl.sim.render import project, rig_pose
    from cellctl.sim.rig import distorted_rig

    calib = distorted_rig()
    xs, ys = np.meshgrid(np.linspace(0, 1279, 33), np.linspace(0, 1023, 27))
    pixels = np.column_stack([xs.ravel(), ys.ravel()])
    for K, D in ((calib.K1, calib.D1), (calib.K2, calib.D2)):
        rays = _undistort(pixels, K, D).astype(np.float64)
        back, _ = cv2.projectPoints(np.column_stack([rays, np.ones(len(rays))]), np.zeros(3), np.zeros(3), K, D)
        assert np.abs(back.reshape(-1, 2) - pixels).max() < 0.01
    pose = rig_pose(calib)
    grid = np.mgrid[-200:201:10, -150:151:10].reshape(2, -1).T.astype(np.float64)
    table = np.column_stack([grid, np.zeros(len(grid))])
    left, right = project(calib, pose, "left", table), project(calib, pose, "right", table)
    seen = np.all((left >= 0) & (left <= [1279, 1023]) & (right >= 0) & (right <= [1279, 1023]), axis=1)
    assert seen.sum() > 500
    dy = calib.rectify_points_left(left[seen])[:, 1] - calib.rectify_points_right(right[seen])[:, 1]
    assert np.abs(dy).max() < 0.01


def test_the_tilted_rig_looks_at_the_table_as_far_off_square_as_drawn() -> None:
    """tilted-rig mounts the rig 8-12 degrees off square (the usual tilt's direction, scaled), outside the matrix;
    the plain scene keeps the usual 2 / -1 degrees."""
    from cellctl.sim.render import RIG_TILT_DEG
    from cellctl.sim.rig import default_rig
    from cellctl.sim.scene import SoleScene

    look = look_for(("tilted-rig",), 3)
    assert 8.0 <= look.rig_tilt_deg <= 12.0 and "tilted-rig" not in MATRIX_ENTRIES
    assert fair_refusals(("tilted-rig",)) == {FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED}
    for scene_look, angle in ((look, look.rig_tilt_deg), (look_for((), 3), float(np.hypot(*RIG_TILT_DEG)))):
        scene = SoleScene.random(3, "black", default_rig(), scene_look)
        down = scene.camera_pose[:3, 2] @ np.array([0.0, 0.0, -1.0])  # the left camera's axis against straight down
        assert np.degrees(np.arccos(down)) == pytest.approx(angle, abs=1e-6)
    with pytest.raises(ValueError, match="tilt"):
        SceneLook(rig_tilt_deg=35.0)


@pytest.mark.parametrize("color", ["white", "grey", "black"])
def test_the_judges_rim_colour_is_the_one_the_simulator_paints(color: str) -> None:
    # sole_matrix.textureless_glue_band restates appearance.ColourScheme.draw's choice of rim colour.
    from cellctl.eval.sole_matrix import textureless_glue_band
    from cellctl.sim.appearance import DARK_ACCENT, ColourScheme

    look = SceneLook(colours="rim")
    scene = SoleScene.random(3, color, half_size_rig(), look)
    assert scene.sole is not None
    scheme = ColourScheme.draw(np.random.default_rng(0), color, look, scene.sole.shape)
    assert scheme.rim_mm > 2.0  # wider than the glue offset: the glue line runs on it
    assert textureless_glue_band(color, look) == (scheme.rim_bgr == DARK_ACCENT)
    assert not textureless_glue_band(color, SceneLook())
