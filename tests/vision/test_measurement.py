"""Sole reconstruction and measurement against simulated soles of known geometry (docs/measurements.md).

Three levels: the measuring code on the simulator's true depth (no matcher: tests segmentation and
measurement alone), end to end through the stereo matcher on white and black soles (the paper's 1.3 mm),
and bad input that must give a clear error or an invalid result, never a number.
The 20-sole accuracy table is `cellctl bench-sole`, not a test.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.cli import main
from cellctl.errors import FailureKind, MeasurementInputError
from cellctl.eval.sole_bench import glue_truth
from cellctl.sim.look import SceneLook
from cellctl.sim.rig import default_rig
from cellctl.sim.scene import SoleScene, true_cloud
from cellctl.sim.sole import SoleModel, SolePose
from cellctl.vision import glue_path as glue_path_module
from cellctl.vision.closed_path import outward_normals
from cellctl.vision.image_noise import (
    CLEAN_EXPOSURE_NOISE_DN,
    MAX_IMAGE_NOISE_DN,
    NOISY_EXPOSURES_DN,
    mean_noise_dn,
)
from cellctl.vision.measurement import MeasurementRefused, SoleMeasurement, measure_sole
from cellctl.vision.reconstruction import Reconstruction, ReconstructionRefused, SoleReconstructor, StereoCloud

TOLERANCE_MM = 1.3  # Wang et al. 2022, Table 4
# Black soles whose glue heights are measured finely enough to publish at the default 1 mm tolerance (median
# expected error 0.26 and 0.25 mm; checks.GLUE_TYPICAL_SD_SHARE); sole 5's 0.31 mm is refused (test below).
STEREO_SOLES = [(0, "white"), (3, "white"), (1, "black"), (9, "black")]


@pytest.fixture(scope="module")
def rig():  # noqa: ANN201
    return default_rig()


@pytest.fixture(scope="module")
def reconstructor(rig) -> SoleReconstructor:  # noqa: ANN001
    return SoleReconstructor(rig)


@pytest.fixture(scope="module")
def stereo_results(rig, reconstructor):  # noqa: ANN001, ANN201
    results = []
    for seed, colour in STEREO_SOLES:
        scene = SoleScene.random(seed, colour, rig)
        pair = scene.render()
        reconstruction = reconstructor.reconstruct(pair.left, pair.right)
        results.append((scene, pair, reconstruction, measure_sole(reconstruction)))
    return results


def errors(scene: SoleScene, result: SoleMeasurement) -> np.ndarray:
    truth = scene.sole.truth()
    assert result.valid, result.reason
    return np.array(
        [
            result.length_mm - truth.length_mm,
            result.heel_height_mm - truth.heel_height_mm,
            result.toe_height_mm - truth.toe_height_mm,
        ]
    )


# ---- on the true depth: segmentation and measurement alone ----------------------------------------------


@pytest.mark.parametrize(("seed", "colour"), [(2, "white"), (6, "black")])
def test_measurement_on_true_depth(rig, reconstructor, seed: int, colour: str) -> None:  # noqa: ANN001
    scene = SoleScene.random(seed, colour, rig)
    pair = scene.render()
    reconstruction = reconstructor.segment(true_cloud(rig, pair.depth_left, pair.left))
    result = measure_sole(reconstruction)
    length, heel, toe = errors(scene, result)
    assert abs(length) < 0.5
    assert abs(heel) < 0.05 and abs(toe) < 0.05
    # The measured table frame really is the table: its z = 0 plane maps onto the true one.
    transform = scene.table_from_measured(reconstruction.camera_to_table)
    assert abs(transform[2, 3]) < 0.05 and transform[2, 2] == pytest.approx(1.0, abs=1e-4)


def _across_errors(scene: SoleScene, reconstruction: Reconstruction, result: SoleMeasurement) -> np.ndarray:
    """Per glue point the true top's slope outward across the path less the glue normal's (rise per mm)."""
    path = result.glue_path
    transform = scene.table_from_measured(reconstruction.camera_to_table)
    _, _, true_normals = glue_truth(scene, (path.points @ transform[:3, :3].T + transform[:3, 3])[:, :2])
    true_normals = true_normals @ transform[:3, :3]  # into the measured frame
    outward = outward_normals(path.points[:, :2])
    slope = lambda n: -np.sum(n[:, :2] * outward, axis=1) / n[:, 2]  # noqa: E731
    return slope(true_normals) - slope(path.normals)


def test_glue_normals_on_a_dished_top_follow_it_more_closely(rig, reconstructor, monkeypatch) -> None:  # noqa: ANN001
    """On a dished top the normals' slope across the path, a difference of heights 15 mm apart, is the slope 7.5 mm
    further in: on the true depth of a 6 mm dish 0.026 flatter than the top at the glue line (1.5 degrees). The glue
    line's rise over the rings' line reads the curve (0.024) and the normals take it back (glue_path.across_bend)
    but for the deadband kept against the estimate's noise."""
    scene = SoleScene.random(4, "white", rig, dataclasses.replace(SceneLook(), cross_curvature_mm=-6.0))
    pair = scene.render()
    reconstruction = reconstructor.segment(true_cloud(rig, pair.depth_left, pair.left))
    result = measure_sole(reconstruction)
    assert isinstance(result, SoleMeasurement), result
    missed = np.median(_across_errors(scene, reconstruction, result))
    monkeypatch.setattr(glue_path_module, "across_bend", lambda rise: 0.0)
    uncorrected = measure_sole(reconstruction)
    assert isinstance(uncorrected, SoleMeasurement)
    missed_before = np.median(_across_errors(scene, reconstruction, uncorrected))
    assert missed_before > 0.02  # the normals lean less than the top: flatter than it
    assert 0.0 < missed < missed_before - 0.006  # taken back but for the deadband (GLUE_BEND_DEADBAND)


