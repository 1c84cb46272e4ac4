"""Middlebury data sets in their three folder layouts, read into one `Scene` shape.

- 2001/2003 ("newEval" v2, the paper's Table 3): `<scene>/left.png right.png gt.png` with the
  region masks nonocc/all/disc (255 = evaluated); scales and ranges are fixed per scene
  (`middlebury.SCENES`).
- 2005/2006: `<Scene>/left.png right.png gt.png` (third size), disparity = gt / 3, 0 = unknown,
  no masks.  Evaluated: every pixel with known ground truth except the left band x < number of
  disparities, where no match exists (the data folder's README.txt).  The range is
  0 .. ceil(max gt) + 1 (ceil(max gt) + 2 disparities), as that README advises.
- 2014: `<Scene>/im0.png im1.png disp0GT.pfm calib.txt mask0nocc.png`; disparity in px as float
  (inf = unknown), ndisp from calib.txt; regions "nonocc" (mask 255) and "all" (known ground truth).

`load_dataset(folder)` reads every scene folder it finds, each by its own layout.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from cellctl.eval import middlebury
from cellctl.eval.middlebury import Scene, SceneInfo

LAYOUT_2001 = "2001-2003"
LAYOUT_2005 = "2005-2006"
LAYOUT_2014 = "2014"
SCALE_2005 = 3  # 2005/2006 third size: disparity = gt value / 3


def scene_layout(folder: Path) -> str | None:
    """The layout of one scene folder, None if it holds no known layout."""
    if all((folder / name).is_file() for name in ("im0.png", "im1.png", "disp0GT.pfm", "calib.txt")):
        return LAYOUT_2014
    if all((folder / name).is_file() for name in ("left.png", "right.png", "gt.png")):
        has_masks = all((folder / f"{r}.png").is_file() for r in middlebury.REGIONS)
        if has_masks and folder.name in middlebury.SCENES:
            return LAYOUT_2001
        return LAYOUT_2005
    return None


def load_dataset(data_dir: str | Path, names: list[str] | None = None) -> list[Scene]:
    """Every scene of a data folder (sorted by name; 2001/2003 in Middlebury's order), or the named ones."""
    root = Path(data_dir)
    if not root.is_dir():
        raise FileNotFoundError(f"Middlebury data folder not found: {root} (check the --data path)")
    found = {p.name: layout for p in root.iterdir() if p.is_dir() and (layout := scene_layout(p)) is not None}
    if not found:
        raise FileNotFoundError(
            f"{root} holds no Middlebury scene folder (expected <scene>/left.png right.png gt.png [masks], "
            "or <scene>/im0.png im1.png disp0GT.pfm calib.txt)"
        )
    order = [n for n in middlebury.SCENES if n in found] + sorted(n for n in found if n not in middlebury.SCENES)
    if names is not None:
        unknown = [n for n in names if n not in found]
        if unknown:
            raise ValueError(f"scene(s) {', '.join(unknown)} not in {root}; it holds {', '.join(order)}")
        order = [n for n in order if n in names]
    return [load_scene_folder(root / name, found[name]) for name in order]


def load_scene_folder(folder: Path, layout: str | None = None) -> Scene:
    """One scene folder in the given (or detected) layout."""
    layout = layout or scene_layout(folder)
    if layout == LAYOUT_2001:
        return middlebury.load_scene(folder.name, folder.parent)
    if layout == LAYOUT_2005:
        return _load_2005(folder)
    if layout == LAYOUT_2014:
        return _load_2014(folder)
    raise FileNotFoundError(f"{folder} is not a Middlebury scene folder (no left/right/gt or im0/im1/disp0GT)")


def _image(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise ValueError(f"cannot decode image {path}")
    return image


def _same_size(folder: Path, reference: np.ndarray, **images: np.ndarray) -> None:
    for name, image in images.items():
        if image.shape[:2] != reference.shape[:2]:
            raise ValueError(
                f"{folder / name} is {image.shape[1]}x{image.shape[0]}, "
                f"the left image {reference.shape[1]}x{reference.shape[0]}"
            )


def _load_2005(folder: Path) -> Scene:
    left = _image(folder / "left.png", cv2.IMREAD_COLOR)
    right = _image(folder / "right.png", cv2.IMREAD_COLOR)
    gt_image = _image(folder / "gt.png", cv2.IMREAD_UNCHANGED)
    if gt_image.ndim != 2 or gt_image.dtype != np.uint8:
        raise ValueError(f"{folder / 'gt.png'} must be an 8-bit single-channel PNG")
    _same_size(folder, left, **{"right.png": right, "gt.png": gt_image})
    gt = middlebury.ground_truth_disparity(gt_image, SCALE_2005)
    if not np.isfinite(gt).any():
        raise ValueError(f"{folder / 'gt.png'} has no known disparity (all values 0)")
    num = math.ceil(float(np.nanmax(gt))) + 2
    if num >= left.shape[1]:
        raise ValueError(f"{folder}: ground truth up to {num - 2} px does not fit an image {left.shape[1]} px wide")
    evaluated = np.ones(gt.shape, bool)
    evaluated[:, :num] = False  # the left band: no match exists there
    info = SceneInfo(folder.name, scale=SCALE_2005, min_disparity=0, num_disparities=num, layout=LAYOUT_2005)
    return Scene(info, left, right, gt, {"all": evaluated})


def read_pfm(path: Path) -> np.ndarray:
    """A one-channel PFM image as float32, top row first (PFM stores the bottom row first)."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        size = f.readline().split()
        scale_line = f.readline().strip()
        data = f.read()
    if kind != b"Pf" or len(size) != 2:
        raise ValueError(f"{path} is not a one-channel PFM file (header {kind!r})")
    try:
        width, height, scale = int(size[0]), int(size[1]), float(scale_line)
    except ValueError:
        raise ValueError(f"{path}: unreadable PFM header") from None
    dtype = "<f4" if scale < 0 else ">f4"
    if len(data) < width * height * 4:
        raise ValueError(f"{path} is truncated ({len(data)} bytes of data for {width}x{height})")
    pixels = np.frombuffer(data, dtype, count=width * height).reshape(height, width)
    return np.ascontiguousarray(pixels[::-1]).astype(np.float32)


def read_calib(path: Path) -> dict[str, str]:
    """calib.txt of the 2014 layout as key -> value text."""
    entries = {}
    for line in path.read_text().splitlines():
        if "=" in line:
            key, value = line.split("=", 1)
            entries[key.strip()] = value.strip()
    return entries


def _load_2014(folder: Path) -> Scene:
    left = _image(folder / "im0.png", cv2.IMREAD_COLOR)
    right = _image(folder / "im1.png", cv2.IMREAD_COLOR)
    gt = read_pfm(folder / "disp0GT.pfm")
    gt[~np.isfinite(gt)] = np.nan
    calib = read_calib(folder / "calib.txt")
    try:
        num = int(calib["ndisp"])
    except (KeyError, ValueError):
        raise ValueError(f"{folder / 'calib.txt'} lacks a whole ndisp=N line") from None
    images = {"im1.png": right, "disp0GT.pfm": gt}
    mask_path = folder / "mask0nocc.png"
    known = np.isfinite(gt)
    regions = {"all": known}
    if mask_path.is_file():
        mask = _image(mask_path, cv2.IMREAD_GRAYSCALE)
        images["mask0nocc.png"] = mask
        regions = {"nonocc": middlebury.region_mask(mask) & known, "all": known}
    _same_size(folder, left, **images)
    if num < 1 or num >= left.shape[1]:
        raise ValueError(f"{folder / 'calib.txt'}: ndisp={num} does not fit an image {left.shape[1]} px wide")
    info = SceneInfo(folder.name, scale=1, min_disparity=0, num_disparities=num, layout=LAYOUT_2014)
    return Scene(info, left, right, gt, regions)
