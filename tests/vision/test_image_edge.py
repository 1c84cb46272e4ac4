"""The outline moved onto the edge both cameras' silhouettes show (cellctl.vision.image_edge)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from cellctl.vision.closed_path import closed_runs, run_lengths
from cellctl.vision.edge_checks import check_edge_offsets
from cellctl.vision.footprint import Footprint
from cellctl.vision.image_edge import (
    EDGE_HEIGHT_IN_MM,
    EDGE_MOVE_MAX_MM,
    EDGE_MOVE_MIN_MM,
    PlacedOutline,
    _paired,
    depth_silent,
    edge_heights,
    edge_shift,
    notch_fill,
    stereo_offsets,
)
from cellctl.vision.outline_checks import by_one_camera

RADIUS = 50.0
HEIGHT = 20.0
FOCAL = 1400.0
SIZE = 900


def camera_image(camera: np.ndarray, wall: bool = True) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """A cylinder's silhouette seen by a pinhole camera looking straight down from `camera` (without `wall`:
    only its top face changed, the wall lit like the table), and the camera's projection."""
    v, u = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    direction = np.column_stack([(u.ravel() - SIZE / 2) / FOCAL, (v.ravel() - SIZE / 2) / FOCAL])
    hit = np.zeros(u.size, bool)
    for z in np.linspace(0.0, HEIGHT, 81) if wall else [HEIGHT]:
        hit |= np.linalg.norm(camera[:2] + direction * (camera[2] - z), axis=1) <= RADIUS

    def project(points: np.ndarray) -> np.ndarray:
        rel = points - camera
        return np.column_stack([FOCAL * rel[:, 0] / -rel[:, 2], FOCAL * rel[:, 1] / -rel[:, 2]]) + SIZE / 2

    return hit.reshape(SIZE, SIZE), project


def one_camera(
    ring: np.ndarray,
    outward: np.ndarray,
    heights: np.ndarray,
    changed: np.ndarray,
    project: Callable[[np.ndarray], np.ndarray],
    camera: np.ndarray,
) -> np.ndarray:
    """One camera's innermost reading with no second camera to confirm: `stereo_offsets` given the same camera
    twice (where it sees the wall, so does the other, and the reading nearer the outline is taken)."""
    view = (changed, project, camera)
    (reading, _), _ = stereo_offsets(ring, outward, heights, (view, view))
    return reading


def circle(radius: float) -> tuple[np.ndarray, np.ndarray]:
    angle = np.linspace(0.0, 2 * np.pi, int(2 * np.pi * RADIUS), endpoint=False)
    outward = np.column_stack([np.cos(angle), np.sin(angle)])
    return radius * outward, outward


class _Top:
    """A top of height `height(x, y)` as SoleSurface.coarse_heights reads it (the disc's median is its centre's
    height on a top that is linear over the disc)."""

    def __init__(self, height: Callable[[np.ndarray], np.ndarray]) -> None:
        self.height = height

    def coarse_heights(self, xy: np.ndarray, radius_mm: float) -> np.ndarray:
        return self.height(np.asarray(xy))