# ---- end to end through the stereo matcher -------------------------------------------------------------


def test_stereo_measurements_within_the_paper_tolerance(stereo_results) -> None:  # noqa: ANN001
    table = np.array([errors(scene, result) for scene, _, _, result in stereo_results])
    assert np.all(np.abs(table) < TOLERANCE_MM), table
    # What the line aims for: heights within 0.5 mm, length within 1 mm.
    assert np.all(np.abs(table[:, 1:]) < 0.5), table
    assert np.all(np.abs(table[:, 0]) < 1.0), table


def test_a_black_sole_too_coarse_for_the_glue_tolerance_is_refused_saying_so(rig, reconstructor) -> None:  # noqa: ANN001
    """Standard sole 5 (black): its glue heights' median expected error is 0.31 mm, beyond 0.28 x the 1 mm tolerance,
    where a path's worst point lies beyond the tolerance on a few soles in a hundred: refused, saying so; a cell whose
    dispenser allows 2 mm takes it."""
    scene = SoleScene.random(5, "black", rig)
    pair = scene.render()
    reconstruction = reconstructor.reconstruct(pair.left, pair.right)
    result = measure_sole(reconstruction)
    assert isinstance(result, MeasurementRefused) and result.failure is FailureKind.SURFACE_NOT_MEASURED, result
    assert "measured too coarsely for its glue heights" in result.reason
    assert isinstance(measure_sole(reconstruction, glue_height_tolerance_mm=2.0), SoleMeasurement)


def test_white_and_black_soles_use_the_colour_filter(stereo_results) -> None:  # noqa: ANN001
    for scene, _, reconstruction, _ in stereo_results:
        assert reconstruction.colour_filter, scene.color
        assert reconstruction.sole_points[:, 2].min() > 2.9  # nothing of the table is left in the sole's cloud


