"""Ray casting of a simulated scene: the table and an optional sole mesh in one Open3D `RaycastingScene`.

Every pixel's ray starts from its *distorted* position, undistorted with the camera's own model
(cv2.undistortPoints), so the images carry the lens distortion of the calibration. `RayCaster` answers
what each ray hits (distance, geometry, part of the sole, point, facet normal), whether the straight line
from a point to a light is free (cast shadows), and which pixels lie on a geometric edge (supersampled by
the renderer, cellctl.sim.render).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np
import open3d as o3d

from cellctl.sim.sole import SoleModel

TABLE_GEOMETRY, SOLE_GEOMETRY = 0, 1
SHADOW_RAY_LIFT_MM = 0.05  # shadow rays start this far off the surface, so they do not hit it again
_CPU = o3d.core.Device("CPU:0")  # every tensor of the renderer lives on the CPU


class RayCaster:
    """The scene's geometry: the table (geometry 0) and, if given, the sole's mesh (geometry 1)."""

    def __init__(self, image_size: tuple[int, int], sole: SoleModel | None) -> None:
        self.image_size = image_size
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(_table_mesh())  # geometry id 0 = TABLE_GEOMETRY
        self._parts = np.zeros(0, np.int32)
        if sole is not None:
            vertices, triangles, self._parts = sole.mesh()
            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = _tensor(vertices, o3d.core.float32)
            mesh.triangle.indices = _tensor(triangles, o3d.core.int32)
            self._scene.add_triangles(mesh)  # geometry id 1 = SOLE_GEOMETRY

    def cast(self, pixels: np.ndarray | None, K: np.ndarray, D: np.ndarray, pose: np.ndarray) -> dict[str, np.ndarray]:
        """Trace the rays of the given pixel positions (all pixel centres when None)."""
        if pixels is None:
            normalised = _pixel_rays(K.tobytes(), D.tobytes(), self.image_size)
        else:
            normalised = _undistort(pixels, K, D)
        # Direction (x, y, 1) in the camera frame: the hit distance t is then the camera z-depth.
        rotation = pose[:3, :3].astype(np.float32)
        directions = normalised @ rotation[:, :2].T + rotation[:, 2]
        rays = np.empty((len(directions), 6), np.float32)
        rays[:, :3] = pose[:3, 3]
        rays[:, 3:] = directions
        result = self._scene.cast_rays(_tensor(rays, o3d.core.float32))
        t = result["t_hit"].numpy()
        hit = np.isfinite(t)
        geometry = np.where(hit, result["geometry_ids"].numpy().astype(np.int32), -1)
        part = np.full(len(t), -1, np.int32)
        on_sole = geometry == SOLE_GEOMETRY
        part[on_sole] = self._parts[result["primitive_ids"].numpy()[on_sole]]
        # Positions in float64: the texture and the sole's height field need better than 0.01 mm.
        points = pose[:3, 3] + directions.astype(np.float64) * np.where(hit, t, 0.0)[:, None]
        return {
            "t": t,
            "geometry": geometry,
            "part": part,
            "points": points,
            "facet_normals": result["primitive_normals"].numpy(),
        }

    def unshadowed(
        self, points: np.ndarray, normals: np.ndarray, hit: np.ndarray, light_positions: np.ndarray
    ) -> np.ndarray:
        """Per light (L x N, bool): whether the straight line from each hit point to the light is free."""
        lit = np.zeros((len(light_positions), len(points)), bool)
        start = (points + SHADOW_RAY_LIFT_MM * normals)[hit].astype(np.float32)
        for k, light in enumerate(light_positions):
            # Ray direction = the full vector to the light: anything hit at t < 1 lies between point and light.
            rays = np.hstack([start, light.astype(np.float32) - start])
            t = self._scene.cast_rays(_tensor(rays, o3d.core.float32))["t_hit"].numpy()
            lit[k, hit] = ~(t < 1.0)
        return lit

    def edge_pixels(self, hits: dict[str, np.ndarray], shape: tuple[int, int]) -> np.ndarray:
        """Indices of pixels next to a change of surface or a depth step: these get supersampled."""
        label = (hits["geometry"] * 4 + np.maximum(hits["part"], 0)).reshape(shape).astype(np.int32)
        depth = np.nan_to_num(hits["t"], nan=1e6).reshape(shape)
        kernel = np.ones((3, 3), np.uint8)
        label_f = label.astype(np.float32)
        changes = cv2.dilate(label_f, kernel) != cv2.erode(label_f, kernel)
        steps = (cv2.dilate(depth.astype(np.float32), kernel) - cv2.erode(depth.astype(np.float32), kernel)) > 2.0
        return np.flatnonzero(changes | steps)


def _undistort(pixels: np.ndarray, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Normalised image coordinates (N x 2, float32) of distorted pixel positions."""
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    points = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
    return cv2.undistortPoints(points, K, D, criteria=criteria).reshape(-1, 2).astype(np.float32)


@functools.lru_cache(maxsize=4)
def _pixel_rays(K_bytes: bytes, D_bytes: bytes, size: tuple[int, int]) -> np.ndarray:
    """Normalised coordinates of every pixel centre of a camera; cached because it is the slow part of a render."""
    K = np.frombuffer(K_bytes, np.float64).reshape(3, 3)
    D = np.frombuffer(D_bytes, np.float64).reshape(1, -1)
    width, height = size
    xs, ys = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = _undistort(np.column_stack([xs.ravel(), ys.ravel()]), K, D)
    rays.setflags(write=False)
    return rays


def _tensor(array: np.ndarray, dtype: o3d.core.Dtype) -> o3d.core.Tensor:
    """A copy of `array` as an Open3D tensor of `dtype` on the CPU (Open3D's stubs want both spelled out)."""
    return o3d.core.Tensor(array, dtype, _CPU)


def _table_mesh() -> o3d.t.geometry.TriangleMesh:
    half = 2000.0
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = _tensor(
        np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]]), o3d.core.float32
    )
    mesh.triangle.indices = _tensor(np.array([[0, 1, 2], [0, 2, 3]]), o3d.core.int32)
    return mesh