def test_the_edge_height_is_carried_on_to_the_outline_where_the_top_rises_to_it() -> None:
    """Read 3 mm inside, a top rising 0.6 per mm towards the outline (a sprung toe's tip) stands 1.8 mm higher at
    the outline: carried on to it. A level top, one rising by less than the heights' noise and one falling to its
    edge (a rounded edge: its silhouette is not its top edge) keep the height read inside."""
    ring, outward = circle(RADIUS)

    def rising(slope: float) -> _Top:  # the top's slope outward (negative: falling to the edge)
        return _Top(lambda xy: HEIGHT + slope * (np.linalg.norm(xy, axis=1) - RADIUS))

    np.testing.assert_allclose(edge_heights(rising(0.6), ring, outward), HEIGHT, atol=1e-9)  # type: ignore[arg-type]
    read_inside = HEIGHT - 0.05 * EDGE_HEIGHT_IN_MM
    np.testing.assert_allclose(edge_heights(rising(0.05), ring, outward), read_inside)  # type: ignore[arg-type]
    np.testing.assert_allclose(edge_heights(rising(-0.6), ring, outward), HEIGHT + 1.8)  # type: ignore[arg-type]
    tip = rising(0.6)
    tip.height = lambda xy: np.where(xy[:, 0] > 40.0, HEIGHT + 0.6 * (np.linalg.norm(xy, axis=1) - RADIUS), HEIGHT)
    carried = edge_heights(tip, ring, outward)  # type: ignore[arg-type]
    assert np.all(np.abs(carried[np.abs(ring[:, 1]) > 40.0] - HEIGHT) < 1e-9)  # the level sides
    tip_end = (np.abs(ring[:, 1]) < 5.0) & (ring[:, 0] > 0)  # carried on
    assert np.all(np.abs(carried[tip_end] - HEIGHT) < 1e-9)


@pytest.mark.parametrize("wall", [True, False])
def test_each_camera_places_the_edge_at_the_height_of_its_silhouette(wall: bool) -> None:
    """A camera off to +x, an outline 1.5 mm inside the circle: the -x side's top edge (the wall faces away) is
    placed on the circle; the +x wall's foot too where the wall shows a change. Where it does not (lit like the
    table), the foot reading ends inside the sole and is the nearer one: never a claim beyond the edge."""
    camera = np.array([120.0, 0.0, 550.0])
    changed, project = camera_image(camera, wall)
    ring, outward = circle(RADIUS - 1.5)
    found = one_camera(ring, outward, np.full(len(ring), HEIGHT), changed, project, camera)
    away = np.sum(outward * (camera[:2] - ring), axis=1) <= 0  # the wall faces away from the camera
    assert np.mean(np.isfinite(found[away])) > 0.9
    assert np.nanmax(np.abs(found[away] - 1.5)) <= 0.5
    if wall:
        assert np.nanmax(np.abs(found[~away] - 1.5)) <= 0.5
    else:
        assert np.nanmax(found[~away]) <= 2.0 and np.nanmedian(found[~away]) < 1.0
    # The top edge taken at the table's height instead lies several mm beyond the edge.
    flat = one_camera(ring, outward, np.zeros(len(ring)), changed, project, camera)
    assert np.nanmax(flat - 1.5) > 2.0


def test_the_outline_moves_only_where_both_cameras_agree() -> None:
    n = 240
    left, right = np.zeros(n), np.zeros(n)
    left[20:40] = right[20:40] = 1.2  # both see the edge 1.2 mm beyond: a dent of the outline
    left[100:120] = 1.5  # one camera fooled (a shadow past the edge): no move
    right[150:170] = np.nan  # the other has no edge there: no move
    left[150:170] = 1.5
    left[60:80] = right[60:80] = 0.3  # within the edge's scatter: no move
    left[180:195] = right[180:195] = -1.2  # both masks end inside the outline: it lies beyond the edge, move in
    left[205:220] = -1.2  # only one camera says inside: no move
    shift = edge_shift(left, right)
    assert np.all(np.abs(shift[25:35] - 1.2) < 0.05)
    assert np.all(np.abs(shift[185:190] + 1.2) < 0.05)
    assert np.all(shift[100:120] == 0.0) and np.all(shift[150:170] == 0.0) and np.all(shift[60:80] == 0.0)
    assert np.all(shift[200:225] == 0.0)


