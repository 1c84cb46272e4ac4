"""`cellctl demo`: the main job on simulated input, showing what the cell does.

Until the daemon exists (issue 6) this runs the matcher on Middlebury Teddy and
writes the coloured disparity map beside a colour-mapped ground truth.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import numpy as np

from cellctl.middlebury import load_scene, bad_pixel_percent
from cellctl.stereo import StereoMatcher


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("demo", help="run the matcher on Teddy and write a coloured disparity PNG",
                              description=__doc__)
    p.add_argument("--data", help="Middlebury 2001-2003 folder (default ../shared/data/middlebury/2001-2003)")
    p.add_argument("--out", default="demo-out", help="output folder (default demo-out)")
    p.set_defaults(func=run)


def colourise(disparity: np.ndarray, max_disparity: float) -> np.ndarray:
    """Colour-mapped disparity (OpenCV's TURBO map), invalid pixels black."""
    scaled = np.nan_to_num(disparity / max_disparity * 255.0, nan=0.0).clip(0, 255).astype(np.uint8)
    image = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    image[~np.isfinite(disparity)] = 0
    return image


def run(args: argparse.Namespace) -> int:
    scene = load_scene("teddy", args.data)
    matcher = StereoMatcher(scene.info.min_disparity, scene.info.num_disparities)
    matcher.compute(scene.left, scene.right)  # first call allocates the buffers
    t0 = time.perf_counter()
    result = matcher.compute_detailed(scene.left, scene.right)
    ms = (time.perf_counter() - t0) * 1e3
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    top = scene.info.num_disparities - 1
    picture = np.hstack([scene.left, colourise(scene.ground_truth, top), colourise(result.disparity, top)])
    path = out / "teddy-disparity.png"
    cv2.imwrite(str(path), picture)
    bad = bad_pixel_percent(result.disparity, scene.ground_truth, scene.regions["nonocc"])
    print(f"teddy {scene.left.shape[1]}x{scene.left.shape[0]}, {scene.info.num_disparities} disparities: "
          f"{ms:.1f} ms, {100 * result.valid.mean():.1f} % measured before fill, "
          f"{bad:.2f} % bad pixels (nonocc, > 1 px)")
    print(f"wrote {path} (left | ground truth | ours)")
    return 0
