"""The `cellctl simulate sole` scene: a stereo pair of a parametric sole with known measurements."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cellctl.errors import UserError


def configure(parser: argparse.ArgumentParser) -> None:
    """A simulated sole on the table: left.png, right.png and its true measurements.

    Writes left.png, right.png, truth.json (length, heel and toe height from the sole's model, its pose,
    the camera pose), depth_left.npy (true depth per left pixel), outline.npy (true footprint outline)
    and calib.yaml (the rig that took the pair) to the output directory. The same seed always gives the
    same sole, pose and noise. --variations adds entries of the variation matrix (`cellctl bench-sole
    --matrix --variations list` names them), e.g. pointed-toe,rim,gain-low. --empty N also writes N exposures
    of the scene's empty table (empty_1_left.png, empty_1_right.png, ...: `DIR/empty_*.png` lists them in
    teaching order) to teach it from (`cellctl teach` averages them), as a cell is taught before it measures.
    """
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="DIR", help="directory to write the scene to")
    parser.add_argument("--seed", type=int, default=0, help="sole shape, pose and noise (default 0)")
    # Checked in run(): the colours live with the renderer, which imports Open3D (slow for `--help`).
    parser.add_argument("--color", default="white", help="sole colour: white (default), black or grey")
    parser.add_argument(
        "--variations", metavar="NAME,...", default="", help="variation matrix entries to apply (default none)"
    )
    parser.add_argument(
        "--calib",
        type=Path,
        metavar="calib.yaml",
        help="rig to render through (default: the built-in simulated rig, or the one the variations name)",
    )
    parser.add_argument(
        "--empty",
        type=int,
        default=0,
        metavar="N",
        help="also write N exposures of the empty table to teach from (cellctl teach; 4 as the benchmark teaches)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import cv2

    from cellctl.sim.look import look_for
    from cellctl.sim.render import SOLE_MATERIALS
    from cellctl.sim.scene import SoleScene
    from cellctl.vision.calibration import Calibration

    if not 0 <= args.empty <= 9:
        raise UserError(f"--empty {args.empty}: the number of empty-table exposures must be 0..9")
    if args.color not in SOLE_MATERIALS:
        raise UserError(f"--color {args.color!r} is not one of {', '.join(sorted(SOLE_MATERIALS))}")
    calib = Calibration.load(args.calib) if args.calib else None
    start = time.perf_counter()
    try:
        look = look_for(tuple(name for name in args.variations.split(",") if name), args.seed)
        scene = SoleScene.random(args.seed, args.color, calib, look)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    pair = scene.render()
    out = scene.write(args.out, pair)
    empty = ""
    for number, shot in enumerate(scene.render_empties(list(range(1, args.empty + 1))) if args.empty else [], 1):
        for name, image in ((f"empty_{number}_left.png", shot.left), (f"empty_{number}_right.png", shot.right)):
            if not cv2.imwrite(str(out / name), image):
                raise UserError(f"cannot write {out / name}: check the directory is writable")
        empty = f", empty_1..{number}_left.png, empty_1..{number}_right.png"
    truth = scene.truth()
    print(
        f"wrote {out}/left.png, right.png{empty}, truth.json, depth_left.npy, outline.npy, calib.yaml in "
        f"{time.perf_counter() - start:.1f} s: {args.color} sole, seed {args.seed}"
        f"{', ' + args.variations if args.variations else ''}, length {truth['length_mm']:.2f} mm, "
        f"heel {truth['heel_height_mm']:.2f} mm, toe {truth['toe_height_mm']:.2f} mm"
    )
    return 0
