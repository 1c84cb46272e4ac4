"""`cellctl teach-robot`: solve and store the table -> robot base transform, or re-check it after a bump.

The teach file is a CSV with a header row and one row per point the robot touched (or presented its target
at): robot_x, robot_y, robot_z (the robot's reading in its base frame, mm) and cell_x, cell_y, cell_z (the
same point measured by the cell in its table frame, mm). `--locate` measures the cell's side: it finds the
ArUco teach markers in a stereo pair (cellctl.vision.teach_target) and writes that CSV with the robot
columns left empty for the operator. docs/robot-frame.md describes the procedure.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path
from typing import TYPE_CHECKING

from cellctl.errors import UserError

if TYPE_CHECKING:  # numpy is imported where used: `cellctl --help` loads no heavy library
    import numpy as np

    from cellctl.service.config import CellConfig
    from cellctl.vision.calibration import Calibration

COLUMNS = ("robot_x", "robot_y", "robot_z", "cell_x", "cell_y", "cell_z")


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "teach-robot",
        help="solve the table -> robot base transform from touched points, or re-check it",
        description=(
            "Reads touched points (CSV: robot_x,robot_y,robot_z,cell_x,cell_y,cell_z in mm), solves the rigid "
            "transform from the cell's table frame to the robot base by least squares, rejects points that "
            "disagree by more than --tolerance, prints each point's residual and stores the transform beside "
            "the calibration. With --check, compares new points against the stored transform instead "
            "(exit 1 if the cell or robot moved)."
        ),
    )
    parser.add_argument("points", type=Path, metavar="POINTS.csv", help="touched points (with --locate: written)")
    parser.add_argument("--config", type=Path, help="cell config: the transform goes beside its calibration")
    parser.add_argument("--frame", type=Path, metavar="robot-frame.json", help="transform file (overrides --config)")
    parser.add_argument(
        "--tolerance", type=float, default=None, metavar="MM", help="largest residual of a good point (default 1.0)"
    )
    parser.add_argument("--check", action="store_true", help="re-check the stored transform, change nothing")
    parser.add_argument(
        "--locate",
        nargs=2,
        type=Path,
        metavar=("LEFT", "RIGHT"),
        help="measure the teach markers in this raw stereo pair and write POINTS.csv for the robot's readings",
    )
    parser.add_argument(
        "--locate-live",
        action="store_true",
        help="as --locate, with a pair grabbed from the config's cameras (stop the service first)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from cellctl.vision.robot_frame import DEFAULT_TOLERANCE_MM, FrameFitFailed, solve_robot_frame

    tolerance = DEFAULT_TOLERANCE_MM if args.tolerance is None else args.tolerance
    if tolerance <= 0:
        raise UserError(f"--tolerance {tolerance:g} mm must be positive")
    if args.locate or args.locate_live:
        return _locate(args)
    frame_path = _frame_path(args)
    robot, cell = read_points(args.points)
    if args.check:
        return _check(frame_path, robot, cell, tolerance)
    fit = solve_robot_frame(cell, robot, tolerance)
    if isinstance(fit, FrameFitFailed):
        print(f"cellctl teach-robot: not solved: {fit.reason}")
        return 1
    _print_points(fit.residuals_mm, fit.inliers, tolerance)
    from cellctl.vision.robot_frame import save_robot_frame

    save_robot_frame(frame_path, fit, note=f"taught from {args.points.name}")
    matrix = np.array2string(fit.transform.matrix, precision=4, suppress_small=True)
    print(f"table -> robot base:\n{matrix}")
    print(f"rms residual {fit.rms_mm:.3f} mm over {int(fit.inliers.sum())} points; saved to {frame_path}")
    if fit.rejected:
        print(f"rejected point(s) {', '.join(str(i + 1) for i in fit.rejected)}: check them and re-teach if unsure")
    if not fit.checked:
        print("warning: with 3 points no point is checked against the others; teach 4 or more")
    return 0


def read_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Robot and cell points (N x 3 each) from a teach CSV; UserError naming the row and column."""
    import numpy as np

    if not path.is_file():
        raise UserError(f"teach file {path} does not exist")
    with path.open(newline="", encoding="utf-8") as source:
        reader = csv.DictReader(row for row in source if row.strip() and not row.lstrip().startswith("#"))
        missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
        if missing:
            raise UserError(f"{path}: header lacks column(s) {', '.join(missing)} (need {','.join(COLUMNS)})")
        rows = []
        for number, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[c]) for c in COLUMNS])
            except (TypeError, ValueError):
                raise UserError(
                    f"{path}: data row {number - 1} has an empty or non-numeric value (fill in every robot_* "
                    f"and cell_* column): {dict(row)}"
                ) from None
    values = np.array(rows, dtype=float).reshape(-1, 6)
    if not np.all(np.isfinite(values)):
        raise UserError(f"{path}: a coordinate is not finite")
    return values[:, :3], values[:, 3:]


