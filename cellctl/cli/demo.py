"""`cellctl demo`: the cell on simulated hardware, as `make demo` shows it.

Starts the service (`cellctl run --config deploy/cell-sim.toml`, simulated 1280x1024 cameras, Modbus TCP)
in a child process, drives it with the PLC simulator for several cycles, and prints what the PLC received
next to the simulated sole's true measurements. `--teddy` instead runs the stereo matcher on Middlebury
Teddy and writes the coloured disparity map beside the ground truth.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo",
        help="run the service on simulated cameras against the PLC simulator",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cycles", type=int, default=6, help="PLC cycles to run (default 6)")
    p.add_argument("--config", type=Path, help="service config (default deploy/cell-sim.toml)")
    p.add_argument("--port", type=int, default=5020, help="Modbus TCP port for the demo (default 5020)")
    p.add_argument("--station-port", type=int, help="operator station web port (default: [station] port of the config)")
    p.add_argument("--teddy", action="store_true", help="instead: the matcher on Middlebury Teddy")
    p.add_argument(
        "--data", help="with --teddy: Middlebury 2001-2003 folder (default ../shared/data/middlebury/2001-2003)"
    )
    p.add_argument(
        "-o", "--out", default="demo-out", help="output folder: journal, PLY and overlays, Teddy PNG (default demo-out)"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.teddy:
        return run_teddy(args)
    from cellctl.cli.demo_cell import run_cell_demo  # pymodbus: loaded only when the demo runs

    return run_cell_demo(args.config, args.port, args.cycles, Path(args.out), args.station_port)


def run_teddy(args: argparse.Namespace) -> int:
    import cv2
    import numpy as np

    from cellctl.eval.middlebury import bad_pixel_percent, load_scene
    from cellctl.eval.pictures import disparity_colour
    from cellctl.stereo import StereoMatcher

    scene = load_scene("teddy", args.data)
    matcher = StereoMatcher(scene.info.min_disparity, scene.info.num_disparities)
    matcher.compute(scene.left, scene.right)  # first call allocates the buffers
    t0 = time.perf_counter()
    result = matcher.compute_detailed(scene.left, scene.right)
    ms = (time.perf_counter() - t0) * 1e3
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lo, n = scene.info.min_disparity, scene.info.num_disparities
    truth, ours = (disparity_colour(d, lo, n) for d in (scene.ground_truth, result.disparity))
    picture = np.hstack([scene.left, truth, ours])
    path = out / "teddy-disparity.png"
    cv2.imwrite(str(path), picture)
    bad = bad_pixel_percent(result.disparity, scene.ground_truth, scene.regions["nonocc"])
    print(
        f"teddy {scene.left.shape[1]}x{scene.left.shape[0]}, {scene.info.num_disparities} disparities: "
        f"{ms:.1f} ms, {100 * result.valid.mean():.1f} % measured before fill, "
        f"{bad:.2f} % bad pixels (nonocc, > 1 px)"
    )
    print(f"wrote {path} (left | ground truth | ours)")
    return 0
