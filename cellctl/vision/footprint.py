"""The sole's footprint: a raster of the table plane marking where the sole is, seen from above.

Both the segmentation (largest region above the table) and the measurement (outline, axis, glue path)
work on this raster. A 2-D raster rather than 3-D clustering (e.g. DBSCAN) because the sole lies flat on
the table, so "one connected object" is a question about its plan view; OpenCV's connected components,
morphology and contours answer it in milliseconds where DBSCAN over ~10^5 points takes seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.stereo.kernels import cell_counts, cells_marked, label_areas, points_in_polygon

DEFAULT_CELL_MM = 0.5  # ~ the stereo pixel footprint at 550 mm (0.39 mm): most cells receive a point


@dataclass
class Footprint:
    """A binary raster of the table plane: cell (row, col) covers [x0 + col*c, x0 + (col+1)*c) x same in y."""

    mask: np.ndarray  # uint8, 1 = sole
    origin: tuple[float, float]  # table (x, y) in mm of the corner of cell (0, 0)
    cell_mm: float

    @classmethod
    def empty_like(cls, xy: np.ndarray, cell_mm: float = DEFAULT_CELL_MM, margin_mm: float = 10.0) -> Footprint:
        """An empty raster covering the points (N x 2) with a margin; cell corners lie on multiples of cell_mm,
        so rasters of the same cell size share their cells whatever they cover."""
        # Per column: numpy reduces an N x 2 array along its rows ~50 times slower (same values).
        lo = np.floor((np.array([xy[:, 0].min(), xy[:, 1].min()]) - margin_mm) / cell_mm) * cell_mm
        hi = np.array([xy[:, 0].max(), xy[:, 1].max()]) + margin_mm
        cols, rows = (np.ceil((hi - lo) / cell_mm).astype(int) + 1).tolist()
        return cls(np.zeros((rows, cols), np.uint8), (float(lo[0]), float(lo[1])), cell_mm)

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(row, col, inside) of points (N x 2); row/col are clipped where `inside` is False."""
        col = np.floor((xy[:, 0] - self.origin[0]) / self.cell_mm).astype(np.int64)
        row = np.floor((xy[:, 1] - self.origin[1]) / self.cell_mm).astype(np.int64)
        rows, cols = self.mask.shape
        inside = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
        return np.clip(row, 0, rows - 1), np.clip(col, 0, cols - 1), inside

    def counts(self, xy: np.ndarray) -> np.ndarray:
        """Number of points per cell (float32, the raster's shape); the cells as `cells` finds them, in C
        (one pass instead of numpy's ten over the ~5 10^5 points of a cycle)."""
        return cell_counts(xy, self.origin, self.cell_mm, self.mask.shape)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Whether each point (N x 2) lies in a marked cell (the cells as `cells` finds them, in C)."""
        return cells_marked(xy, self.origin, self.cell_mm, self.mask)

    def centres(self) -> np.ndarray:
        """Table (x, y) of the centres of the marked cells (N x 2)."""
        # The marked cells by flat index (np.nonzero's order; its two-index form costs ~4 x as much on the ~3 10^5
        # cells of a 0.25 mm raster), written into one N x 2 array: the same values as np.column_stack's.
        flat = np.flatnonzero(self.mask)
        rows = flat // self.mask.shape[1]
        cols = flat - rows * self.mask.shape[1]
        centres = np.empty((len(flat), 2))
        np.multiply(cols + 0.5, self.cell_mm, out=centres[:, 0])
        centres[:, 0] += self.origin[0]
        np.multiply(rows + 0.5, self.cell_mm, out=centres[:, 1])
        centres[:, 1] += self.origin[1]
        return centres

    def cells_beyond(self, point: np.ndarray, direction: np.ndarray, offset: float) -> tuple[int, int]:
        """(marked cells whose centres c lie beyond the line (c - point) . direction = offset, all marked cells).

        Per raster row the cells beyond are those past one column, counted from the mask's integral image: ~1 ms
        on a cycle's 0.25 mm raster, where projecting every marked cell's centre (`centres`) cost 10-15 ms of
        CPU (beside the glue line's rasters on the other thread: CPU saved, not cycle time). Cells within
        rounding of the line count either way, as in any evaluation of the projection."""
        height, width = self.mask.shape
        step = self.cell_mm * np.asarray(direction, np.float64)  # the projection's change per column and per row
        first = (np.asarray(self.origin) + 0.5 * self.cell_mm - np.asarray(point, np.float64)) @ direction
        sums = cv2.integral(self.mask)  # (height + 1) x (width + 1): marked cells above and left of each corner
        row_counts = sums[1:, width] - sums[:-1, width]
        rows = np.arange(height)
        threshold = offset - first - step[1] * rows  # row r needs step[0] * col > threshold[r]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if step[0] > 0:  # columns from floor(threshold / step) + 1 on
                start = np.clip(np.floor(threshold / step[0]) + 1, 0, width).astype(np.int64)
                beyond = row_counts - (sums[rows + 1, start] - sums[rows, start])
            elif step[0] < 0:  # columns before ceil(threshold / step)
                end = np.clip(np.ceil(threshold / step[0]), 0, width).astype(np.int64)
                beyond = sums[rows + 1, end] - sums[rows, end]
            else:
                beyond = np.where(threshold < 0, row_counts, 0)
        return int(beyond.sum()), int(row_counts.sum())

    @property
    def area_mm2(self) -> float:
        return float(np.count_nonzero(self.mask)) * self.cell_mm**2

    def to_table(self, pixel_xy: np.ndarray) -> np.ndarray:
        """Raster coordinates (col, row as OpenCV contour points, cell centres at integers) to table mm."""
        return np.asarray(pixel_xy, np.float64) * self.cell_mm + np.array(self.origin) + 0.5 * self.cell_mm

    def outline(self) -> np.ndarray:
        """Outer boundary of the largest region, table mm (N x 2), counter-clockwise seen from +z.

        The contour runs through the centres of the boundary cells, i.e. half a cell inside the region's
        edge; it is pushed out by half a cell along its normal so the outline lies on the edge itself.
        """
        contours, _ = cv2.findContours(self.mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        if not contours:
            return np.zeros((0, 2))
        contour = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float64)
        if _signed_area(contour) < 0:
            contour = contour[::-1]
        return self.to_table(_offset(contour, 0.5))

    def largest_region(self) -> Footprint:
        """Only the largest 8-connected region, with its holes filled."""
        labels, largest = largest_component(self.mask)
        mask = np.zeros_like(self.mask)
        if largest > 0:
            region = (labels == largest).astype(np.uint8)
            contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(mask, contours, -1, 1, thickness=cv2.FILLED)
        return Footprint(mask, self.origin, self.cell_mm)

    def without_specks(self, max_area_mm2: float, min_gap_mm: float) -> Footprint:
        """Without the specks: regions smaller than `max_area_mm2` that lie farther than `min_gap_mm` from the
        largest region (which is kept, holes and all, as is every region near it or larger)."""
        labels, largest = largest_component(self.mask)
        if largest == 0:
            return self
        areas = label_areas(labels, int(labels.max()) + 1).astype(np.float64) * self.cell_mm**2
        near = Footprint((labels == largest).astype(np.uint8), self.origin, self.cell_mm).dilated(min_gap_mm)
        keep = areas >= max_area_mm2
        keep[labels[near.mask > 0]] = True
        keep[0] = False
        return Footprint(keep[labels].astype(np.uint8), self.origin, self.cell_mm)

    def morphology(self, close_mm: float, open_mm: float) -> Footprint:
        """Close gaps between sampled cells, then open away specks thinner than `open_mm`."""
        mask = self.mask
        if close_mm > 0:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, _disc(close_mm / self.cell_mm))
        if open_mm > 0:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, _disc(open_mm / self.cell_mm))
        return Footprint(mask, self.origin, self.cell_mm)

    def filled(self, polygon: np.ndarray) -> Footprint:
        """A raster on this one's cells marking the cells whose centres lie inside `polygon` (N x 2, table mm)."""
        shift = 8  # sub-cell vertex positions: 1/256 of a cell
        cells = (np.asarray(polygon, np.float64) - np.array(self.origin)) / self.cell_mm - 0.5
        mask = np.zeros_like(self.mask)
        if len(cells) == 0:
            return Footprint(mask, self.origin, self.cell_mm)
        # Drawn in the polygon's box and 2 empty cells round it (the raster's cells beyond are never marked): the
        # same cells as on the whole raster at a fifth of a cycle's 0.25 mm raster (8 -> 2 ms).
        height, width = mask.shape
        low, high = np.floor(cells.min(axis=0)).astype(int) - 2, np.ceil(cells.max(axis=0)).astype(int) + 3
        x0, y0 = min(max(int(low[0]), 0), width), min(max(int(low[1]), 0), height)
        box = mask[y0 : min(max(int(high[1]), 0), height), x0 : min(max(int(high[0]), 0), width)]
        if box.size == 0:
            return Footprint(mask, self.origin, self.cell_mm)
        vertices = np.round(cells * (1 << shift)).astype(np.int32) - np.array([x0 << shift, y0 << shift], np.int32)
        cv2.fillPoly(box, [vertices], 1, cv2.LINE_8, shift)
        # fillPoly also marks cells the edge merely touches: test the centres of the boundary cells exactly.
        rows, cols = np.nonzero((box > 0) & (cv2.erode(box, np.ones((3, 3), np.uint8)) == 0))
        # cv2.pointPolygonTest's answer for all of them in one C call (np.nonzero gives them sorted by row).
        outside = points_in_polygon(cells, np.column_stack([cols + x0, rows + y0])) < 0
        box[rows[outside], cols[outside]] = 0
        return Footprint(mask, self.origin, self.cell_mm)

    def eroded(self, distance_mm: float) -> Footprint:
        """Cells at least `distance_mm` inside the region's edge."""
        # Only the region's bounding box and the ring of empty cells around it can hold a cell's nearest
        # empty cell (any farther one is farther than the ring's): the distances there are the whole
        # raster's, at a fraction of its cells.
        rows, cols = self._box(1)
        inside = cv2.distanceTransform(self.mask[rows, cols], cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * self.cell_mm
        mask = np.zeros_like(self.mask)
        mask[rows, cols] = inside >= distance_mm
        return Footprint(mask, self.origin, self.cell_mm)

    def dilated(self, distance_mm: float) -> Footprint:
        """Cells within `distance_mm` of the region."""
        reach = distance_mm / self.cell_mm
        mask = np.zeros_like(self.mask)
        if reach <= _SMALL_REACH_CELLS:
            # A short reach is a dilation by the disc of cell offsets whose distance, computed as the
            # distance transform computes it (float32), is within it: the same cells, without the transform.
            offset = np.arange(-int(reach), int(reach) + 1)
            squared = (offset[:, None] ** 2 + offset[None, :] ** 2).astype(np.float32)
            disc = (np.sqrt(squared) * np.float32(self.cell_mm) <= np.float32(distance_mm)).astype(np.uint8)
            return Footprint(cv2.dilate(self.mask, disc), self.origin, self.cell_mm)
        # Cells farther than the reach from the region's bounding box are farther from the region.
        rows, cols = self._box(int(np.ceil(reach)) + 1)
        outside = cv2.distanceTransform(1 - self.mask[rows, cols], cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * self.cell_mm
        mask[rows, cols] = outside <= distance_mm
        return Footprint(mask, self.origin, self.cell_mm)

    def closed(self, radius_mm: float) -> Footprint:
        """The region closed with a disc of `radius_mm`: notches and dents narrower than the disc filled, the
        rest of the edge unchanged (cells exactly as cv2's closing with that disc of cells marks them)."""
        # A closing never marks a cell beyond the region's bounding box (a disc touching that cell from outside
        # the box misses the region), so only the box is closed: a fifth of a cycle's 0.25 mm raster.
        rows, cols = self._box(0)
        # Padded so that the dilation is not cut (the erosion would keep what it cut).
        pad = int(np.ceil(radius_mm / self.cell_mm)) + 2
        padded = Footprint(
            cv2.copyMakeBorder(self.mask[rows, cols], pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=0),
            (self.origin[0] - pad * self.cell_mm, self.origin[1] - pad * self.cell_mm),
            self.cell_mm,
        )
        # Erosion keeps the cells whose disc lies inside: farther than the radius from any unmarked cell
        # (strictly; the distances are float32 square roots of whole cell counts).
        mask = np.zeros_like(self.mask)
        mask[rows, cols] = padded.dilated(radius_mm).eroded(radius_mm + _STRICT_MM).mask[pad:-pad, pad:-pad]
        return Footprint(mask, self.origin, self.cell_mm)

    def _box(self, margin: int) -> tuple[slice, slice]:
        """Rows and columns of the region's bounding box plus `margin` cells, within the raster."""
        x, y, width, height = cv2.boundingRect(self.mask)
        if width == 0:
            return slice(0, self.mask.shape[0]), slice(0, self.mask.shape[1])
        return slice(max(y - margin, 0), y + height + margin), slice(max(x - margin, 0), x + width + margin)


def largest_component(mask: np.ndarray) -> tuple[np.ndarray, int]:
    """The 8-connected components of a uint8 mask (labels, as cv2.connectedComponentsWithStats numbers them)
    and the label of the largest (the first of equal ones; 0: none). Areas by counting the labels: OpenCV's
    statistics cost ~4 x the labelling itself on the footprint's raster, and np.bincount ~2 x (it copies the
    labels to intp first): counted in C (cellctl.stereo.kernels.label_areas, the same counts)."""
    count, labels = cv2.connectedComponents(mask, connectivity=8)
    if count < 2:
        return labels, 0
    areas = label_areas(labels, count)
    return labels, 1 + int(np.argmax(areas[1:]))


_STRICT_MM = 1e-3  # far below a cell, far above float32 rounding of the distances
_SMALL_REACH_CELLS = 4  # up to a 9 x 9 disc a dilation is cheaper than the distance transform


def _disc(diameter_cells: float) -> np.ndarray:
    size = max(1, int(round(diameter_cells)))
    size += 1 - size % 2  # odd, so the element is centred
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _offset(contour: np.ndarray, distance: float) -> np.ndarray:
    """Move each vertex of a counter-clockwise polygon `distance` outward along its smoothed normal."""
    tangent = np.roll(contour, -2, axis=0) - np.roll(contour, 2, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    outward = np.column_stack([tangent[:, 1], -tangent[:, 0]])  # right of the direction of travel (CCW)
    return contour + distance * outward


def snap_to_inset(footprint: Footprint, xy: np.ndarray, inset_mm: float, iterations: int = 4) -> np.ndarray:
    """Points (N x 2, table mm) moved onto the line `inset_mm` inside the footprint's edge.

    A glue line taken from the raster and smoothed along its length drifts off its offset where the outline
    turns sharply (a Gaussian pulls a pointed toe's corner inwards by ~1 mm). Each point is moved along the
    gradient of the edge's distance field (bilinear on the cell centres) until it lies `inset_mm` inside:
    the offset then holds exactly, whatever the outline's shape. Points on the field's ridge (the medial
    axis of a wide part, where the gradient vanishes) are left where they are.
    """
    cell = footprint.cell_mm
    # The region's bounding box with a ring of empty cells: every cell's nearest other-kind cell lies in it
    # for the distances that matter here (within the box), at a fraction of the raster's cells.
    x, y, width, height = cv2.boundingRect(footprint.mask)
    margin = 2 + int(np.ceil(inset_mm / cell))
    top, left = max(y - margin, 0), max(x - margin, 0)
    mask = footprint.mask[top : y + height + margin, left : x + width + margin]
    inside = cv2.distanceTransform(mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform(1 - mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    # Cell centres lie half a cell from the edge between a marked and an unmarked cell.
    signed = np.where(mask > 0, inside - 0.5, 0.5 - outside).astype(np.float32) * cell
    grad_y, grad_x = (g.astype(np.float32) for g in np.gradient(signed, cell))
    points = np.asarray(xy, np.float64).copy()
    for _ in range(iterations):
        col = (points[:, 0] - footprint.origin[0]) / cell - 0.5 - left
        row = (points[:, 1] - footprint.origin[1]) / cell - 0.5 - top
        grid = np.float32(col).reshape(-1, 1), np.float32(row).reshape(-1, 1)
        value = cv2.remap(signed, *grid, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()
        gx = cv2.remap(grad_x, *grid, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()
        gy = cv2.remap(grad_y, *grid, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()
        norm2 = gx.astype(np.float64) ** 2 + gy.astype(np.float64) ** 2
        # Along a pointed end's bisector the field rises only as sin(half angle): still a usable slope.
        move = np.where(norm2 > 0.01, (inset_mm - value) / np.maximum(norm2, 1e-9), 0.0)
        step = move[:, None] * np.column_stack([gx, gy])
        length = np.linalg.norm(step, axis=1, keepdims=True)
        points += step * np.minimum(1.0, 4 * cell / np.maximum(length, 1e-12))  # the field is local: small steps
    return points
