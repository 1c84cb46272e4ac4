"""What the simulated surfaces look like: materials, textures, the sole's colour schemes, the table looks and
the lights, chosen by a scene's `SceneLook`.

Textures are relative brightness maps (mean about 1) over a surface's own coordinates: the table's (x, y),
the sole's (u, v). The sole's colour scheme is a BGR albedo per surface point: plain, a contrasting rim
(a band round the top edge and the whole wall), a logo, or multi-colour patches.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cellctl.sim.look import SceneLook
from cellctl.sim.sole import SoleShape

PIXEL_FOOTPRINT_SIGMA_MM = 0.2  # texture pre-filter: pixel box (0.39 mm at 550 mm) plus lens blur


@dataclass(frozen=True)
class Material:
    """Surface appearance: BGR albedo (0..1), texture octaves (wavelength mm, relative amplitude), gloss."""

    albedo_bgr: tuple[float, float, float]
    octaves: tuple[tuple[float, float], ...]
    specular: float
    shininess: float


_TABLE_OCTAVES = ((14.0, 0.07), (4.0, 0.06), (1.2, 0.06))
TABLES: dict[str, Material] = {
    "dark": Material((0.16, 0.15, 0.14), _TABLE_OCTAVES, 0.01, 8.0),
    "grey": Material((0.42, 0.42, 0.41), _TABLE_OCTAVES, 0.01, 8.0),
    "patterned": Material((0.40, 0.41, 0.40), _TABLE_OCTAVES, 0.01, 8.0),  # plus the cutting-mat pattern
    "light": Material((0.78, 0.79, 0.78), _TABLE_OCTAVES, 0.01, 8.0),  # a white fixture plate
}
TABLE = TABLES["dark"]
_SOLE_OCTAVES = ((8.0, 0.04), (2.5, 0.035), (0.9, 0.035))
SOLE_MATERIALS: dict[str, Material] = {
    # Roughened white rubber, black leather and mid-grey rubber: a few per cent of texture contrast, no more.
    "white": Material((0.70, 0.72, 0.73), _SOLE_OCTAVES, 0.02, 10.0),
    "black": Material((0.20, 0.19, 0.19), _SOLE_OCTAVES, 0.05, 20.0),
    "grey": Material((0.42, 0.43, 0.44), _SOLE_OCTAVES, 0.03, 12.0),
}
GLOSS = (0.8, 250.0)  # specular weight and Blinn-Phong exponent of a glossy sole: small, intense highlights
DARK_ACCENT = (0.05, 0.05, 0.06)  # rim / logo colour on a light sole
LIGHT_ACCENT = (0.62, 0.63, 0.62)  # ... on a black sole
PATCH_COLOURS = (
    (0.12, 0.18, 0.62),
    (0.58, 0.32, 0.12),
    (0.25, 0.55, 0.30),
    (0.08, 0.08, 0.09),
)  # red, blue, green, black

LIGHTS_MM = np.array([[-260.0, 0.0, 640.0], [260.0, 0.0, 640.0]])  # the cell's two LED bars
SIDE_LIGHT_MM = np.array([-520.0, 180.0, 260.0])  # the `shadows` look: a low lamp beside the cell


RING_LIGHT = (6, 90.0, 540.0)  # the `ring` lighting: lamps, radius (mm) round the rig's axis, height above the table
OVERHEAD_LIGHT = (150.0, 900.0)  # the `overhead` lamp: offset from the rig's axis and height (mm)
SIDE_BAR = (600.0, 420.0, 100.0)  # the `side` bar: distance out, height and the spacing of its two lamps (mm)


def lights(look: SceneLook) -> tuple[np.ndarray, np.ndarray]:
    """Light positions (N x 3, table frame) and relative intensities of a look (the same total, two, for each
    layout: the renderer normalises the diffuse light at the table's origin, not the highlights)."""
    positions, power = _layout(look)
    if look.shadows:
        return np.vstack([positions, SIDE_LIGHT_MM]), np.append(0.6 * power, 1.6)
    return positions, power


def _layout(look: SceneLook) -> tuple[np.ndarray, np.ndarray]:
    azimuth = np.radians(look.light_azimuth_deg)
    direction = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    if look.lighting == "ring":
        count, radius, height = RING_LIGHT
        angles = 2.0 * np.pi * np.arange(count) / count
        positions = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.full(count, height)])
        return positions, np.full(count, 2.0 / count)
    if look.lighting == "overhead":
        offset, height = OVERHEAD_LIGHT
        return (offset * direction + [0.0, 0.0, height])[None], np.array([2.0])
    if look.lighting == "side":
        distance, height, spacing = SIDE_BAR
        along = np.array([-direction[1], direction[0], 0.0])
        centre = distance * direction + [0.0, 0.0, height]
        return np.vstack([centre - 0.5 * spacing * along, centre + 0.5 * spacing * along]), np.ones(2)
    return LIGHTS_MM, np.ones(len(LIGHTS_MM))