def test_glue_path_follows_the_edge_on_the_surface(stereo_results) -> None:  # noqa: ANN001
    scene, _, reconstruction, result = stereo_results[0]
    path = result.glue_path
    assert path.closed and len(path.points) > 200
    steps = np.linalg.norm(np.diff(np.vstack([path.points, path.points[:1]])[:, :2], axis=0), axis=1)
    assert np.allclose(steps, 2.0, atol=0.1)
    # Counter-clockwise seen from the cameras, starting at the heel end.
    xy = path.points[:, :2]
    assert 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]) > 0
    assert np.argmin(xy @ result.axis) == 0
    # In the simulator's frame: 2 mm inside the true outline, on the true top surface, with its normal.
    transform = scene.table_from_measured(reconstruction.camera_to_table)
    true_xyz = path.points @ transform[:3, :3].T + transform[:3, 3]
    outline = scene.sole.outline_table(4000).astype(np.float32).reshape(-1, 1, 2)
    inset = np.array([cv2.pointPolygonTest(outline, (float(x), float(y)), True) for x, y in true_xyz[:, :2]])
    assert np.all(np.abs(inset - 2.0) < 0.6), (inset.min(), inset.max())
    height_error = true_xyz[:, 2] - scene.sole.top_height_at(true_xyz[:, :2])
    assert np.percentile(np.abs(height_error), 95) < 0.6 and np.abs(height_error).max() < 1.0
    angles = np.degrees(
        np.arccos(
            np.clip(
                np.sum(path.normals @ transform[:3, :3].T * scene.sole.top_normal_at(true_xyz[:, :2]), axis=1), -1, 1
            )
        )
    )
    assert np.median(angles) < 3.0 and angles.max() < 8.0, (np.median(angles), angles.max())


# ---- bad input -----------------------------------------------------------------------------------------


def test_surface_samples_on_two_threads_are_those_on_one(stereo_results) -> None:  # noqa: ANN001
    from cellctl.vision.surface import SoleSurface

    for _, _, reconstruction, result in stereo_results[:2]:
        surface = SoleSurface(reconstruction)
        # The glue path's queries (its path, then its inner ring), an odd count, and one the images cannot fit.
        path = result.glue_path.points[:, :2]
        for xy in (np.vstack([path, path + 9.0]), path[:-1], np.vstack([path[:5], [[1e4, 1e4]]])):
            one, two = surface.sample(xy, 4.0), surface.sample(xy, 4.0, parallel=True)
            assert one.refined.any()
            for a, b in ((one.z, two.z), (one.normals, two.normals), (one.refined, two.refined)):
                np.testing.assert_array_equal(a, b)


def test_the_mean_of_four_exposures_measures_the_black_sole_one_exposure_cannot(rig, reconstructor) -> None:  # noqa: ANN001
    """Sole 5 again, as a cycle takes it (cellctl.cameras.averaging): the outline from the last exposure, unchanged, the
    surface fitted on the mean of four, whose halved noise brings the glue heights within the 1 mm tolerance."""
    from cellctl.eval.sole_bench import glue_truth, scene_frame

    scene = SoleScene.random(5, "black", rig)
    frame = scene_frame(scene, 4)
    assert frame.averaged is not None and frame.info["averaged_frames"] == 4
    single = reconstructor.reconstruct(frame.left, frame.right)
    averaged = reconstructor.reconstruct(frame.left, frame.right, frame.averaged)
    assert isinstance(single, Reconstruction) and isinstance(averaged, Reconstruction)
    np.testing.assert_array_equal(averaged.sole_points, single.sole_points)
    assert not averaged.from_mean  # a clean exposure: only the surface fits read the mean
    assert isinstance(measure_sole(single), MeasurementRefused)
    result = measure_sole(averaged)
    assert isinstance(result, SoleMeasurement), result
    assert np.all(np.abs(errors(scene, result)) < [1.0, 0.5, 0.5])
    transform = scene.table_from_measured(result.camera_to_table)
    points = result.glue_path.points @ transform[:3, :3].T + transform[:3, 3]
    _, height, _ = glue_truth(scene, points[:, :2])
    assert float(np.abs(points[:, 2] - height).max()) < 1.0
    with pytest.raises(MeasurementInputError, match="calibrat"):
        reconstructor.reconstruct(frame.left, frame.right, (frame.left[::2, ::2], frame.right[::2, ::2]))


