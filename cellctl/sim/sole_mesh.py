"""The simulated sole as a closed triangle mesh for the renderer's ray casting (cellctl.sim.render)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from cellctl.sim.sole import SoleModel

MESH_U_SAMPLES = 600
MESH_S_SAMPLES = 61
MESH_S_SAMPLES_EDGED = 121  # with an edge profile: columns crowd towards the outline to resolve the profile


def sole_mesh(model: SoleModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed triangle mesh in the table frame: vertices (V x 3), triangles (T x 3), part per triangle.

    Parts: 0 top surface, 1 side wall, 2 underside, 3 top surface within the edge profile. The top is a
    (u, s) grid where s in [-1, 1] runs from the lateral to the medial edge; the grid collapses to a point
    at each tip. With an edge profile the columns crowd towards the edges and the top takes the profile.
    """
    shape = model.shape
    u = shape.u_samples(MESH_U_SAMPLES)
    if shape.edge.plain:
        s = np.linspace(-1.0, 1.0, MESH_S_SAMPLES)
    else:
        t = np.linspace(-1.0, 1.0, MESH_S_SAMPLES_EDGED)
        s = np.sign(t) * (1.0 - (1.0 - np.abs(t)) ** 2)
    centre = shape.centre_line(u)
    medial, lateral = shape.half_width(u, True), shape.half_width(u, False)
    uu = np.repeat(u, s.size)
    ss = np.tile(s, u.size)
    vv = np.repeat(centre, s.size) + np.where(ss >= 0, ss * np.repeat(medial, s.size), ss * np.repeat(lateral, s.size))
    xy = model.pose.to_table(np.column_stack([uu, vv]), shape.length)
    plain_top = shape.top_height(uu, vv)
    top_z = shape.surface_height(uu, vv)
    top = np.column_stack([xy, top_z])
    bottom = np.column_stack([xy, shape.underside(uu)])
    grid = _grid_triangles(u.size, s.size)
    n_grid = top.shape[0]
    # Wall quads between the top and underside edge rings (lateral s=-1 and medial s=+1 columns).
    walls = []
    for column in (0, s.size - 1):
        ring = np.arange(u.size) * s.size + column
        a, b = ring[:-1], ring[1:]
        quads = np.vstack([np.column_stack([a, b, b + n_grid]), np.column_stack([a, b + n_grid, a + n_grid])])
        # Winding so that facet normals point out of the sole: the lateral ring (s = -1) runs the other way.
        walls.append(quads[:, ::-1] if column == 0 else quads)
    vertices = np.vstack([top, bottom])
    triangles = np.vstack([grid, *walls, grid[:, ::-1] + n_grid])
    on_profile = np.any(np.abs(plain_top - top_z)[grid] > 1e-9, axis=1)  # a lip rises: a profile too
    parts = np.concatenate(
        [
            np.where(on_profile, 3, 0).astype(np.int32),
            np.ones(sum(len(w) for w in walls), np.int32),
            np.full(len(grid), 2, np.int32),
        ]
    )
    if model.pose.mirrored:
        # Mirroring reverses the winding; keep triangle normals pointing out of the sole.
        triangles = triangles[:, ::-1]
    return vertices, triangles.astype(np.int32), parts


def _grid_triangles(rows: int, cols: int) -> np.ndarray:
    r, c = np.meshgrid(np.arange(rows - 1), np.arange(cols - 1), indexing="ij")
    a = (r * cols + c).ravel()
    b, d = a + 1, a + cols
    return np.vstack([np.column_stack([a, d, b]), np.column_stack([b, d, d + 1])])
