"""A parametric shoe sole with known geometry, and its measurements computed from the model itself.

The sole is described in its own plane coordinates: u runs along the sole from the heel tip (u = 0) to the
toe tip (u = L), v across it. The outline is a medial and a lateral half-width profile around a slightly
bent centre line, with caps at both ends (elliptical unless a SceneLook asks for pointed, square or cusped
ones), so the forefoot is wider than the heel and the arch is cut in deeper on the medial side. The top
(gluing) surface is a height field over (u, v): heel thickness blending into forefoot thickness, toe spring
lifting the front of the sole, and a slight cross curvature; near the outline an optional edge profile
(sloped wall, rounded top edge) lowers it. Every wall is vertical for at least its bottom 4 mm, so the
footprint on the table is exactly the outline.

`SoleModel.truth()` computes length, heel height and toe height from this definition (polygon moments of
the densely sampled outline, exact height-field evaluation) following docs/measurements.md, without any of
the measuring code, so the simulator can judge the measurement.

The end shapes and the edge profile (sloped walls, rounded top edges) are in sole_profile.py, the mesh the
renderer casts rays at in sole_mesh.py, the polygon geometry of the truth in polygon.py.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from cellctl.sim.look import SceneLook
from cellctl.sim.polygon import clip_half_plane as _clip_half_plane
from cellctl.sim.polygon import polygon_area as _polygon_area
from cellctl.sim.polygon import polygon_moments as _polygon_moments
from cellctl.sim.sole_mesh import sole_mesh
from cellctl.sim.sole_profile import EdgeProfile, EndShape

# Parameter ranges of the generated soles (mm unless noted).
LENGTH_RANGE_MM = (240.0, 300.0)
# Per SceneLook.size: the sole's length range. "normal" is the matrix's (men's and most women's sizes); the others
# are what another cell feeds: children's and small women's soles, and the largest men's.
SIZE_LENGTH_RANGES_MM: dict[str, tuple[float, float]] = {
    "normal": LENGTH_RANGE_MM,
    "small": (170.0, 240.0),
    "large": (300.0, 340.0),
}
# Per SceneLook.width: the heel's and the ball's half-widths as fractions of the length. "normal" is the matrix's;
# a court shoe's or racing flat's sole is narrower, a boot's or a work shoe's wider.
WIDTH_FRACTIONS: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {
    "normal": ((0.115, 0.135), (0.170, 0.190)),
    "narrow": ((0.095, 0.110), (0.140, 0.160)),
    "wide": ((0.140, 0.160), (0.200, 0.230)),
}
# Per SceneLook.waist: the medial and lateral arch cuts as fractions of the ball's half-width, and the toe's shift
# to the medial side as a fraction of the length. "normal" is the matrix's; "deep" a waisted sole on a curved last.
WAIST_FRACTIONS: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "normal": ((0.20, 0.35), (0.04, 0.12), (0.0, 0.03)),
    "deep": ((0.38, 0.50), (0.10, 0.20), (0.03, 0.06)),
}
HEEL_HEIGHT_RANGE_MM = (20.0, 35.0)
TOE_HEIGHT_RANGE_MM = (8.0, 28.0)
# Per SceneLook.height: heel and toe height ranges and the cross curvature's bound.
HEIGHT_CLASS_RANGES_MM: dict[str, tuple[tuple[float, float], tuple[float, float], float]] = {
    "normal": (HEEL_HEIGHT_RANGE_MM, TOE_HEIGHT_RANGE_MM, 1.5),
    "flat": ((6.0, 7.5), (6.0, 7.5), 0.4),
    "tall": ((40.0, 50.0), (22.0, 45.0), 2.0),
}
EDGE_DISTANCE_SAMPLES = 1500  # outline samples (about twice as many points) for exact distances to it
MIN_EDGE_THICKNESS_MM = 5.0  # thinnest the top surface gets above the sole's underside at the edge
# Samples of the outline used for the truth; the rendered mesh uses fewer (cellctl.sim.sole_mesh).
TRUTH_OUTLINE_SAMPLES = 20000
EDGE_NORMAL_STEP_MM = 0.02  # central differences of the edge profile (distances are float32-exact to ~2e-5 mm)
HEIGHT_POINT_FRACTION = 0.10  # heights are taken 10 % of the length in from each end


def _smoothstep(x: np.ndarray | float) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class SoleShape:
    """Shape parameters of one sole, in mm in the sole's own (u, v) plane coordinates."""

    length: float
    heel_half_width: float
    ball_half_width: float
    medial_arch: float  # how far the arch cuts into the medial half-width
    lateral_arch: float
    heel_cap: float  # radius of the elliptical heel cap along u
    toe_cap: float  # length of the elliptical toe cap along u
    toe_shift: float  # medial shift of the centre line at the toe
    heel_thickness: float
    forefoot_thickness: float
    thickness_blend: tuple[float, float]  # fractions of the length where heel blends into forefoot
    toe_spring_start: float  # fraction of the length where the toe spring begins
    toe_spring: float  # lift of the underside at the toe tip
    cross_curvature: float  # dome (> 0) or cup (< 0) height across the sole
    heel_end: EndShape = EndShape()
    toe_end: EndShape = EndShape()
    edge: EdgeProfile = EdgeProfile()

    @classmethod
    def random(cls, rng: np.random.Generator, look: SceneLook | None = None) -> SoleShape:
        """A plausible sole with the parameter ranges of the simulator, and the ends and edge of `look`."""
        return draw_shape(rng, look or SceneLook())

    # ---- outline -------------------------------------------------------------------------------------

    def centre_line(self, u: np.ndarray) -> np.ndarray:
        """v of the centre line; bends to the medial side (+v) towards the toe."""
        return self.toe_shift * _smoothstep((u / self.length - 0.55) / 0.45)

    def half_width(self, u: np.ndarray, medial: bool) -> np.ndarray:
        """Distance from the centre line to the medial (+v) or lateral (-v) edge at u."""
        t = u / self.length
        arch = self.medial_arch if medial else self.lateral_arch
        profile = (
            self.heel_half_width
            + (self.ball_half_width - self.heel_half_width) * _smoothstep((t - 0.30) / 0.40)
            - arch * np.exp(-(((t - 0.45) / 0.12) ** 2))
        )
        # Caps: the width goes to zero at both tips (sole_profile.EndShape: round, square, cusped, pointed).
        heel = self.heel_end.cap(u / (self.heel_cap * self.heel_end.cap_scale))
        toe = self.toe_end.cap((self.length - u) / (self.toe_cap * self.toe_end.cap_scale))
        width = profile * heel * toe
        return self.toe_end.limit(self.length - u, self.heel_end.limit(u, width))

    def edge_distance_estimate(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """How far (u, v) lies inside the outline across the sole: cheap, for colour bands, not for truth."""
        offset = np.asarray(v) - self.centre_line(u)
        half = np.where(offset >= 0, self.half_width(u, True), self.half_width(u, False))
        return half - np.abs(offset)

    def u_samples(self, n: int) -> np.ndarray:
        """n values of u from heel tip to toe tip, dense near the tips where the outline turns fastest."""
        return self.length * 0.5 * (1.0 - np.cos(np.linspace(0.0, np.pi, n)))

    def outline(self, n: int = TRUTH_OUTLINE_SAMPLES) -> np.ndarray:
        """Closed outline (first point not repeated) in (u, v), counter-clockwise, about 2n points."""
        u = self.u_samples(n)
        centre = self.centre_line(u)
        medial = np.column_stack([u, centre + self.half_width(u, True)])
        lateral = np.column_stack([u, centre - self.half_width(u, False)])
        # Lateral side heel->toe (v < centre), then medial side toe->heel: counter-clockwise in (u, v).
        return np.vstack([lateral, medial[-2:0:-1]])

    # ---- top surface ---------------------------------------------------------------------------------

    def underside(self, u: np.ndarray) -> np.ndarray:
        """Height of the sole's underside above the table: zero except under the sprung toe."""
        t = u / self.length
        reach = np.clip((t - self.toe_spring_start) / (1.0 - self.toe_spring_start), 0.0, None)
        return self.toe_spring * reach**2

    def top_height(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Height of the top (gluing) surface above the table at sole coordinates (u, v)."""
        u = np.asarray(u, dtype=np.float64)
        v = np.asarray(v, dtype=np.float64)
        t = u / self.length
        lo, hi = self.thickness_blend
        thickness = self.heel_thickness + (self.forefoot_thickness - self.heel_thickness) * _smoothstep(
            (t - lo) / (hi - lo)
        )
        # A quadratic in the absolute lateral offset keeps the surface smooth at the narrow tips.
        across = (v - self.centre_line(u)) / (1.05 * self.ball_half_width)
        return self.underside(u) + thickness + self.cross_curvature * (1.0 - across**2)

    def top_normal(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit normals (N x 3, in u, v, z) of the top surface, by central differences of the height field."""
        h = 1e-3
        dzdu = (self.top_height(u + h, v) - self.top_height(u - h, v)) / (2 * h)
        dzdv = (self.top_height(u, v + h) - self.top_height(u, v - h)) / (2 * h)
        n = np.column_stack([-dzdu, -dzdv, np.ones_like(dzdu)])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    # ---- edge profile (sole_profile.EdgeProfile) -----------------------------------------------------

    @functools.cached_property
    def _outline_contour(self) -> np.ndarray:
        """The outline for cv2.pointPolygonTest, in (u - L/2, v): centred so float32 keeps ~1e-5 mm."""
        outline = self.outline(EDGE_DISTANCE_SAMPLES) - [self.length / 2.0, 0.0]
        return outline.astype(np.float32).reshape(-1, 1, 2)

    def edge_distance(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Exact distance of (u, v) inside the outline (negative outside)."""
        contour = self._outline_contour
        points = np.column_stack([np.asarray(u, np.float64) - self.length / 2.0, np.asarray(v, np.float64)])
        return np.array([cv2.pointPolygonTest(contour, (float(a), float(b)), True) for a, b in points])

    def surface_height(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Height of the top surface including the edge profile (top_height is the surface without it)."""
        top = self.top_height(u, v)
        if self.edge.plain:
            return top
        u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
        bottom = self.underside(u)
        # Exact distances only where the profile can reach: the lateral distance is at most 1 / cos(30 deg)
        # of the true one along the sides, and within the caps (plus the band) of the tips anything goes.
        band = self.edge.band_mm(float(np.max(top - bottom)))
        near_end = (u < self.heel_cap * self.heel_end.cap_scale + band) | (
            u > self.length - self.toe_cap * self.toe_end.cap_scale - band
        )
        near = near_end | (self.edge_distance_estimate(u, v) < 1.2 * band)
        height = top.copy()
        height[near] = self.edge.height(self.edge_distance(u[near], v[near]), top[near], bottom[near], u[near])
        return height

    def surface_normal(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit normals (N x 3, in u, v, z) of the top surface including the edge profile."""
        if self.edge.plain:
            return self.top_normal(u, v)
        h = EDGE_NORMAL_STEP_MM
        u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
        dzdu = (self.surface_height(u + h, v) - self.surface_height(u - h, v)) / (2 * h)
        dzdv = (self.surface_height(u, v + h) - self.surface_height(u, v - h)) / (2 * h)
        n = np.column_stack([-dzdu, -dzdv, np.ones_like(dzdu)])
        return n / np.linalg.norm(n, axis=1, keepdims=True)


def draw_shape(rng: np.random.Generator, look: SceneLook) -> SoleShape:
    """A plausible sole with the parameter ranges of the simulator, and the ends and edge of `look`."""
    heel_range, toe_range, cross_bound = HEIGHT_CLASS_RANGES_MM[look.height]
    length = rng.uniform(*SIZE_LENGTH_RANGES_MM[look.size])
    heel_fraction, ball_fraction = WIDTH_FRACTIONS[look.width]
    medial_fraction, lateral_fraction, shift_fraction = WAIST_FRACTIONS[look.waist]
    heel_half = length * rng.uniform(*heel_fraction)
    ball_half = length * rng.uniform(*ball_fraction)
    heel_height = rng.uniform(*heel_range)
    # A toe higher than the heel is not a shoe: draw the toe height up to the heel height.
    toe_height = rng.uniform(toe_range[0], min(toe_range[1], heel_height))
    cross = rng.uniform(-cross_bound, cross_bound)  # drawn even when the look sets it: the later draws stay put
    if look.cross_curvature_mm is not None:
        cross = look.cross_curvature_mm
    spring_start = rng.uniform(0.60, 0.70)
    # The toe spring may take at most what leaves the forefoot MIN_EDGE_THICKNESS_MM thick.
    lift_at_toe_point = rng.uniform(1.0, max(1.0, min(8.0, toe_height - cross - MIN_EDGE_THICKNESS_MM)))
    reach = ((1.0 - HEIGHT_POINT_FRACTION) - spring_start) / (1.0 - spring_start)
    forefoot = max(MIN_EDGE_THICKNESS_MM, toe_height - cross - lift_at_toe_point)
    if look.toe_spring_mm is not None:  # the drawn forefoot lifted further: the toe height grows with the lift
        lift_at_toe_point = look.toe_spring_mm
    toe_spring = lift_at_toe_point / reach**2
    return SoleShape(
        length=length,
        heel_half_width=heel_half,
        ball_half_width=ball_half,
        medial_arch=ball_half * rng.uniform(*medial_fraction),
        lateral_arch=ball_half * rng.uniform(*lateral_fraction),
        heel_cap=heel_half * rng.uniform(0.9, 1.2),
        toe_cap=length * rng.uniform(0.14, 0.20),
        toe_shift=length * rng.uniform(*shift_fraction),
        heel_thickness=heel_height - cross,
        forefoot_thickness=forefoot,
        thickness_blend=(rng.uniform(0.18, 0.25), rng.uniform(0.55, 0.65)),
        toe_spring_start=spring_start,
        toe_spring=toe_spring,
        cross_curvature=cross,
        # Drawn after the plain shape's numbers, so a plain look gives the plain simulator's soles.
        heel_end=EndShape.draw(look.heel, rng),
        toe_end=EndShape.draw(look.toe, rng),
        edge=EdgeProfile(
            look.wall_slope_deg,
            look.top_edge_radius_mm,
            look.wall_foot_mm,
            look.top_lip_mm,
            look.top_lip_width_mm,
            look.top_lip_heel_share * length if look.top_lip_heel_share < 1.0 else float("inf"),
        ),
    )


@dataclass(frozen=True)
class SolePose:
    """Where the sole lies on the table: mid-length point, heading of the heel->toe direction, and side."""

    x: float
    y: float
    yaw_deg: float
    mirrored: bool  # a left shoe: its medial side is at -v

    def to_table(self, uv: np.ndarray, length: float) -> np.ndarray:
        """Sole (u, v) coordinates (N x 2) to table (x, y)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        local = np.column_stack([uv[:, 0] - length / 2.0, -uv[:, 1] if self.mirrored else uv[:, 1]])
        return local @ self._rotation().T + np.array([self.x, self.y])

    def to_sole(self, xy: np.ndarray, length: float) -> np.ndarray:
        """Table (x, y) (N x 2) to sole (u, v) coordinates."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        local = (xy - np.array([self.x, self.y])) @ self._rotation()
        return np.column_stack([local[:, 0] + length / 2.0, -local[:, 1] if self.mirrored else local[:, 1]])

    def _rotation(self) -> np.ndarray:
        a = np.radians(self.yaw_deg)
        return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@dataclass(frozen=True)
class SoleTruth:
    """The three measurements of docs/measurements.md, computed from the model, in the table frame."""

    length_mm: float
    heel_height_mm: float
    toe_height_mm: float
    axis: tuple[float, float]  # unit heel->toe direction in the table plane
    heel_point: tuple[float, float, float]  # where heel_height_mm is taken (on the top surface)
    toe_point: tuple[float, float, float]
    half_area_difference: float  # (toe half - heel half) / footprint area

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass(frozen=True)
class SoleModel:
    """One sole (shape) lying on the table (pose)."""

    shape: SoleShape
    pose: SolePose

    def outline_table(self, n: int = TRUTH_OUTLINE_SAMPLES) -> np.ndarray:
        """The footprint outline in the table frame (N x 2), counter-clockwise seen from above."""
        xy = self.pose.to_table(self.shape.outline(n), self.shape.length)
        return xy[::-1] if self.pose.mirrored else xy  # mirroring flips the winding

    def footprint_table(self, n: int = TRUTH_OUTLINE_SAMPLES) -> np.ndarray:
        """The footprint as docs/measurements.md defines it (table frame, counter-clockwise): the outline."""
        return self.outline_table(n)

    def top_height_at(self, xy: np.ndarray) -> np.ndarray:
        """Top-surface height (edge profile included) at table points (N x 2); meaningful inside the footprint."""
        uv = self.pose.to_sole(xy, self.shape.length)
        return self.shape.surface_height(uv[:, 0], uv[:, 1])

    def top_normal_at(self, xy: np.ndarray) -> np.ndarray:
        """Unit normals (N x 3) of the top surface (edge profile included) at table points, in the table frame."""
        uv = self.pose.to_sole(xy, self.shape.length)
        return self._to_table_normals(self.shape.surface_normal(uv[:, 0], uv[:, 1]))

    def interior_normal_at(self, xy: np.ndarray) -> np.ndarray:
        """Normals of the top surface without the edge profile: cheap, for shading away from the edge."""
        uv = self.pose.to_sole(xy, self.shape.length)
        return self._to_table_normals(self.shape.top_normal(uv[:, 0], uv[:, 1]))

    def _to_table_normals(self, normals: np.ndarray) -> np.ndarray:
        along, across, up = normals.T
        if self.pose.mirrored:
            across = -across
        a = np.radians(self.pose.yaw_deg)
        return np.column_stack([np.cos(a) * along - np.sin(a) * across, np.sin(a) * along + np.cos(a) * across, up])

    def truth(self) -> SoleTruth:
        """Length, heel and toe height as docs/measurements.md defines them, from the model geometry."""
        outline = self.outline_table()
        area, centroid, cov = _polygon_moments(outline)
        eigvals, eigvecs = np.linalg.eigh(cov)
        axis = eigvecs[:, int(np.argmax(eigvals))]
        proj = (outline - centroid) @ axis
        lo, hi = float(proj.min()), float(proj.max())
        mid = 0.5 * (lo + hi)
        # Toe = end whose half of the footprint has the larger area (the definition, not the model's u axis).
        upper = _polygon_area(_clip_half_plane(outline, axis, float(centroid @ axis + mid)))
        difference = (upper - (area - upper)) / area
        if difference < 0:
            axis, lo, hi, difference = -axis, -hi, -lo, -difference
        length = hi - lo
        heel_xy = centroid + axis * (lo + HEIGHT_POINT_FRACTION * length)
        toe_xy = centroid + axis * (hi - HEIGHT_POINT_FRACTION * length)
        heel_z, toe_z = self.top_height_at(np.vstack([heel_xy, toe_xy]))
        return SoleTruth(
            length_mm=float(length),
            heel_height_mm=float(heel_z),
            toe_height_mm=float(toe_z),
            axis=(float(axis[0]), float(axis[1])),
            heel_point=(float(heel_xy[0]), float(heel_xy[1]), float(heel_z)),
            toe_point=(float(toe_xy[0]), float(toe_xy[1]), float(toe_z)),
            half_area_difference=float(difference),
        )

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closed triangle mesh in the table frame: vertices (V x 3), triangles (T x 3), part per triangle
        (cellctl.sim.sole_mesh)."""
        return sole_mesh(self)