def test_an_exposure_too_noisy_to_measure_is_measured_on_the_mean(rig, reconstructor) -> None:  # noqa: ANN001
    """Heavy sensor noise (6 DN of read noise) is refused on one exposure; the mean of four has half its noise, and
    the whole reconstruction (matcher, outline, surface) reads the mean, within the tolerances."""
    from cellctl.eval.sole_bench import scene_frame
    from cellctl.sim.look import SceneLook

    scene = SoleScene.random(1, "white", rig, SceneLook(noise="heavy"))
    frame = scene_frame(scene, 4)
    assert frame.averaged is not None and frame.info["averaged_frames"] == 4
    single = reconstructor.reconstruct(frame.left, frame.right)
    assert isinstance(single, ReconstructionRefused) and single.failure is FailureKind.SURFACE_NOT_MEASURED
    assert "too noisy" in single.reason
    assert not reconstructor.last_from_mean
    averaged = reconstructor.reconstruct(frame.left, frame.right, frame.averaged)
    assert reconstructor.last_from_mean and isinstance(averaged, Reconstruction) and averaged.from_mean
    assert averaged.image_noise_dn is not None and averaged.image_noise_dn < MAX_IMAGE_NOISE_DN
    result = measure_sole(averaged)
    assert isinstance(result, SoleMeasurement), result
    assert np.all(np.abs(errors(scene, result)) < [1.0, 0.5, 0.5])
    # The mean's own noise (what averaging removed, over sqrt(n - 1)) decides the glue heights' share: as noisy as
    # one clean exposure here; a camera 2.5 times the simulator's averaged over sixteen would be quieter, and then
    # the share for a clean camera's mean applies, which this sole's expected error (~0.21 mm) is over.
    assert averaged.exposure_noise_dn is not None and averaged.exposure_noise_dn > NOISY_EXPOSURES_DN
    assert mean_noise_dn(averaged.exposure_noise_dn, 4) > CLEAN_EXPOSURE_NOISE_DN
    quieter = dataclasses.replace(averaged, surface_exposures=16, exposure_noise_dn=2.5)
    assert mean_noise_dn(2.5, 16) < CLEAN_EXPOSURE_NOISE_DN
    many = measure_sole(quieter)
    assert not many.valid and many.failure is FailureKind.SURFACE_NOT_MEASURED
    assert "on the mean of the exposures" in many.reason
    # A replayed mean's count is not known (the replayed frame says 1, `cellctl measure --mean` says nothing): both
    # are taken as the cycle's four, so a replay decides as the cycle did.
    for unknown in (None, 1):
        replayed = measure_sole(dataclasses.replace(averaged, surface_exposures=unknown, exposure_noise_dn=1.5))
        assert mean_noise_dn(1.5, 4) < CLEAN_EXPOSURE_NOISE_DN and not replayed.valid


def test_a_camera_noisier_than_a_clean_one_is_measured_on_the_mean_and_a_clean_one_on_its_last_exposure(
    rig,
    reconstructor,  # noqa: ANN001
) -> None:
    """Where averaging removed more than a clean camera's noise (a sensor 2.5 times the simulator's: measurable on one
    exposure, not to the cell's precision), matcher, outline and surface read the mean; a clean camera's last
    exposure is measured as it is."""
    from cellctl.eval.sole_bench import scene_frame
    from cellctl.sim.look import SceneLook
    from cellctl.vision.image_noise import NOISY_EXPOSURES_DN, exposure_noise_dn

    for scale, on_mean in ((1.0, False), (2.5, True)):
        scene = SoleScene.random(1, "white", rig, SceneLook(noise_scale=scale))
        frame = scene_frame(scene, 4)
        assert frame.averaged is not None
        assert (exposure_noise_dn(frame.left, frame.averaged[0]) > NOISY_EXPOSURES_DN) is on_mean
        reconstruction = reconstructor.reconstruct(frame.left, frame.right, frame.averaged)
        assert isinstance(reconstruction, Reconstruction) and reconstruction.surface_averaged
        assert reconstructor.last_from_mean is on_mean and reconstruction.from_mean is on_mean
        result = measure_sole(reconstruction)
        assert isinstance(result, SoleMeasurement), result
        assert np.all(np.abs(errors(scene, result)) < [1.0, 0.5, 0.5])


