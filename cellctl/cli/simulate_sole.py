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
    --matrix --variations list` names them), e.g. pointed-toe,rim,gain-low.
    """
    parser.add_argument("-o", "--out", required=True, type=Path, metavar="DIR", help="directory to write the scene to")
    parser.add_argument("--seed", type=int, default=0, help="sole shape, pose and noise (default 0)")
    # Checked in run(): the colours live with the renderer, which imports Open3D (slow for `--help`).
    parser.add_argument("--color", default="white", help="sole colour: white (default) or black")
    parser.add_argument(
        "--variations", metavar="NAME,...", default="", help="variation matrix entries to apply (default none)"
    )
    parser.add_argument(
        "--calib",
        type=Path,
        metavar="calib.yaml",
        help="rig to render through (default: the built-in simulated rig, or the one the variations name)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from cellctl.sim.look import look_for
    from cellctl.sim.render import SOLE_MATERIALS
    from cellctl.sim.scene import SoleScene
    from cellctl.vision.calibration import Calibration

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
    truth = scene.truth()
    print(
        f"wrote {out}/left.png, right.png, truth.json, depth_left.npy, outline.npy, calib.yaml in "
        f"{time.perf_counter() - start:.1f} s: {args.color} sole, seed {args.seed}"
        f"{', ' + args.variations if args.variations else ''}, length {truth['length_mm']:.2f} mm, "
        f"heel {truth['heel_height_mm']:.2f} mm, toe {truth['toe_height_mm']:.2f} mm"
    )
    return 0