def _locate(args: argparse.Namespace) -> int:
    """Find the markers, write the teach CSV with the cell's coordinates filled in."""
    from cellctl.images import read_image
    from cellctl.vision.calibration import Calibration
    from cellctl.vision.reconstruction import SoleReconstructor
    from cellctl.vision.table import find_table
    from cellctl.vision.teach_target import locate_markers

    if args.config is None:
        raise UserError("--locate needs --config: the calibration and depth range of the cell")
    from cellctl.service.config import CellConfig

    config = CellConfig.load(args.config)
    calib = Calibration.load(config.calibration.path)
    images = _grab(config, calib) if args.locate_live else []
    for side, path in zip(("LEFT", "RIGHT"), args.locate or []):
        try:
            image = read_image(path, what=f"{side} image")
        except ValueError as exc:
            raise UserError(str(exc)) from None
        try:
            calib.check_image(image)
        except ValueError as exc:
            raise UserError(f"{side} image {path}: {exc}") from None
        images.append(image)
    cloud = SoleReconstructor(calib, config.measure.depth_range_mm).points_from_disparity(*images)
    table = find_table(cloud.points)
    if table is None:
        print("cellctl teach-robot: the table was not found in the pair: clear the view and check the depth range")
        return 1
    targets = locate_markers(calib, images[0], images[1], table)
    if not targets:
        print("cellctl teach-robot: no teach marker (ArUco 4x4, ids 0..49) seen by both cameras")
        return 1
    with args.points.open("w", encoding="utf-8") as out:
        out.write("# cell_*: measured by the cameras; fill in robot_* with the robot's reading at each marker centre\n")
        out.write("marker," + ",".join(COLUMNS) + "\n")
        for target in targets:
            x, y, z = target.table_xyz
            out.write(f"{target.marker_id},,,,{x:.3f},{y:.3f},{z:.3f}\n")
    for target in targets:
        x, y, z = target.table_xyz
        print(f" marker {target.marker_id:3d}: cell x={x:9.3f} y={y:9.3f} z={z:8.3f} mm")
    print(f"{len(targets)} markers written to {args.points}: add the robot's readings, then run teach-robot on it")
    return 0


def _grab(config: CellConfig, calib: Calibration) -> list[np.ndarray]:
    """One synchronised pair from the cell's own cameras."""
    from cellctl.cli.cameras import opened_cameras

    with opened_cameras(
        config, calib, "cannot grab a pair: {} (is `cellctl run` still holding the cameras?)"
    ) as source:
        frame = source.grab_pair()
    return [frame.left, frame.right]


def _frame_path(args: argparse.Namespace) -> Path:
    if args.frame is not None:
        return args.frame
    if args.config is None:
        raise UserError("give --config (the transform goes beside its calibration) or --frame FILE")
    from cellctl.service.config import CellConfig

    return CellConfig.load(args.config).robot_frame_path


def _check(frame_path: Path, robot: np.ndarray, cell: np.ndarray, tolerance: float) -> int:
    import numpy as np

    from cellctl.vision.robot_frame import load_robot_frame

    if not frame_path.is_file():
        raise UserError(f"no taught transform at {frame_path}: run `cellctl teach-robot POINTS.csv` first")
    transform = load_robot_frame(frame_path)
    residuals = np.linalg.norm(transform.apply(cell) - robot, axis=1)
    good = residuals <= tolerance
    _print_points(residuals, good, tolerance)
    if np.all(good):
        print(f"robot frame ok: largest residual {residuals.max():.3f} mm <= {tolerance:g} mm ({frame_path})")
        return 0
    print(
        f"robot frame MOVED: {int((~good).sum())} of {len(good)} points off by up to {residuals.max():.2f} mm: "
        "check the cell's and the robot's mounting, then re-teach (`cellctl teach-robot POINTS.csv`)"
    )
    return 1


def _print_points(residuals: np.ndarray, used: np.ndarray, tolerance: float) -> None:
    print(" point  residual_mm  status")
    for index, (residual, ok) in enumerate(zip(residuals, used), start=1):
        status = "used" if ok else f"REJECTED (> {tolerance:g} mm)"
        print(f" {index:5d}  {residual:11.3f}  {status}")