def test_no_move_where_the_outermost_reading_contradicts_or_the_edge_is_too_far() -> None:
    """Inward only where the outermost readings also put the edge inside (no changed band beyond the outline
    that could be the sole's); outward by the outermost readings; nothing beyond EDGE_MOVE_MAX_MM (a cast
    shadow's edge 2-3 mm out): those points stay for the edge-offset check to refuse."""
    n = 200
    inner = np.zeros(n)
    inner[20:40] = -1.0
    inner[60:80] = 0.1  # innermost on the outline, outermost 1.0 beyond: the excused band is the sole's edge
    inner[100:120] = 2.5  # both cameras agree on an edge 2.5 mm out: too far for a depth error
    inner[140:160] = -(EDGE_MOVE_MAX_MM + 0.5)
    inner[170:190] = 1.8  # a dark top edge's last 1.8 mm without depth (fresh sole 39082): moved
    outer = inner.copy()
    outer[20:40] = 1.0  # the outermost reading finds a changed band beyond the outline: no move either way
    outer[60:80] = 1.0
    shift = edge_shift(inner, inner, outer=(outer, outer))
    assert np.all(shift[15:45] == 0.0)
    assert np.all(np.abs(shift[65:75] - 1.0) < 0.05)
    assert np.all(shift[100:120] == 0.0) and np.all(shift[140:160] == 0.0)
    assert np.all(np.abs(shift[175:185] - 1.8) < 0.05)
    moved = inner - shift
    failure = check_edge_offsets([moved, moved])  # the points left alone are still refused
    assert failure is not None


def test_inward_moves_take_a_narrow_blob_point_by_point_but_not_a_smeared_edge() -> None:
    """A blob of depth 3 mm wide beyond the edge (both cameras 1.1 mm inside the outline there): moved in per
    point, where a running median would keep most of it. A stretch of 30 mm beyond the edge is the disparity
    smeared along it (heights inside it smeared too): not moved, the edge-offset check refuses it. A blob with
    one point where the cameras disagree, or one camera alone seeing it at its end: none of it moves."""
    n = 300
    left, right = np.zeros(n), np.zeros(n)
    left[50:53] = right[50:53] = -1.1
    left[100:130] = right[100:130] = -1.0
    left[200:204] = right[200:204] = -1.1
    right[202] = -0.4  # the two cameras 0.7 mm apart at one point of the blob
    left[150], right[150] = -0.62, -0.62  # one point: the readings' scatter, no blob
    left[250:253] = right[250:253] = -1.1
    left[253], right[253] = 0.1, -0.9  # at its end one camera sees the blob, the other does not (3065)
    shift = edge_shift(left, right, longest_blob_mm=7.0)
    assert shift[51] < -0.8 and np.all(shift[50:53] < -0.6)
    assert np.all(shift[:49] == 0.0) and np.all(shift[54:200] == 0.0) and np.all(shift[200:] == 0.0)
    assert np.all(shift[245:260] == 0.0)
    assert check_edge_offsets([left - shift, right - shift]) is not None  # the blob left alone is refused
    rest = left - shift
    rest[195:210] = rest[245:260] = 0.0
    failure = check_edge_offsets([rest, rest])  # and so is the smeared stretch
    assert failure is not None and "1.0 mm inside the outline at outline point 1" in failure.reason
    # Without the bound the smeared stretch moves too (as the running-median rule moved it).
    assert np.all(edge_shift(left, right)[105:125] < -0.9)


def test_runs_and_their_lengths_go_around_the_closed_outline() -> None:
    flags = np.array([1, 1, 0, 1, 1, 1, 0, 0, 1], bool)
    # In order along the path: the run across the end starts at its last point (notch_fill's flanks read its ends).
    assert [run.tolist() for run in closed_runs(flags)] == [[3, 4, 5], [8, 0, 1]]
    assert run_lengths(flags).tolist() == [3, 3, 0, 3, 3, 3, 0, 0, 3]
    assert run_lengths(np.ones(4, bool)).tolist() == [4, 4, 4, 4]
    assert run_lengths(np.zeros(4, bool)).tolist() == [0, 0, 0, 0]