def sole_material(color: str, look: SceneLook) -> Material:
    base = SOLE_MATERIALS[color]
    if look.texture_contrast != 1.0:  # a smoother moulding: the same pattern, fainter
        octaves = tuple((wavelength, amplitude * look.texture_contrast) for wavelength, amplitude in base.octaves)
        base = Material(base.albedo_bgr, octaves, base.specular, base.shininess)
    if look.gloss:
        return Material(base.albedo_bgr, base.octaves, *GLOSS)
    if look.sheen_weight > 0.0:
        return Material(base.albedo_bgr, base.octaves, look.sheen_weight, look.sheen_shininess)
    return base


@dataclass
class Texture:
    """A relative brightness map (mean 1) over a rectangle of a surface, sampled bilinearly."""

    image: np.ndarray  # float32
    origin: tuple[float, float]  # mm at texel (0, 0)
    texel_mm: float

    @classmethod
    def fractal(
        cls,
        rng: np.random.Generator,
        origin: tuple[float, float],
        size_mm: tuple[float, float],
        texel_mm: float,
        octaves: tuple[tuple[float, float], ...],
    ) -> Texture:
        """Sum of smooth noise octaves (band-limited noise upsampled with bicubic interpolation)."""
        width, height = int(size_mm[0] / texel_mm), int(size_mm[1] / texel_mm)
        image = np.ones((height, width), np.float32)
        for wavelength, amplitude in octaves:
            coarse = rng.standard_normal(
                (max(2, int(size_mm[1] / wavelength) + 1), max(2, int(size_mm[0] / wavelength) + 1))
            ).astype(np.float32)
            octave = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
            # A pixel integrates light over its footprint (~0.4 mm on the table) but a ray samples a point:
            # pre-filtering by the footprint stops the samples from aliasing. The amplitude is set after
            # the filter, so it is the contrast the camera actually records.
            octave = cv2.GaussianBlur(octave, (0, 0), PIXEL_FOOTPRINT_SIGMA_MM / texel_mm)
            image += amplitude * octave / max(float(octave.std()), 1e-6)
        return cls(image, origin, texel_mm)

    def with_cutting_mat(self, rng: np.random.Generator) -> Texture:
        """This texture times a cutting-mat pattern: grid lines every 10 mm (bold every 50 mm) and blotches."""
        height, width = self.image.shape
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float32) * np.float32(self.texel_mm)
        phase = rng.uniform(0.0, 10.0, 2)
        pattern = np.ones((height, width), np.float32)
        for step, line_mm, strength in ((10.0, 0.6, 0.45), (50.0, 1.4, 0.7)):
            # Distance from the cell centre in x or y, whichever is larger: step / 2 on a grid line.
            off = np.maximum(np.abs((xs + phase[0]) % step - step / 2), np.abs((ys + phase[1]) % step - step / 2))
            pattern += np.float32(strength) * (off > step / 2 - line_mm / 2)
        cells = rng.uniform(0.65, 1.35, (int(height * self.texel_mm / 30.0) + 2, int(width * self.texel_mm / 30.0) + 2))
        pattern *= cv2.resize(cells.astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST)
        blurred = cv2.GaussianBlur(pattern, (0, 0), PIXEL_FOOTPRINT_SIGMA_MM / self.texel_mm)
        return Texture(self.image * blurred / float(blurred.mean()), self.origin, self.texel_mm)

    def with_knurl(self, period_mm: float, angle_deg: float, contrast: float) -> Texture:
        """This texture times a grid of bumps: 1 + contrast * sin(2 pi a / period) * sin(2 pi b / period), with
        (a, b) the surface's axes turned by `angle_deg`, pre-filtered as the octaves are."""
        height, width = self.image.shape
        ys, xs = np.mgrid[0:height, 0:width].astype(np.float32) * np.float32(self.texel_mm)
        angle = np.radians(angle_deg)
        a = xs * np.float32(np.cos(angle)) + ys * np.float32(np.sin(angle))
        b = ys * np.float32(np.cos(angle)) - xs * np.float32(np.sin(angle))
        wave = np.float32(2.0 * np.pi / period_mm)
        pattern = 1.0 + np.float32(contrast) * np.sin(wave * a) * np.sin(wave * b)
        blurred = cv2.GaussianBlur(pattern, (0, 0), PIXEL_FOOTPRINT_SIGMA_MM / self.texel_mm)
        return Texture(self.image * blurred, self.origin, self.texel_mm)

    def sample(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        if len(x_mm) == 0:
            return np.zeros(0)
        # cv2.remap does the bilinear lookup; it wants 2-D maps, so fold the points into rows of 1024.
        n = len(x_mm)
        rows = -(-n // 1024)
        mx = np.zeros(rows * 1024, np.float32)
        my = np.zeros(rows * 1024, np.float32)
        mx[:n] = (np.asarray(x_mm) - self.origin[0]) / self.texel_mm
        my[:n] = (np.asarray(y_mm) - self.origin[1]) / self.texel_mm
        out = cv2.remap(
            self.image, mx.reshape(rows, 1024), my.reshape(rows, 1024), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT
        )
        return out.ravel()[:n]


def table_texture(rng: np.random.Generator, look: SceneLook) -> Texture:
    texture = Texture.fractal(rng, (-400.0, -350.0), (800.0, 700.0), 0.25, TABLES[look.table].octaves)
    return texture.with_cutting_mat(rng) if look.table == "patterned" else texture


@dataclass(frozen=True)
class ColourScheme:
    """Where a sole is not its base colour: a rim band, or ellipses (logo marks, patches) in (u, v)."""

    base: tuple[float, float, float]
    rim_mm: float  # width of the contrasting band round the top edge (0: none); the wall is rim too
    rim_bgr: tuple[float, float, float]
    spots: tuple[tuple[float, float, float, float, float, tuple[float, float, float]], ...]  # u, v, a, b, angle, bgr

    @classmethod
    def draw(cls, rng: np.random.Generator, color: str, look: SceneLook, shape: SoleShape) -> ColourScheme:
        base = TABLES[look.table].albedo_bgr if look.camouflage else SOLE_MATERIALS[color].albedo_bgr
        accent = LIGHT_ACCENT if color == "black" else DARK_ACCENT
        if look.colours == "rim":
            return cls(base, float(rng.uniform(4.0, 9.0)), accent, ())
        spots = []
        if look.colours == "logo":
            # A mark in the forefoot and a row of "letters" along the arch: small, well inside the outline.
            spots.append((0.72 * shape.length, 0.0, 14.0, 9.0, float(rng.uniform(0, 180)), accent))
            for k in range(5):
                spots.append((0.38 * shape.length + 7.0 * k, 0.0, 2.5, 5.0, 0.0, accent))
        elif look.colours == "patches":
            for _ in range(int(rng.integers(3, 6))):
                u = float(rng.uniform(0.2, 0.85)) * shape.length
                size = float(rng.uniform(8.0, 22.0))
                colour = PATCH_COLOURS[int(rng.integers(len(PATCH_COLOURS)))]
                v = float(rng.uniform(-0.4, 0.4)) * shape.ball_half_width
                spots.append((u, v, size, size * float(rng.uniform(0.4, 1.0)), float(rng.uniform(0, 180)), colour))
        return cls(base, 0.0, accent, tuple(spots))

    def albedo(self, shape: SoleShape, uv: np.ndarray, wall: np.ndarray) -> np.ndarray:
        """BGR albedo (N x 3) at sole points (u, v); `wall` marks points on the side wall."""
        albedo = np.tile(np.array(self.base, np.float32), (len(uv), 1))
        u, v = uv[:, 0], uv[:, 1]
        if self.rim_mm > 0:
            albedo[wall | (shape.edge_distance_estimate(u, v) < self.rim_mm)] = self.rim_bgr
        for cu, cv, a, b, angle, bgr in self.spots:
            c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
            du, dv = u - cu, v - cv
            inside = ((c * du + s * dv) / a) ** 2 + ((-s * du + c * dv) / b) ** 2 < 1.0
            albedo[inside & ~wall] = bgr
        return albedo