def test_the_surface_fits_read_the_sole_rectified_without_rounding(rig, stereo_results) -> None:  # noqa: ANN001
    """The reconstruction's `surface_grey`: round the sole, the raw pair rectified in float (Calibration.rectify_grey);
    elsewhere the rounded pair; and the surface's image fits read it."""
    from cellctl.vision.surface import SoleSurface

    for _, pair, reconstruction, result in stereo_results[:2]:
        assert reconstruction.surface_grey is not None and reconstruction.rectified is not None
        for side, raw, fine, rounded in zip(
            ("left", "right"),
            (pair.left, pair.right),
            reconstruction.surface_grey,
            reconstruction.rectified,
            strict=True,
        ):
            changed = fine != rounded
            rows, columns = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
            box = (slice(rows[0], rows[-1] + 1), slice(columns[0], columns[-1] + 1))
            np.testing.assert_allclose(
                fine[box], rig.rectify_grey(raw, side, box), atol=1e-3
            )  # another raw crop: ~1e-5
            assert np.abs(fine - rounded).max() <= 1.0 + 1e-3 and 0.2 < float(np.std((fine - rounded)[box])) < 0.5
        # Both boxes hold the sole: its left pixels, and the right ones at x - d (d = f B / Z).
        x, y = reconstruction.sole_pixels.T
        to_camera = np.linalg.inv(reconstruction.camera_to_table)
        depth = reconstruction.sole_points @ to_camera[2, :3] + to_camera[2, 3]
        for image, column in enumerate((x, x - rig.focal_px * rig.baseline_mm / depth)):
            at = (np.round(y).astype(int), np.round(column).astype(int))
            assert np.mean(reconstruction.surface_grey[image][at] != reconstruction.rectified[image][at]) > 0.9
        path = result.glue_path.points[:, :2]
        fine_z = SoleSurface(reconstruction).sample(path, 4.0).z
        rounded_z = SoleSurface(dataclasses.replace(reconstruction, surface_grey=None)).sample(path, 4.0).z
        same_z = SoleSurface(dataclasses.replace(reconstruction, surface_grey=reconstruction.rectified)).sample(
            path, 4.0
        )
        np.testing.assert_array_equal(same_z.z, rounded_z)
        # The rounding's noise moves a patch's height by a few hundredths of a mm (a fit near its limits more).
        assert 0.0 < np.nanmedian(np.abs(fine_z - rounded_z)) < 0.1


def test_the_depths_normals_along_the_glue_path_are_the_tops(stereo_results) -> None:  # noqa: ANN001
    """glue_path.depth_normals, the glue-normal check's second reference (the depth's own planes, not the image
    patches'): on the stereo soles, within a few degrees of the true top's normal at the glue points, at the points
    asked for only."""
    from cellctl.vision.defaults import GLUE_SPACING_MM
    from cellctl.vision.glue_path import depth_normals
    from cellctl.vision.surface import SoleSurface

    for scene, _, reconstruction, result in stereo_results:
        path = result.glue_path.points
        transform = scene.table_from_measured(reconstruction.camera_to_table)
        true_xy = (path @ transform[:3, :3].T + transform[:3, 3])[:, :2]
        index = np.arange(0, len(path), 3)
        normals = depth_normals(SoleSurface(reconstruction), path[:, :2], index, GLUE_SPACING_MM)
        assert normals.shape == (len(index), 3)
        cosine = np.sum(normals @ transform[:3, :3].T * scene.sole.top_normal_at(true_xy[index]), axis=1)
        angles = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))
        assert np.median(angles) < 6.0 and angles.max() < 20.0, (scene.color, np.median(angles), angles.max())


def test_the_images_noise_is_kept_and_named_where_depth_has_holes(stereo_results) -> None:  # noqa: ANN001
    """The segmentation's reading of the image noise stays on the reconstruction (a clean simulated camera reads
    0.5-0.75 DN), and a refusal for pixels without depth names it beside glare and texture, with the limit."""
    from cellctl.vision.measurement import _depth_holes_cause

    for _, _, reconstruction, _ in stereo_results:
        assert reconstruction.image_noise_dn is not None and 0.3 < reconstruction.image_noise_dn < 0.9
    found = stereo_results[0][2]
    assert _depth_holes_cause(dataclasses.replace(found, image_noise_dn=1.24)) == (
        "glare, no texture or image noise: the image's noise reads 1.2 DN, refused beyond 1.5; a clean camera reads "
        "under 0.8"
    )
    # On the mean of the cycle's exposures (the last one too noisy), still noisy: more exposures are the remedy.
    assert _depth_holes_cause(dataclasses.replace(found, image_noise_dn=1.04, from_mean=True)) == (
        "glare, no texture or image noise: the image's noise reads 1.0 DN on the mean of the cycle's exposures (one "
        "alone is too noisy), refused beyond 1.5; a clean camera reads under 0.8: check exposure, gain and lighting, "
        "or average more exposures per cycle ([cameras] averaged_frames)"
    )
    assert _depth_holes_cause(dataclasses.replace(found, image_noise_dn=None)) == "glare, no texture or image noise"


