"""Radiometric check: the same scenes with the right image's intensities changed.

Real pairs differ in exposure, gain and response between the two cameras (Middlebury 2005/2006
and 2014 ship such pairs; a cell's two cameras drift apart).  Each variant maps the right
image's 8-bit values through one monotonic curve, leaving the left image and the ground truth
alone, so a matcher's bad-pixel rate on a variant against the plain run shows how much it
relies on equal intensities.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np

from cellctl.eval.middlebury import Scene


@dataclass(frozen=True)
class Variant:
    """out = clip(255 * (gain * in / 255) ** gamma + offset), applied to every channel of the right image."""

    name: str
    gain: float = 1.0
    gamma: float = 1.0
    offset: float = 0.0

    def lut(self) -> np.ndarray:
        x = np.arange(256, dtype=np.float64) / 255.0
        y = 255.0 * np.clip(self.gain * x, 0.0, 1.0) ** self.gamma + self.offset
        return np.clip(np.round(y), 0, 255).astype(np.uint8)


VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant("gain", gain=0.8),
        Variant("gamma", gamma=1.2),
        Variant("offset", offset=20.0),
        Variant("all", gain=0.8, gamma=1.2, offset=20.0),
    )
}


def apply(scene: Scene, variant: Variant) -> Scene:
    """The scene with its right image mapped through the variant's curve."""
    return replace(scene, right=cv2.LUT(scene.right, variant.lut()))
