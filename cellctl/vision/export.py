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

import numpy as np
from numpy.typing import ArrayLike

#: What each frame name means, for the header comment.
FRAMES = {
    "table": "table frame of the cell: origin under the left camera on the table plane, z up from the table",
    "robot": "robot base frame, through the transform taught with `cellctl teach-robot`",
}
#: Normals of the cloud: from this many nearest neighbours (a ~2 mm patch at the cloud's density).
CLOUD_NORMAL_NEIGHBOURS = 20


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


def cloud_normals(points: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Unit normals of a surface cloud from its nearest neighbours, turned towards `up` (the cameras' side)."""
    import open3d as o3d

    xyz = np.ascontiguousarray(np.asarray(points, np.float64))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    if len(xyz) >= 3:
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(CLOUD_NORMAL_NEIGHBOURS))
        cloud.orient_normals_to_align_with_direction(np.asarray(up, np.float64))
        return np.asarray(cloud.normals)
    return np.tile(np.asarray(up, float), (len(xyz), 1))


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