def test_no_sole_in_view(rig, reconstructor) -> None:  # noqa: ANN001
    empty = dataclasses.replace(SoleScene.random(0, "white", rig), sole=None)
    pair = empty.render()
    result = measure_sole(reconstructor.reconstruct(pair.left, pair.right))
    assert not result.valid and "no sole in view" in result.reason
    assert result.failure is FailureKind.NO_SOLE
    assert isinstance(result, MeasurementRefused)  # no length, heights or glue path: the type has none


def test_sole_cut_by_the_image_border(rig, reconstructor) -> None:  # noqa: ANN001
    scene = SoleScene.random(0, "white", rig)
    # Slide the sole towards -x until its end leaves the left camera's image.
    pose = scene.sole.pose
    cut = dataclasses.replace(
        scene, sole=SoleModel(scene.sole.shape, SolePose(pose.x - 170.0, pose.y, 0.0, pose.mirrored))
    )
    assert not cut.in_view(0)
    pair = cut.render()
    result = measure_sole(reconstructor.reconstruct(pair.left, pair.right))
    assert not result.valid and "cut by the image border" in result.reason
    assert result.failure is FailureKind.SOLE_AT_BORDER
    assert isinstance(result, MeasurementRefused)  # no numbers: the type has none


def test_calibration_not_matching_the_images(reconstructor, stereo_results) -> None:  # noqa: ANN001
    _, pair, _, _ = stereo_results[0]
    half = cv2.resize(pair.left, (640, 512)), cv2.resize(pair.right, (640, 512))
    with pytest.raises(MeasurementInputError, match="calibrat") as error:
        reconstructor.reconstruct(*half)
    assert error.value.kind is FailureKind.CALIBRATION_MISMATCH
    assert isinstance(error.value, ValueError)  # an error of the call, as the CLI reports bad input


def test_sole_coloured_like_the_table_is_not_measured(rig, reconstructor, stereo_results) -> None:  # noqa: ANN001
    # Without a colour edge the matcher's halo would make the sole mm too long: refuse, do not guess.
    _, pair, _, _ = stereo_results[0]
    rng = np.random.default_rng(0)
    grey = np.clip(40 + 4 * rng.standard_normal(pair.left.shape[:2]), 0, 255).astype(np.uint8)
    result = measure_sole(reconstructor.segment(true_cloud(rig, pair.depth_left, cv2.merge([grey] * 3))))
    assert not result.valid and "colours too similar" in result.reason
    assert result.failure is FailureKind.COLOURS_TOO_SIMILAR
    assert isinstance(result, MeasurementRefused)  # no numbers: the type has none


def test_no_table_plane(rig, reconstructor) -> None:  # noqa: ANN001
    # Enough measured points, but scattered through the working volume: nothing is a plane.
    width, height = rig.image_size
    count = width * height // 4
    rng = np.random.default_rng(0)
    points = rng.uniform([-200.0, -150.0, 450.0], [200.0, 150.0, 650.0], size=(count, 3))
    cloud = StereoCloud(points, np.zeros((count, 3), np.float32), np.zeros((count, 2)), np.ones(count), rig.image_size)
    result = measure_sole(reconstructor.segment(cloud))
    assert not result.valid and "no table plane" in result.reason
    assert result.failure is FailureKind.NO_TABLE