def test_where_both_cameras_see_the_wall_the_readings_that_agree_are_taken() -> None:
    """Both cameras see the wall: one camera's foot and the other's top, whichever pair agrees best (3065: the
    left top reading on the outline, +0.1, is a second step; its foot -1.4 agrees with the right's top -1.1).
    Nearer the outline among equally good pairs, or where no such pair has both readings."""
    foot_l, top_l = np.array([-1.38, -0.5, np.nan, -1.12]), np.array([0.12, 0.5, np.nan, 0.62])
    foot_r, top_r = np.array([-1.88, 0.5, -0.62, -1.38]), np.array([-1.12, -0.5, 0.12, np.nan])
    left, right = _paired(foot_l, top_l, foot_r, top_r)
    assert left.tolist()[:2] == [-1.38, -0.5] and right.tolist()[:2] == [-1.12, -0.5]
    assert np.isnan(left[2]) and right[2] == 0.12
    # Two foot readings agreeing is no evidence (2003: both 1.1-1.4 mm inside on a tall white wall, the outline
    # right): each camera's reading nearer the outline.
    assert left[3] == 0.62 and right[3] == -1.38


def test_a_camera_that_sees_the_wall_is_read_at_the_height_the_other_confirms() -> None:
    """An outline 1 mm beyond a dark cylinder's foot. The left camera, outside the +x wall, sees that wall: its
    mask ends at the foot, and the same ray meets the top's height ~1 mm further out, on the outline. Taking
    the reading nearer the outline (one camera alone) takes the top and clears the outline there; the right
    camera, on the far side, sees only the top edge and puts it 1 mm inside: its reading picks the foot."""
    left_camera, right_camera = np.array([80.0, 0.0, 550.0]), np.array([-80.0, 0.0, 550.0])
    (changed_l, project_l), (changed_r, project_r) = camera_image(left_camera), camera_image(right_camera)
    ring, outward = circle(RADIUS + 1.0)
    heights = np.full(len(ring), HEIGHT)
    (left, right), _ = stereo_offsets(
        ring, outward, heights, ((changed_l, project_l, left_camera), (changed_r, project_r, right_camera))
    )
    wall_side = (ring[:, 0] > RADIUS * np.cos(np.radians(20))) & (np.abs(ring[:, 1]) < 15.0)
    assert np.count_nonzero(wall_side) > 20
    assert np.nanmax(np.abs(left[wall_side] + 1.0)) <= 0.4
    assert np.nanmax(np.abs(right[wall_side] + 1.0)) <= 0.4
    alone = one_camera(ring, outward, heights, changed_l, project_l, left_camera)
    assert np.nanmedian(alone[wall_side]) > -0.5  # the bias the other camera removes


def table_depth(radius: float, shadow: tuple[float, float] | None = None) -> Footprint:
    """Raw cells (0.25 mm) where depth measured the table around a disc: beyond `radius` from the centre; with
    `shadow` (from, to in radians) the sole's edge there lies 1.2 mm inside RADIUS and a contact shadow covers
    the table from it to RADIUS: depth measures the (textured) table in the shadow from 0.3 mm past the edge."""
    cell = 0.25
    n = int(2 * (RADIUS + 10) / cell)
    y, x = (np.mgrid[0:n, 0:n] + 0.5) * cell - (RADIUS + 10)
    r, angle = np.hypot(x, y), np.mod(np.arctan2(y, x), 2 * np.pi)
    table = r > radius
    if shadow is not None:
        table |= (angle >= shadow[0]) & (angle < shadow[1]) & (r > RADIUS - 1.2 + 0.3)
    return Footprint(table.astype(np.uint8), (-(RADIUS + 10), -(RADIUS + 10)), cell)


