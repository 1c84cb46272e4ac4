"""`cellctl measure`: measure one sole from a stereo pair (length, heel and toe height, glue path).

Exit status: 0 measured, 1 not measured (the reason is printed, and in the JSON), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:
    import numpy as np

    from cellctl.vision.measurement import MeasurementResult
    from cellctl.vision.reconstruction import ReconstructionResult


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "measure",
        help="measure a sole from a stereo pair (length, heel/toe height, glue path)",
        description=(
            "Reconstruct the sole from a raw (unrectified) left/right pair and print its length, heel and toe "
            "height and glue path as defined in docs/measurements.md. Exit status 1 if the sole could not be "
            "measured (the reason is printed)."
        ),
    )
    parser.add_argument("--calib", required=True, type=Path, metavar="calib.yaml", help="stereo calibration")
    parser.add_argument("left", type=Path, metavar="LEFT", help="left image")
    parser.add_argument("right", type=Path, metavar="RIGHT", help="right image")
    parser.add_argument(
        "--mean",
        nargs=2,
        type=Path,
        metavar=("MEAN_LEFT", "MEAN_RIGHT"),
        help="the mean of the cycle's exposures of the same view (the image log's meanleft_/meanright_ files): the "
        "sole's surface is fitted on them, as the cycle did (default: on LEFT and RIGHT)",
    )
    parser.add_argument(
        "--depth-range",
        nargs=2,
        type=float,
        metavar=("MIN", "MAX"),
        help="working distance from the cameras in mm (default 450 650): sets the disparity search range",
    )
    # Defaults live in cellctl.vision.measurement, which is imported only when the command runs (Open3D is slow to load).
    parser.add_argument("--glue-offset", type=float, metavar="MM", help="glue path inset from the edge (default 2)")
    parser.add_argument("--glue-spacing", type=float, metavar="MM", help="glue path point spacing (default 2)")
    parser.add_argument(
        "--glue-height-tolerance",
        type=float,
        metavar="MM",
        help="how far glue heights may stray: a sole measured too coarsely for it is refused (default 1)",
    )
    wall = parser.add_mutually_exclusive_group()
    wall.add_argument(
        "--vertical-wall",
        action="store_true",
        help="the sole's side wall is known not to lean out (its mould): measure it even if its wall is too low all "
        "round for the cell to check (under 10 mm; refused as wall_too_low otherwise)",
    )
    wall.add_argument(
        "--wall-draft",
        type=float,
        metavar="DEG",
        help="the sole's side wall leans out this many degrees from its top edge to the table (its mould's draft, "
        "0..10): the outline, length and glue path are taken at the foot the cameras cannot see",
    )
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument(
        "--ply", type=Path, metavar="out.ply", help="write the sole's point cloud (table frame, colours)"
    )
    parser.add_argument(
        "--export",
        type=Path,
        metavar="DIR",
        help="write glue-path.csv, glue-path.ply (polyline with normals) and cloud.ply (with normals), table frame",
    )
    parser.add_argument(
        "--png", type=Path, metavar="overlay.png", help="write the left image with edge, glue path and points"
    )
    parser.add_argument(
        "--untaught",
        action="store_true",
        help="measure without a taught table (`cellctl teach`): the colour test finds the edge, reliable only for "
        "a plain one-colour sole on a plain table (docs/measurements.md)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import cv2

    from cellctl.images import lossy_warning
    from cellctl.vision.calibration import Calibration
    from cellctl.vision.defaults import GLUE_HEIGHT_TOLERANCE_MM, GLUE_OFFSET_MM, GLUE_SPACING_MM
    from cellctl.vision.measurement import check_glue_settings, measure_sole
    from cellctl.vision.reconstruction import DEFAULT_DEPTH_RANGE_MM, SoleReconstructor
    from cellctl.vision.teach import TeachError, load_taught
    from cellctl.vision.wall_draft import check_draft

    offset = GLUE_OFFSET_MM if args.glue_offset is None else args.glue_offset
    spacing = GLUE_SPACING_MM if args.glue_spacing is None else args.glue_spacing
    tolerance = GLUE_HEIGHT_TOLERANCE_MM if args.glue_height_tolerance is None else args.glue_height_tolerance
    try:
        check_glue_settings(offset, spacing, tolerance)
    except ValueError as exc:
        raise UserError(f"--glue-offset/--glue-spacing/--glue-height-tolerance: {exc}") from None
    draft = 0.0 if args.vertical_wall else args.wall_draft
    if draft:
        try:
            check_draft(draft)
        except ValueError as exc:
            raise UserError(f"--wall-draft: {exc}") from None
    calib = Calibration.load(args.calib)
    left, right = _read(args.left, "LEFT"), _read(args.right, "RIGHT")
    mean = None if args.mean is None else (_read(args.mean[0], "MEAN_LEFT"), _read(args.mean[1], "MEAN_RIGHT"))
    named = [("LEFT", args.left, left), ("RIGHT", args.right, right)]
    if mean is not None:
        named += [("MEAN_LEFT", args.mean[0], mean[0]), ("MEAN_RIGHT", args.mean[1], mean[1])]
    for name, path, image in named:
        if warning := lossy_warning(path, f"{name} image"):
            print(warning, file=sys.stderr)
        try:
            calib.check_image(image)
        except ValueError as exc:
            raise UserError(f"{name} {path}: {exc}") from None
    if mean is not None:
        from cellctl.cameras.averaging import frames_agree

        for side, (name, path, single) in enumerate(named[:2]):
            if not frames_agree(single, mean[side]):  # fitted on another view, the surface would be another sole's
                raise UserError(
                    f"MEAN_{name} {args.mean[side]} does not show the same still view as {name} {path}: give the "
                    "mean of that cycle's exposures (the image log's meanleft_/meanright_ files of the same number), "
                    "or leave --mean out"
                )
    depth_range = tuple(args.depth_range) if args.depth_range else DEFAULT_DEPTH_RANGE_MM
    try:  # a table taught beside the calibration (`cellctl teach`) is used when there is one
        taught = load_taught(args.calib, calib)
    except TeachError as exc:
        raise UserError(str(exc)) from None
    if taught is None and not args.untaught:  # as the service's require_taught_table (docs/service.md)
        raise UserError(
            f"no taught table beside {args.calib}: teach the empty fixture first (cellctl teach --calib "
            f"{args.calib} LEFT RIGHT), or pass --untaught for a plain one-colour sole on a plain table"
        )
    reconstruction = SoleReconstructor(calib, depth_range, taught=taught).reconstruct(left, right, mean)
    result = measure_sole(reconstruction, offset, spacing, tolerance, wall_draft_deg=draft)
    if args.ply:
        _write_ply(args.ply, reconstruction)
    if args.export:
        _export(args.export, reconstruction, result)
    if args.png:
        from cellctl.vision.overlay import draw_overlay

        if not cv2.imwrite(str(args.png), draw_overlay(left, calib, reconstruction, result)):
            raise UserError(f"cannot write {args.png}: check the directory exists and is writable")
    if args.json:
        print(json.dumps(result.to_dict()))
    else:
        print(_summary(result))
    return 0 if result.valid else 1


def _read(path: Path, name: str) -> np.ndarray:
    from cellctl.images import read_image  # OpenCV: not at the top, so --help stays light

    try:
        return read_image(path, what=f"{name} image")
    except ValueError as exc:
        raise UserError(str(exc)) from None


def _write_ply(path: Path, reconstruction: ReconstructionResult) -> None:
    import open3d as o3d

    from cellctl.vision.reconstruction import ReconstructionRefused

    if len(reconstruction.sole_points) == 0:
        why = reconstruction.reason if isinstance(reconstruction, ReconstructionRefused) else "none found"
        raise UserError(f"no sole points to write to {path}: {why}")
    if not o3d.io.write_point_cloud(path, reconstruction.point_cloud()):
        raise UserError(f"cannot write {path}: check the directory exists and is writable")


def _export(directory: Path, reconstruction: ReconstructionResult, result: MeasurementResult) -> None:
    from cellctl.vision.export import cloud_normals, write_cloud_ply, write_glue_csv, write_glue_ply
    from cellctl.vision.measurement import SoleMeasurement

    if not directory.is_dir():
        raise UserError(f"--export {directory} is not a directory: create it first")
    points = reconstruction.sole_points
    if len(points):
        write_cloud_ply(directory / "cloud.ply", points, cloud_normals(points), reconstruction.sole_colors[:, ::-1])
    if isinstance(result, SoleMeasurement):
        path = result.glue_path
        write_glue_csv(directory / "glue-path.csv", path.points, path.normals)
        write_glue_ply(directory / "glue-path.ply", path.points, path.normals, "table", path.closed)


def _summary(result: MeasurementResult) -> str:
    from cellctl.vision.measurement import MeasurementRefused

    if isinstance(result, MeasurementRefused):
        return f"not measured: {result.reason}"
    path = result.glue_path
    total = sum(result.timings.values())
    return "\n".join(
        [
            f"length_mm       {result.length_mm:8.2f}",
            f"heel_height_mm  {result.heel_height_mm:8.2f}",
            f"toe_height_mm   {result.toe_height_mm:8.2f}",
            f"glue_path       {len(path.points)} points, {path.length_mm:.0f} mm, closed, from the heel end",
            f"points          {result.points}",
            f"time            {total:.2f} s",
        ]
    )