def test_no_surface_measured_at_the_heel_point(rig, reconstructor) -> None:  # noqa: ANN001
    scene = SoleScene.random(2, "white", rig)
    pair = scene.render()
    reconstruction = reconstructor.segment(true_cloud(rig, pair.depth_left, pair.left))
    heel = measure_sole(reconstruction).heel_point
    # The same footprint, but no measured points around the heel point (a glossy spot, say).
    far = np.linalg.norm(reconstruction.sole_points[:, :2] - heel[:2], axis=1) > 15.0
    holed = dataclasses.replace(reconstruction, sole_points=reconstruction.sole_points[far])
    result = measure_sole(holed)
    assert not result.valid and "no measured surface at the heel point" in result.reason
    assert result.failure is FailureKind.SURFACE_NOT_MEASURED and isinstance(result, MeasurementRefused)


def test_too_few_measured_points(rig, reconstructor) -> None:  # noqa: ANN001
    width, height = rig.image_size
    blank = np.full((height, width, 3), 40, np.uint8)  # a covered lens: nothing to match
    result = measure_sole(reconstructor.reconstruct(blank, blank.copy()))
    assert not result.valid and "too few measured points" in result.reason
    assert result.failure is FailureKind.TOO_FEW_POINTS


def test_toe_and_heel_too_close_to_call(rig, reconstructor) -> None:  # noqa: ANN001
    scene = SoleScene.random(2, "white", rig)
    shape = scene.sole.shape
    # A sole as wide at the heel as at the ball, with no arch and the same round ends: symmetric.
    symmetric = dataclasses.replace(
        shape,
        heel_half_width=shape.ball_half_width,
        medial_arch=0.0,
        lateral_arch=0.0,
        heel_cap=shape.toe_cap,
        toe_shift=0.0,
    )
    scene = dataclasses.replace(scene, sole=SoleModel(symmetric, scene.sole.pose))
    assert abs(scene.sole.truth().half_area_difference) < 0.01
    pair = scene.render()
    reconstruction = reconstructor.segment(true_cloud(rig, pair.depth_left, pair.left))
    result = measure_sole(reconstruction)
    assert not result.valid and "too close to call" in result.reason
    assert result.failure is FailureKind.ENDS_TOO_CLOSE_TO_CALL
    assert isinstance(result, MeasurementRefused)  # no heights: the type has none
    # With much of the sole without depth the footprint's halves say nothing: the lost pixels are the reason.
    assert isinstance(reconstruction, Reconstruction)
    holed = measure_sole(dataclasses.replace(reconstruction, unmeasured_fraction=0.3))
    assert holed.failure is FailureKind.SURFACE_NOT_MEASURED
    assert holed.reason.startswith("30 % of the sole's pixels have no measured depth")
    assert "toe and heel too close to call" in holed.reason


def test_a_short_sole_with_a_steep_toe_spring_is_measured(rig, reconstructor) -> None:  # noqa: ANN001
    """The glue path's checks bound what a sole's top can be, not what the standard soles happen to be: a 185 mm
    sole whose toe rises steeply has glue points above its points' 99th percentile and steps of 0.7 mm per mm along
    the path, and its right result is published (the checks once refused both)."""
    from cellctl.vision.checks import GLUE_HEIGHT_MARGIN_MM

    scene = SoleScene.random(2, "white", rig)
    shape = scene.sole.shape
    scale = 185.0 / shape.length
    lengths = ("length", "heel_half_width", "ball_half_width", "medial_arch", "lateral_arch", "heel_cap", "toe_cap")
    short = dataclasses.replace(
        shape, **{name: getattr(shape, name) * scale for name in (*lengths, "toe_shift")}, toe_spring=40.0
    )
    scene = dataclasses.replace(scene, sole=SoleModel(short, scene.sole.pose))
    pair = scene.render()
    reconstruction = reconstructor.segment(true_cloud(rig, pair.depth_left, pair.left))
    result = measure_sole(reconstruction)
    length, heel, toe = errors(scene, result)
    assert abs(length) < 0.5 and abs(heel) < 0.1 and abs(toe) < 0.1
    assert isinstance(result, SoleMeasurement)
    z = result.glue_path.points[:, 2]
    # What the old bounds refused: heights beyond the 99th percentile's margin, steps steeper than 0.6 per mm.
    assert z.max() > np.quantile(reconstruction.sole_points[:, 2], 0.99) + GLUE_HEIGHT_MARGIN_MM
    assert np.abs(np.diff(z)).max() > 0.6 * 2.0
    transform = scene.table_from_measured(result.camera_to_table)
    points = result.glue_path.points @ transform[:3, :3].T + transform[:3, 3]
    assert np.abs(points[:, 2] - scene.sole.top_height_at(points[:, :2])).max() < 0.3


