"""Shapes of a sole's ends (round, pointed, square, cusped) and of its edge (side wall and top edge profile).

Ends: the half-width of the sole near a tip is the plain profile times a cap factor of t = distance from the
tip / cap length: an ellipse for a round end, a superellipse for a square one, the ellipse to the power 1.5
for a cusp (concave sides meeting in a point of zero radius). A pointed end is a wedge of a given full angle
whose apex is rounded with a given tip radius; behind the apex its sides curve out (an ogive, reaching
OGIVE_HALF_WIDTH_MM at `reach` from the tip, as a pointed shoe's forefoot does) and blend into the plain
profile with a smooth minimum.

Edge: the top surface near the outline, as a function of the exact distance `dist` from the outline
(inside), the local top height T and underside height U. A vertical wall rises from U; a sloped wall rises
from a vertical foot of `foot_mm` (FOOT_MM unless the look draws another: 0 is a wall leaning from the table
up) and leans out by `wall_slope_deg` towards the table; a rounded top edge is a circular fillet of
`top_radius` between the wall and the top. With the default foot every profile keeps the part of the sole
above MIN_HEIGHT_MM (docs/measurements.md, footprint) reaching out to the outline itself, so the footprint is
the outline: the foot and the fillet are limited to keep `foot_mm` of vertical wall. A cupsole's raised lip
lifts the top by `lip_mm` towards the outline over its last `lip_width_mm` (the footbed sunk inside its
sidewall), before the wall and fillet shape it. A lower foot is what
another simulator (or a real moulded sole) may well have: the outline is still the foot on the table.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIP_FADE_MM = 20.0  # a heel cup's lip fades out over this beyond its reach along the sole
FOOT_MM = 4.0  # vertical wall kept at the bottom of every edge profile: above the footprint's 3 mm threshold
SQUARE_POWER = (4.0, 6.0)  # superellipse exponents of a square end
POINTED_WEDGE_DEG = (35.0, 60.0)  # full angle of a pointed end
POINTED_TIP_RADIUS_MM = (1.0, 5.0)
POINTED_REACH_MM = (40.0, 65.0)  # distance from the tip where a pointed end's ogive is OGIVE_HALF_WIDTH_MM wide
OGIVE_HALF_WIDTH_MM = 45.0
BLEND_MM = 6.0  # smooth-minimum width where a wedge meets the plain profile


@dataclass(frozen=True)
class EndShape:
    """The shape of one end of the sole."""

    kind: str = "round"  # round | pointed | square | cusped
    power: float = 2.0  # square: superellipse exponent
    wedge_deg: float = 0.0  # pointed: full angle of the wedge
    tip_radius: float = 0.0  # pointed: radius of the rounded apex
    cap_scale: float = 1.0  # cap length relative to the plain shape's
    reach: float = 0.0  # pointed: distance from the tip where the ogive is OGIVE_HALF_WIDTH_MM wide

    @classmethod
    def draw(cls, kind: str, rng: np.random.Generator) -> EndShape:
        if kind == "pointed":
            return cls(
                kind,
                wedge_deg=float(rng.uniform(*POINTED_WEDGE_DEG)),
                tip_radius=float(rng.uniform(*POINTED_TIP_RADIUS_MM)),
                reach=float(rng.uniform(*POINTED_REACH_MM)),
            )
        if kind == "square":
            return cls(kind, power=float(rng.uniform(*SQUARE_POWER)), cap_scale=float(rng.uniform(0.35, 0.6)))
        if kind == "cusped":
            return cls(kind, cap_scale=float(rng.uniform(1.1, 1.4)))
        return cls()

    def cap(self, t: np.ndarray) -> np.ndarray:
        """Cap factor (0 at the tip, 1 from the end of the cap on) at t = distance from the tip / cap length."""
        t = np.clip(t, 0.0, 1.0)
        if self.kind == "pointed":
            return np.ones_like(t)
        if self.kind == "square":
            return (1.0 - (1.0 - t) ** self.power) ** (1.0 / self.power)
        ellipse = np.sqrt(np.clip(1.0 - (1.0 - t) ** 2, 0.0, 1.0))
        return ellipse**1.5 if self.kind == "cusped" else ellipse

    def limit(self, distance: np.ndarray, width: np.ndarray) -> np.ndarray:
        """The half-width `width` limited by a pointed end's rounded wedge at `distance` from the tip."""
        if self.kind != "pointed":
            return width
        half = np.radians(self.wedge_deg / 2.0)
        r = self.tip_radius
        d = np.clip(distance, 0.0, None)
        # Apex circle centred r behind the tip, tangent to the wedge's sides where d = r (1 - sin(half)).
        tangent = r * (1.0 - np.sin(half))
        circle = np.sqrt(np.clip(r * r - (r - np.minimum(d, tangent)) ** 2, 0.0, None))
        # Behind the apex: the wedge's line plus a quadratic that widens it to an ogive (same slope at the apex).
        run = self.reach - tangent
        bow = max(0.0, OGIVE_HALF_WIDTH_MM - r * np.cos(half) - run * np.tan(half)) / run**2
        behind = np.clip(d - tangent, 0.0, None)
        wedge = np.where(d <= tangent, circle, r * np.cos(half) + behind * np.tan(half) + bow * behind**2)
        return _smooth_min(width, wedge, BLEND_MM)


