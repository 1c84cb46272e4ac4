"""Ambient occlusion of the table by the sole: the room's diffuse light that still reaches a table point.

A physically based renderer darkens the table at the foot of anything standing on it: the object hides part of
the sky (the room's diffuse light) from the table beside it, most at the foot, fading over a distance of about the
object's height. The simulator's ambient light is otherwise the same everywhere, so this is a look another
simulator is likely to have and ours never had: a dark band hugging the sole's foot, on the table, in both views
and in neither taught image.

Model: beside a long straight wall of height h at distance d, a point of the floor sees the wall over the part of
its cosine-weighted hemisphere the wall subtends, the view factor (1 - d / sqrt(d^2 + h^2)) / 2 (a standard
result for an infinitely long strip: half the sky blocked at the foot, 15 % at d = h, 3 % at d = 3 h). Here h is
the sole's top height 5 mm inside the nearest point of its outline and d the distance to the outline; at a
convex end the sole hides less sky than a straight wall would, so the model darkens there somewhat more than
a full render: a bound, which the variation's strength (a factor on the blocked share) scales down.
"""

from __future__ import annotations

import cv2
import numpy as np

from cellctl.sim.sole import SoleModel
from cellctl.vision.closed_path import outward_normals

CELL_MM = 0.25  # raster of the distance and height fields (the table's pixels are ~0.4 mm)
MARGIN_MM = 150.0  # beyond this the blocked share is under 3 % of the sky for the tallest heels (50 mm)
HEIGHT_INSET_MM = 5.0  # the wall's height is read this far inside the outline, past a rounded or bevelled edge


def sky_fraction(sole: SoleModel, xy: np.ndarray, strength: float) -> np.ndarray:
    """Per table point (N x 2, table frame) the share of the room's diffuse light that reaches it: 1 less
    `strength` times the share of the sky the sole blocks (1 under the sole itself, which no camera sees)."""
    if strength <= 0.0 or len(xy) == 0:
        return np.ones(len(xy), np.float32)
    outline = sole.footprint_table()
    low = outline.min(axis=0) - MARGIN_MM
    shape = tuple(np.ceil((outline.max(axis=0) + MARGIN_MM - low) / CELL_MM).astype(int))  # (columns, rows)
    cells = np.round((outline - low) / CELL_MM).astype(np.int32)
    # The outline's samples as seeds, each labelled on its own (one label per seed pixel): the label of a cell's nearest
    # seed gives the wall height there.
    seeds = np.ones((shape[1], shape[0]), np.uint8)
    seeds[cells[:, 1], cells[:, 0]] = 0
    distance, labels = cv2.distanceTransformWithLabels(
        seeds, cv2.DIST_L2, cv2.DIST_MASK_PRECISE, labelType=cv2.DIST_LABEL_PIXEL
    )
    inside = np.zeros_like(seeds)
    cv2.fillPoly(inside, [cells.reshape(-1, 1, 2)], 1)
    height_of_label = np.zeros(int(labels.max()) + 1, np.float64)
    height_of_label[labels[cells[:, 1], cells[:, 0]]] = _wall_heights(sole, outline)
    column, row = np.round((xy - low) / CELL_MM).astype(np.int64).T
    on_grid = (column >= 0) & (column < shape[0]) & (row >= 0) & (row < shape[1])
    blocked = np.zeros(len(xy), np.float64)
    c, r = column[on_grid], row[on_grid]
    d = distance[r, c].astype(np.float64) * CELL_MM
    h = height_of_label[labels[r, c]]
    share = 0.5 * (1.0 - d / np.sqrt(d * d + np.maximum(h, 1e-6) ** 2))
    blocked[on_grid] = np.where(inside[r, c] > 0, 0.0, share)
    return (1.0 - strength * blocked).astype(np.float32)


def _wall_heights(sole: SoleModel, outline: np.ndarray) -> np.ndarray:
    """The sole's top height HEIGHT_INSET_MM inside each sample of its counter-clockwise outline."""
    return np.asarray(sole.top_height_at(outline - HEIGHT_INSET_MM * outward_normals(outline)), np.float64)