# ---- the command ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bound", "limits", "named"),
    [
        ("PLAUSIBLE_LENGTH_MM", (100.0, 200.0), "sole length"),  # the simulated soles are 240-300 mm
        ("PLAUSIBLE_HEIGHT_MM", (0.5, 5.0), "heel height"),
    ],
)
def test_implausible_results_are_refused_not_reported(
    stereo_results,
    monkeypatch: pytest.MonkeyPatch,  # noqa: ANN001
    bound: str,
    limits: tuple[float, float],
    named: str,
) -> None:
    import cellctl.vision.measurement as measurement

    reconstruction = stereo_results[0][2]
    assert measure_sole(reconstruction).valid
    monkeypatch.setattr(measurement, bound, limits)
    result = measure_sole(reconstruction)
    assert not result.valid and result.failure is FailureKind.MEASUREMENT_INVALID
    assert named in result.reason and isinstance(result, MeasurementRefused)  # no length or glue path


def test_measure_command_json(tmp_path: Path, stereo_results, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    scene, pair, _, expected = stereo_results[2]
    scene.write(tmp_path, pair)
    args = ["measure", "--untaught", "--calib", str(tmp_path / "calib.yaml"), str(tmp_path / "left.png")]
    args.append(str(tmp_path / "right.png"))
    code = main([*args, "--json", "--ply", str(tmp_path / "sole.ply"), "--png", str(tmp_path / "overlay.png")])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert {"length_mm", "heel_height_mm", "toe_height_mm", "glue_path", "points", "valid"} <= out.keys()
    assert out["valid"] is True and out["failure"] is None
    # Same images, same numbers up to Open3D's parallel RANSAC and outlier removal, which are not bit-exact.
    assert out["length_mm"] == pytest.approx(expected.length_mm, abs=0.1)
    assert abs(len(out["glue_path"]) - len(expected.glue_path.points)) <= 1 and len(out["glue_path"][0]) == 3
    assert (tmp_path / "sole.ply").stat().st_size > 100_000
    overlay = cv2.imread(str(tmp_path / "overlay.png"))
    assert overlay.shape[0] == 1024 and overlay.shape[1] > 1280  # the left image plus the top view


def test_measure_command_bad_input(tmp_path: Path, stereo_results, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: ANN001
    scene, pair, _, _ = stereo_results[0]
    scene.write(tmp_path, pair)
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), cv2.resize(pair.left, (640, 512)))
    calib = str(tmp_path / "calib.yaml")
    assert main(["measure", "--calib", calib, str(small), str(tmp_path / "right.png")]) == 2
    assert "calibrat" in capsys.readouterr().err
    (tmp_path / "broken.png").write_bytes(b"not an image")
    assert main(["measure", "--calib", calib, str(tmp_path / "broken.png"), str(tmp_path / "right.png")]) == 2
    assert "cannot be read" in capsys.readouterr().err
    assert main(["measure", "--calib", str(tmp_path / "missing.yaml"), str(small), str(small)]) == 2


def test_a_sole_with_more_than_five_percent_of_its_pixels_without_depth_is_not_published() -> None:
    # What passes every check is still refused where that much of the sole lost its depth (glare: 19020 lost 12 %
    # and its heights were 2-2.6 mm low); the same sole with its depth whole is measured.
    rig = default_rig()
    scene = SoleScene.random(2, "white", rig)
    pair = scene.render()
    reconstruction = SoleReconstructor(rig).segment(true_cloud(rig, pair.depth_left, pair.left))
    assert isinstance(reconstruction, Reconstruction)
    assert measure_sole(reconstruction).valid
    holed = measure_sole(dataclasses.replace(reconstruction, unmeasured_fraction=0.12))
    assert isinstance(holed, MeasurementRefused) and holed.failure is FailureKind.SURFACE_NOT_MEASURED
    assert holed.reason.startswith("12 % of the sole's pixels have no measured depth")