def test_the_outline_moves_where_depth_is_silent_but_not_over_a_measured_shadow() -> None:
    """Both masks put the edge 1.2 mm beyond the outline all round. On one side that is a black top edge whose
    last mm has no depth (depth measures the table only from 0.6 mm past the edge): the outline moves there and
    the check passes. On the other side the outline is right and both masks end on a contact shadow on the
    table, which depth measures at table height: no move, and the edge-offset check still refuses it."""
    ring, outward = circle(RADIUS - 1.2)
    offsets = np.full(len(ring), 1.2)
    shadow = (np.pi, 2 * np.pi)  # the lower half: outline on the true edge, a 1.2 mm shadow beyond it
    silent = depth_silent(ring, outward, table_depth(RADIUS + 0.6, shadow))
    in_shadow = np.mod(np.arctan2(outward[:, 1], outward[:, 0]), 2 * np.pi) >= np.pi
    shift = edge_shift(offsets, offsets, silent)
    assert np.all(shift[in_shadow] == 0.0)  # not even the smoothing's tail reaches a guarded point
    assert np.all(np.abs(shift[~in_shadow][10:-10] - 1.2) < 0.05)
    moved = offsets - shift  # where the masks' edge lies from the moved outline
    failure = check_edge_offsets([moved, moved])
    assert failure is not None and "beyond" in failure.reason
    assert np.all(np.abs(moved[~in_shadow][10:-10]) < 0.05)
    # Unguarded, the same shadow would be moved onto and then pass the check: what the guard is for.
    unguarded = edge_shift(offsets, offsets)
    assert check_edge_offsets([offsets - unguarded, offsets - unguarded]) is None


def test_a_single_table_point_in_the_gap_stops_the_move() -> None:
    ring, outward = circle(RADIUS - 1.2)
    table = table_depth(RADIUS + 0.6)
    k = 40
    row, col, _ = table.cells((ring[k] + 0.5 * outward[k])[None])
    table.mask[row, col] = 1  # one measured table-level point 0.5 mm out from outline point k
    proposed = np.full(len(ring), 1.2)
    silent = depth_silent(ring, outward, table)(proposed)
    assert not silent[k] and silent[k + 3] and silent[k - 3]
    # A move that would end short of the measured table is allowed; none is proposed where there is no move.
    assert np.all(depth_silent(ring, outward, table_depth(RADIUS + 0.6))(proposed))
    assert not np.any(depth_silent(ring, outward, table_depth(RADIUS + 0.6))(np.zeros(len(ring))))


def disc_depth(radius: float) -> Footprint:
    """Raised cells (0.25 mm): the disc of `radius` round the centre, where depth measured the sole's height."""
    cell = 0.25
    n = int(2 * (RADIUS + 10) / cell)
    y, x = (np.mgrid[0:n, 0:n] + 0.5) * cell - (RADIUS + 10)
    return Footprint((np.hypot(x, y) <= radius).astype(np.uint8), (-(RADIUS + 10), -(RADIUS + 10)), cell)