def _smooth_min(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """min(a, b) rounded over a width k where a and b are close (polynomial smooth minimum)."""
    h = np.clip(k - np.abs(a - b), 0.0, None) / k
    return np.minimum(a, b) - h * h * k / 4.0


@dataclass(frozen=True)
class EdgeProfile:
    """Side wall slope and top edge radius; `height` gives the top surface near the outline."""

    wall_slope_deg: float = 0.0
    top_radius: float = 0.0
    foot_mm: float = FOOT_MM  # vertical wall below the lean (and below the fillet)
    # A cupsole's raised lip: the top rises by lip_mm towards the outline over the last lip_width_mm (a smoothstep,
    # level at both ends), the footbed sunk below its sidewall. The fillet and the lean, if any, round the lip's top.
    lip_mm: float = 0.0
    lip_width_mm: float = 0.0
    # A heel cup: the lip only from the heel tip to lip_reach_mm along the sole, fading out over LIP_FADE_MM beyond.
    lip_reach_mm: float = float("inf")

    @property
    def plain(self) -> bool:
        return self.wall_slope_deg == 0.0 and self.top_radius == 0.0 and self.lip_mm == 0.0

    def band_mm(self, thickness: float) -> float:
        """How far in from the outline the profile can reach for a sole `thickness` thick."""
        lip = self.lip_width_mm if self.lip_mm else 0.0
        return max(thickness * np.tan(np.radians(self.wall_slope_deg)) + self.top_radius, lip) + 1e-3

    def lip(self, dist: np.ndarray, along: np.ndarray | float = 0.0) -> np.ndarray:
        """The lip's rise (mm) over the plain top at distance `dist` inside the outline, `along` mm from the heel
        tip."""
        if not self.lip_mm:
            return np.zeros_like(np.asarray(dist, np.float64))
        across = _smoothstep(1.0 - np.asarray(dist, np.float64) / self.lip_width_mm)
        return self.lip_mm * across * _smoothstep((self.lip_reach_mm + LIP_FADE_MM - np.asarray(along)) / LIP_FADE_MM)

    def height(
        self, dist: np.ndarray, top: np.ndarray, bottom: np.ndarray, along: np.ndarray | float = 0.0
    ) -> np.ndarray:
        """Top surface height at distance `dist` inside the outline, `along` mm from the heel tip, where the plain top
        is at `top`."""
        if self.plain:
            return np.asarray(top, np.float64)
        dist = np.clip(np.asarray(dist, np.float64), 0.0, None)
        top = np.asarray(top, np.float64) + self.lip(dist, along)
        alpha = np.radians(self.wall_slope_deg)
        foot = bottom + self.foot_mm
        r = np.clip(np.minimum(self.top_radius, top - foot), 0.0, None)
        corner = (top - foot) * np.tan(alpha)  # where the (unrounded) wall meets the top
        tangent = r / np.tan((np.pi / 2 + alpha) / 2)  # corner to the fillet's tangent points
        d_top, d_wall = corner + tangent, corner - tangent * np.sin(alpha)
        centre_z = top - r
        arc = centre_z + np.sqrt(np.clip(r * r - (dist - d_top) ** 2, 0.0, None))
        wall = foot + dist / np.tan(alpha) if alpha > 0 else np.full_like(dist, np.inf)
        return np.where(dist >= d_top, top, np.where(dist >= d_wall, arc, np.minimum(wall, top)))


def _smoothstep(t: np.ndarray) -> np.ndarray:
    """0 below 0, 1 above 1, 3 t^2 - 2 t^3 between: level at both ends."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
