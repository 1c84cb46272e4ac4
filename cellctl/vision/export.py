"""Files for robot and CAD tools: the glue path as CSV and PLY polyline, the sole's cloud as PLY with normals.

    write_glue_csv(path, points, normals)                       # i,x_mm,y_mm,z_mm,nx,ny,nz
    write_glue_ply(path, points, normals, frame="table")        # vertices with normals + closing edges
    write_cloud_ply(path, points, normals, colours, frame="table")

Every PLY names its frame and units in header comments (`comment frame: ...`, `comment units: mm`), which
robot offline-programming tools and CloudCompare show; the CSV has one header row and nothing else, because
robot controllers' CSV readers rarely skip comments. The PLY writer is written here rather than taken from
Open3D because Open3D cannot write header comments or an edge element.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import ArrayLike

#: What each frame name means, for the header comment.
FRAMES = {
    "table": "table frame of the cell: origin under the left camera on the table plane, z up from the table",
    "robot": "robot base frame, through the transform taught with `cellctl teach-robot`",
}
#: Normals of the cloud: height grid step and blur radius in cells (a ~2 mm patch, like the glue normals' fit).
NORMAL_GRID_MM = 1.0
NORMAL_BLUR_CELLS = 2
MIN_SPREAD_MM2 = 0.1  # variance (mm²) of a neighbourhood's points along each direction needed for a slope


def write_glue_csv(path: Path, points: ArrayLike, normals: ArrayLike) -> None:
    """The glue path, one row per point in path order: index, position (mm), unit normal."""
    xyz, nrm = _path(points, normals)
    rows = np.column_stack([np.arange(len(xyz)), xyz, nrm])
    header = "i,x_mm,y_mm,z_mm,nx,ny,nz"
    np.savetxt(path, rows, delimiter=",", header=header, comments="", fmt=["%d"] + ["%.4f"] * 3 + ["%.6f"] * 3)


def write_glue_ply(
    path: Path, points: ArrayLike, normals: ArrayLike, frame: str = "table", closed: bool = True
) -> None:
    """The glue path as a PLY polyline: vertices with normals, and an edge from each point to the next."""
    xyz, nrm = _path(points, normals)
    count = len(xyz)
    ends = np.arange(1, count + 1) % count if closed else np.arange(1, count)
    starts = np.arange(len(ends))
    header = _header(
        frame,
        [f"element vertex {count}", *_props("float x y z nx ny nz")],
        [f"element edge {len(ends)}", "property int vertex1", "property int vertex2"],
        extra=["glue path in path order, starting at the heel" + (", closed" if closed else "")],
    )
    with path.open("w", encoding="ascii") as out:
        out.write(header)
        np.savetxt(out, np.column_stack([xyz, nrm]), fmt="%.4f %.4f %.4f %.6f %.6f %.6f")
        np.savetxt(out, np.column_stack([starts, ends]), fmt="%d %d")


def write_cloud_ply(
    path: Path, points: ArrayLike, normals: ArrayLike, colours: ArrayLike | None = None, frame: str = "table"
) -> None:
    """A point cloud as binary PLY (x, y, z, nx, ny, nz float32, then red, green, blue uchar if given)."""
    xyz, nrm = _path(points, normals)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    properties = _props("float x y z nx ny nz")
    rgb = None if colours is None else np.asarray(colours)
    if rgb is not None:
        if rgb.shape != xyz.shape:
            raise ValueError(f"colours {rgb.shape} must match points {xyz.shape}")
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        properties += _props("uchar red green blue")
    data = np.empty(len(xyz), dtype=fields)
    for k, name in enumerate(("x", "y", "z")):
        data[name], data["n" + name] = xyz[:, k], nrm[:, k]
    if rgb is not None:
        for k, name in enumerate(("red", "green", "blue")):
            data[name] = np.clip(rgb[:, k], 0, 255)
    header = _header(frame, [f"element vertex {len(xyz)}", *properties], binary=True)
    with path.open("wb") as out:
        out.write(header.encode("ascii"))
        out.write(data.tobytes())


def cloud_normals(points: ArrayLike, cell_mm: float = NORMAL_GRID_MM) -> np.ndarray:
    """Unit normals (nz > 0) of a cloud seen from above, in the table frame: the sole's top is a height field.

    A least-squares plane z = a x + b y + c per grid cell, fitted to the points of a Gaussian neighbourhood
    (~2 mm): the plane's moments are summed on a cell_mm grid and blurred, so every cell solves a 3 x 3
    system. OpenCV's blur releases the GIL, so the PLC link's heartbeat keeps running (Open3D's
    nearest-neighbour estimate took ~1.7 s on a sole's 140k points while holding it).
    """
    xyz = np.asarray(points, float)
    if len(xyz) == 0:
        return np.zeros((0, 3))
    origin = xyz[:, :2].min(axis=0)
    local = xyz[:, :2] - origin
    cells = np.floor(local / cell_mm).astype(np.int64) + NORMAL_BLUR_CELLS
    width, height = cells.max(axis=0) + NORMAL_BLUR_CELLS + 1
    index = cells[:, 1] * width + cells[:, 0]
    x, y, z = local[:, 0], local[:, 1], xyz[:, 2]
    size = 2 * NORMAL_BLUR_CELLS + 1

    def moment(values: np.ndarray) -> np.ndarray:
        grid = np.bincount(index, weights=values, minlength=width * height).reshape(height, width)
        return cv2.GaussianBlur(grid, (size, size), 0).ravel()[index]

    weight = np.maximum(moment(np.ones(len(xyz))), 1e-12)
    mx, my, mz = moment(x) / weight, moment(y) / weight, moment(z) / weight
    # Centred second moments of the neighbourhood (float64: ~4 of 16 digits lost to the offset from origin).
    vxx, vyy = moment(x * x) / weight - mx * mx, moment(y * y) / weight - my * my
    vxy = moment(x * y) / weight - mx * my
    vxz, vyz = moment(x * z) / weight - mx * mz, moment(y * z) / weight - my * mz
    det = vxx * vyy - vxy * vxy
    normals = np.tile([0.0, 0.0, 1.0], (len(xyz), 1))
    ok = det > MIN_SPREAD_MM2**2  # a neighbourhood spread in both directions; else the slope is unknown: up
    normals[ok, 0] = -(vyy[ok] * vxz[ok] - vxy[ok] * vyz[ok]) / det[ok]
    normals[ok, 1] = -(vxx[ok] * vyz[ok] - vxy[ok] * vxz[ok]) / det[ok]
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def read_ply_header(path: Path) -> list[str]:
    """The header lines of a PLY file up to and including end_header (for checks and tools)."""
    lines: list[str] = []
    with path.open("rb") as source:
        for raw in source:
            line = raw.decode("ascii").rstrip("\n")
            lines.append(line)
            if line == "end_header":
                return lines
    raise ValueError(f"{path} has no PLY end_header line")


def _path(points: ArrayLike, normals: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    xyz, nrm = np.asarray(points, float), np.asarray(normals, float)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape != nrm.shape:
        raise ValueError(f"need N x 3 points and normals of the same shape, got {xyz.shape} and {nrm.shape}")
    return xyz, nrm


def _props(spec: str) -> list[str]:
    kind, *names = spec.split()
    return [f"property {kind} {name}" for name in names]


def _header(frame: str, *elements: list[str], extra: list[str] | None = None, binary: bool = False) -> str:
    if frame not in FRAMES:
        raise ValueError(f"frame {frame!r} is not one of {', '.join(FRAMES)}")
    lines = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment written by cellctl",
        f"comment frame: {frame} ({FRAMES[frame]})",
        "comment units: mm; normals are unit vectors pointing away from the sole's top surface",
        *(f"comment {text}" for text in extra or []),
    ]
    for element in elements:
        lines += element
    return "\n".join([*lines, "end_header"]) + "\n"
