"""Exports for robot tools, read back by readers nobody here wrote (Open3D's PLY reader, numpy's CSV reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from cellctl.vision.export import (
    cloud_normals,
    read_ply_header,
    write_cloud_ply,
    write_glue_csv,
    write_glue_ply,
)


def ring(n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    points = np.column_stack([120 * np.cos(t), 45 * np.sin(t), 10 + 2 * np.sin(2 * t)])
    normals = np.column_stack([0.1 * np.cos(t), 0.1 * np.sin(t), np.ones(n)])
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def test_glue_csv_has_one_header_row_and_the_path_in_order(tmp_path: Path) -> None:
    points, normals = ring()
    write_glue_csv(tmp_path / "glue.csv", points, normals)
    lines = (tmp_path / "glue.csv").read_text().splitlines()
    assert lines[0] == "i,x_mm,y_mm,z_mm,nx,ny,nz" and len(lines) == len(points) + 1
    table = np.loadtxt(tmp_path / "glue.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, 0], np.arange(len(points)))
    np.testing.assert_allclose(table[:, 1:4], points, atol=1e-4)
    np.testing.assert_allclose(table[:, 4:], normals, atol=1e-6)


def test_glue_ply_is_a_closed_polyline_with_normals_and_names_its_frame(tmp_path: Path) -> None:
    points, normals = ring()
    path = tmp_path / "glue.ply"
    write_glue_ply(path, points, normals, frame="robot")
    header = read_ply_header(path)
    assert any(line.startswith("comment frame: robot") for line in header)
    assert "comment units: mm; normals are unit vectors pointing away from the sole's top surface" in header
    lines = o3d.io.read_line_set(str(path))
    np.testing.assert_allclose(np.asarray(lines.points), points, atol=1e-4)
    edges = np.asarray(lines.lines)
    assert len(edges) == len(points) and edges[-1].tolist() == [len(points) - 1, 0]
    cloud = o3d.io.read_point_cloud(str(path))  # the vertices, with their normals
    np.testing.assert_allclose(np.asarray(cloud.normals), normals, atol=1e-6)


def test_cloud_ply_with_normals_and_colours_reads_back(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    xy = rng.uniform(-50, 50, size=(40000, 2))  # 4 points per mm², as the stereo cloud of a sole
    points = np.column_stack([xy, 20 + 0.2 * xy[:, 0]])  # a plane tilted about y
    normals = cloud_normals(points)
    expected = np.array([-0.2, 0.0, 1.0]) / np.linalg.norm([-0.2, 0.0, 1.0])
    assert np.percentile(normals @ expected, 1) > 0.9995 and np.all(normals @ expected > 0.995)  # up, not flipped
    dome = np.column_stack([xy, 30 - 0.005 * (xy**2).sum(axis=1)])  # curved: normals follow the slope
    true = np.column_stack([0.01 * xy, np.ones(len(xy))])
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    assert np.median(np.sum(cloud_normals(dome) * true, axis=1)) > 0.9995
    colours = rng.integers(0, 256, size=(len(xy), 3))
    path = tmp_path / "cloud.ply"
    write_cloud_ply(path, points, normals, colours)
    assert "comment frame: table" in " ".join(read_ply_header(path))
    cloud = o3d.io.read_point_cloud(str(path))
    np.testing.assert_allclose(np.asarray(cloud.points), points, atol=1e-3)
    np.testing.assert_allclose(np.asarray(cloud.normals), normals, atol=1e-6)
    np.testing.assert_allclose(np.asarray(cloud.colors) * 255, colours, atol=0.5)


def test_bad_input_is_refused(tmp_path: Path) -> None:
    points, normals = ring()
    with pytest.raises(ValueError, match="same shape"):
        write_glue_csv(tmp_path / "x.csv", points, normals[:-1])
    with pytest.raises(ValueError, match="frame"):
        write_glue_ply(tmp_path / "x.ply", points, normals, frame="camera")


@pytest.mark.slow  # one render and measurement at half size
def test_measure_export_writes_the_three_files_of_one_pair(tmp_path: Path) -> None:
    from cellctl.cli import main
    from cellctl.sim.scene import SoleScene
    from tests.sim_rig import HALF_RIG_GLUE_TOLERANCE_MM, half_size_rig, write_half_size_rig

    scene = SoleScene.random(1, "white", half_size_rig())
    scene.write(tmp_path, scene.render())
    calib = write_half_size_rig(tmp_path)
    out = tmp_path / "export"
    out.mkdir()
    args = ["measure", "--untaught", "--calib", str(calib), str(tmp_path / "left.png"), str(tmp_path / "right.png")]
    args += ["--glue-height-tolerance", str(HALF_RIG_GLUE_TOLERANCE_MM)]
    assert main([*args, "--export", str(out)]) == 0
    table = np.loadtxt(out / "glue-path.csv", delimiter=",", skiprows=1)
    assert len(table) > 100 and np.allclose(np.linalg.norm(table[:, 4:], axis=1), 1.0, atol=1e-5)
    lines = o3d.io.read_line_set(str(out / "glue-path.ply"))
    np.testing.assert_allclose(np.asarray(lines.points), table[:, 1:4], atol=1e-3)
    cloud = o3d.io.read_point_cloud(str(out / "cloud.ply"))
    assert len(cloud.points) > 10_000 and cloud.has_normals() and cloud.has_colors()
    assert np.median(np.asarray(cloud.normals)[:, 2]) > 0.9  # the sole's top faces the cameras
    assert main([*args, "--export", str(tmp_path / "missing")]) == 2