def notched(depth: float, at: int = 100, half_width: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The circle's outline (1 mm apart) with a notch `depth` deep, 2 * half_width + 1 points wide, at point `at`
    (a cosine profile: one camera's mask missed the edge pixels there); its outward normals (the true circle's)
    and the notch's depth per point."""
    ring, outward = circle(RADIUS)
    k = np.arange(len(ring)) - at
    dent = np.where(np.abs(k) <= half_width, depth * 0.5 * (1 + np.cos(np.pi * k / (half_width + 1))), 0.0)
    return ring - dent[:, None] * outward, outward, dent


def always(proposed: np.ndarray) -> np.ndarray:
    return np.ones(len(proposed), bool)


def test_one_camera_fills_a_notch_the_other_cameras_mask_left() -> None:
    """A notch 1.5 mm deep over 5 mm: the right camera reads the edge where the circle is, the left one on the
    notch (its mask missed the same pixels the outline did). Depth is raised to the circle and silent: the notch
    is filled to the right camera's edge, nothing else moves. Where the left camera sees it too, the nearer
    reading is taken."""
    ring, outward, dent = notched(1.5)
    right, left = dent.copy(), np.zeros(len(ring))
    move, _ = notch_fill(ring, outward, (left, right), (left, right), always, disc_depth(RADIUS))
    inside = dent > EDGE_MOVE_MIN_MM
    assert np.allclose(move[inside], dent[inside]) and np.all(move[~inside] == 0.0)
    both, _ = notch_fill(ring, outward, (right - 0.2, right), (right - 0.2, right), always, disc_depth(RADIUS))
    assert np.allclose(both[inside], dent[inside] - 0.2)
    _, by = notch_fill(ring, outward, (left, right), (left, right), always, disc_depth(RADIUS))
    assert np.all(by[inside] == 1) and np.all(by[~inside] == -1)  # the right camera filled it
    _, by = notch_fill(ring, outward, (right - 0.2, right), (right - 0.2, right), always, disc_depth(RADIUS))
    assert np.all(by[inside] == 0)  # both could: the nearer edge, the left camera's


def test_a_filled_notch_is_judged_by_the_camera_that_filled_it() -> None:
    """A notch 2.5 mm deep filled from the right camera: the left camera's mask has the notch and reads the edge up
    to 2.5 mm inside the filled outline over 5 points; the mean of both (0.9 mm over the edge-offset check's window)
    would refuse an outline that lies on the edge. Read by the right camera alone there, it passes; a notch point
    mapped by position onto the check's own resampled ring."""
    ring, outward, dent = notched(2.5)
    placed = PlacedOutline(ring + dent[:, None] * outward, np.where(dent > EDGE_MOVE_MIN_MM, 1, -1))
    left, right = -dent, np.zeros(len(ring))
    assert check_edge_offsets([left, right]) is not None
    one_camera = placed.cameras_at(placed.outline + 0.1)
    assert np.array_equal(one_camera, placed.one_camera)
    assert check_edge_offsets(list(by_one_camera((left, right), one_camera))) is None
    assert np.all(PlacedOutline.unmoved(ring).cameras_at(ring) == -1)


def test_a_notch_shallower_than_the_edge_offset_limit_is_filled() -> None:
    """A dent 0.7 mm deep over 5 points passes the edge-offset check's 0.8 mm but not the notch check where it is
    sharp: the camera that shows the edge fills it as it fills a deeper one."""
    ring, outward, dent = notched(0.7)
    zero = np.zeros(len(ring))
    move, by = notch_fill(ring, outward, (zero, dent), (zero, dent), always, disc_depth(RADIUS))
    filled = dent > EDGE_MOVE_MIN_MM
    assert filled.any() and np.allclose(move[filled], dent[filled]) and np.all(by[filled] == 1)


@pytest.mark.parametrize("case", ["no notch", "shallow", "overshoot", "no depth", "table in the gap", "ambiguous"])
def test_no_fill_without_a_notch_depth_and_one_clear_edge(case: str) -> None:
    """The notch is filled only where the outline has one (deeper than the readings' scatter below its course
    either side), the camera's edge stays on that course (a bulge beyond it is a shadow or a reflection
    in one mask), depth measured the sole's height across the gap and no table point in it, and both of the
    camera's readings put the edge beyond."""
    depth = {"shallow": 0.45}.get(case, 1.5)
    ring, outward, dent = notched(depth)
    right = dent + (1.5 if case == "overshoot" else 0.0)
    if case == "no notch":
        ring, outward = circle(RADIUS)
    inner, outer = right.copy(), right.copy()
    if case == "ambiguous":
        inner[100] = 0.0  # the innermost of equally good steps on the outline
    raised = disc_depth(RADIUS - (depth if case == "no depth" else 0.0))
    silent = (lambda p: np.zeros(len(p), bool)) if case == "table in the gap" else always
    zero = np.zeros(len(ring))
    move, _ = notch_fill(ring, outward, (zero, inner), (zero, outer), silent, raised)
    assert np.all(move == 0.0)
