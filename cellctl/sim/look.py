"""The variation matrix of simulated sole scenes: named, switchable, combinable departures from the plain scene.

A `SceneLook` holds every switch of a scene beyond the sole's seed and colour: the shapes of the toe and
heel ends, the side wall and top edge profile, the sole's height class, its colour scheme, the table, the
light (cast shadows), the right camera's gain and gamma, gloss, sensor noise and the rig. The default
`SceneLook()` is the plain scene the simulator has always made (same draws, same pixels).

`VARIATIONS` names the entries of the matrix. Each one changes a few fields and draws its numbers (a gain
of 0.80-0.85, a tip radius, ...) from the scene's own seed, so a (seed, colour, variations) triple always
gives the same scene. Variations that touch different fields combine: `look_for(("pointed-toe",
"gain-low"), seed)`. Each variation also says which refusals (`FailureKind`) are a correct answer to it;
the matrix's entries are meant to be measurable, so most list none: a refusal of such a scene is a missed
measurement, and its reason is judged against the kinds listed. Entries outside the matrix (`in_matrix`
False) run only when named: "camouflage" is unmeasurable by design (only a refusal with its kind is right);
"off-image" (the sole runs off an image) is unmeasurable by design too; "faint-texture", "any-heading",
"light-table", "other-lights", "ambient-occlusion", "knurled-top", "wide-rig", "narrow-rig", "tilted-rig", "moderate-noise",
"soft-focus", "dim-exposure", "small-sole", "large-sole", "narrow-sole", "wide-sole", "waisted-sole",
"dished-top", "domed-top" and "sprung-toe" are kept out so that the matrix sets keep their soles, and are judged
like any entry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from cellctl.errors import FailureKind
from cellctl.sim.sole_profile import FOOT_MM

END_KINDS = ("round", "pointed", "square", "cusped")
HEIGHT_CLASSES = ("normal", "flat", "tall")
COLOUR_SCHEMES = ("plain", "rim", "logo", "patches")
TABLE_LOOKS = ("dark", "grey", "patterned", "light")
NOISE_LEVELS = ("normal", "heavy")
RIGS = ("default", "distorted", "wide", "narrow", "coarse", "fine", "near", "far")  # cellctl.sim.rig.rig_for
HEADINGS = ("along", "any")
PLACEMENTS = ("in-view", "off-image")
SIZES = ("normal", "small", "large")  # cellctl.sim.sole.SIZE_LENGTH_RANGES_MM
WIDTHS = ("normal", "narrow", "wide")  # cellctl.sim.sole.WIDTH_FRACTIONS
WAISTS = ("normal", "deep")  # cellctl.sim.sole.WAIST_FRACTIONS
LIGHTINGS = ("bars", "shadowed-bars", "ring", "overhead", "side")  # cellctl.sim.appearance.lights
DEFAULT_RIGHT_GAIN = 0.97  # the two cameras never expose identically


@dataclass(frozen=True)
class SceneLook:
    """Every switch of a simulated scene; the defaults are the plain scene."""

    toe: str = "round"  # END_KINDS
    heel: str = "round"
    wall_slope_deg: float = 0.0  # side wall leaning out towards the table (0: vertical)
    top_edge_radius_mm: float = 0.0  # rounded (bevelled) top edge (0: sharp)
    wall_foot_mm: float = FOOT_MM  # vertical wall below a sloped wall's lean (0: leaning from the table up)
    top_lip_mm: float = 0.0  # a cupsole's raised lip: the top rises this much towards the outline (0: none)
    top_lip_width_mm: float = 0.0  # over this far in from the outline
    top_lip_heel_share: float = 1.0  # the lip round the heel only, over this share of the length (1: all round)
    height: str = "normal"  # HEIGHT_CLASSES: flat ~6 mm, normal 8-35 mm, tall up to 50 mm
    colours: str = "plain"  # COLOUR_SCHEMES: rim = dark (or light) band round the edge and on the wall
    table: str = "dark"  # TABLE_LOOKS
    shadows: bool = False  # a low side light: the sole casts a long shadow onto the table
    # The cell's lights (LIGHTINGS): bars = the two LED bars beside the rig, their shadows not traced (the matrix's
    # light since the first render: the table beside each wall lit as if the sole were not there); shadowed-bars =
    # the same bars casting their shadows (each darkens the table beside the walls facing away from it); ring = a
    # ring light round the lenses; overhead = one lamp high above; side = one bar to one side. All but bars cast
    # their shadows.
    lighting: str = "bars"
    light_azimuth_deg: float = 0.0  # where the overhead lamp's offset or the side bar points, about the table's z
    ambient_scale: float = 1.0  # the room's diffuse light against the simulator's usual (render.AMBIENT)
    # The sole hides part of the room's diffuse light from the table at its foot (cellctl.sim.occlusion): the
    # strength of that darkening, a factor on the share of the sky the sole blocks (0: none, as every render before).
    ambient_occlusion: float = 0.0
    right_gain: float = DEFAULT_RIGHT_GAIN
    right_gamma: float = 1.0  # output = input ** gamma on the right camera only (1: linear)
    gloss: bool = False  # strong view-dependent highlights: they sit at different places in the two views
    # A satin finish: a broad, weak specular lobe in place of the material's own (Blinn-Phong weight and exponent;
    # weight 0: the material's). Where the lights' reflection falls differs between the views, as with gloss, but
    # as a smooth sheen over much of the top, not as small saturated highlights.
    sheen_weight: float = 0.0
    sheen_shininess: float = 0.0
    noise: str = "normal"  # NOISE_LEVELS
    noise_scale: float = 1.0  # the sensor's noise (read and shot) times this: a camera noisier than the level's
    # Defocus beyond the lens's usual blur (render.LENS_BLUR_PX), as a Gaussian sigma in pixels added in quadrature,
    # per camera: a lens focused off the table or a softer optic than the simulator's (0: in focus).
    left_defocus_px: float = 0.0
    right_defocus_px: float = 0.0
    exposure_scale: float = 1.0  # both cameras' exposure against the usual (render.EXPOSURE_DN): dim below 1
    rig: str = "default"  # RIGS: distorted = a wide-angle rig with strong distortion and misalignment
    camouflage: bool = False  # the sole has the table's colour and texture statistics: no colour edge at all
    texture_contrast: float = 1.0  # the sole's texture contrast relative to its material's (1: as SOLE_MATERIALS)
    # A regular pattern moulded into the top (a knurl: a grid of bumps), on top of the material's texture: its
    # period (0: none), its grid's angle to the sole's axis and its contrast (relative brightness amplitude).
    knurl_period_mm: float = 0.0
    knurl_angle_deg: float = 0.0
    knurl_contrast: float = 0.0
    rig_tilt_deg: float = 0.0  # the rig mounted this far off square to the table (0: the usual, render.RIG_TILT_DEG)
    heading: str = "along"  # HEADINGS: along = heel-toe axis within 35 degrees of the image rows, any = any heading
    placement: str = "in-view"  # PLACEMENTS: off-image = one end runs up to OFF_IMAGE_PX beyond an image's edge
    size: str = "normal"  # SIZES: the sole's length range (normal 240-300 mm, small 170-240, large 300-340)
    width: str = "normal"  # WIDTHS: the ball's half-width 17-19 % of the length (narrow 14-16 %, wide 20-23 %)
    # The top's cross curvature (sole.SoleShape.cross_curvature: a dome > 0, a dished footbed < 0); None: drawn
    # within the height class's bound as always.
    cross_curvature_mm: float | None = None
    # The underside's lift 10 % of the length in from the toe tip (sole.SoleShape.toe_spring); None: drawn within 1-8
    # mm as always (what the forefoot's thickness leaves).
    toe_spring_mm: float | None = None
    waist: str = "normal"  # WAISTS: how deep the arch cuts in and how far the last curves (deep: a waisted sole)

    def __post_init__(self) -> None:
        for name, allowed in (
            ("toe", END_KINDS),
            ("heel", END_KINDS),
            ("height", HEIGHT_CLASSES),
            ("colours", COLOUR_SCHEMES),
            ("table", TABLE_LOOKS),
            ("noise", NOISE_LEVELS),
            ("rig", RIGS),
            ("heading", HEADINGS),
            ("placement", PLACEMENTS),
            ("size", SIZES),
            ("width", WIDTHS),
            ("waist", WAISTS),
            ("lighting", LIGHTINGS),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(f"scene look {name} must be one of {', '.join(allowed)}, got {getattr(self, name)!r}")
        if not 0.0 <= self.wall_slope_deg < 45.0 or self.top_edge_radius_mm < 0.0 or self.wall_foot_mm < 0.0:
            raise ValueError("wall slope must be in [0, 45) degrees, the top edge radius and wall foot >= 0 mm")
        if not 0.0 < self.top_lip_heel_share <= 1.0:
            raise ValueError("a lip's share of the length must be in (0, 1]")
        if self.top_lip_mm < 0.0 or (self.top_lip_mm > 0.0 and self.top_lip_width_mm <= 0.0):
            raise ValueError("a lip must rise >= 0 mm, over a positive width")
        if self.right_gain <= 0.0 or self.right_gamma <= 0.0:
            raise ValueError("right camera gain and gamma must be positive")
        if self.knurl_period_mm < 0.0 or not 0.0 <= self.knurl_contrast < 1.0:
            raise ValueError("a knurl's period must be >= 0 mm and its contrast in [0, 1)")
        if not 0.0 <= self.sheen_weight < 1.0 or (self.sheen_weight > 0.0 and self.sheen_shininess <= 0.0):
            raise ValueError("a sheen's weight must be in [0, 1), its exponent positive")
        if not 0.0 <= self.ambient_occlusion <= 1.0:
            raise ValueError("the ambient occlusion's strength must be in [0, 1]")
        if self.texture_contrast <= 0.0:
            raise ValueError("the sole's texture contrast must be positive")
        if self.noise_scale <= 0.0:
            raise ValueError("the sensor's noise scale must be positive")
        if self.left_defocus_px < 0.0 or self.right_defocus_px < 0.0:
            raise ValueError("the cameras' defocus must be >= 0 px")
        if self.exposure_scale <= 0.0:
            raise ValueError("the cameras' exposure scale must be positive")
        if not 0.0 < self.ambient_scale < 1.0 / 0.35:
            raise ValueError("the ambient light's scale must be positive and leave the lights a share")
        if not 0.0 <= self.rig_tilt_deg < 30.0:
            raise ValueError("the rig's tilt must be in [0, 30) degrees")


@dataclass(frozen=True)
class Variation:
    """One named entry of the matrix: which fields it sets (values drawn from the seed) and fair refusals."""

    name: str
    description: str
    fields: tuple[str, ...]  # the SceneLook fields it sets: two variations setting one field do not combine
    apply: Callable[[SceneLook, np.random.Generator], SceneLook]
    refusals: frozenset[FailureKind] = field(default_factory=frozenset)
    in_matrix: bool = True  # False: only run when named (the module doc says which and why)


def _set(**values: object) -> Callable[[SceneLook, np.random.Generator], SceneLook]:
    return lambda look, rng: replace(look, **values)  # type: ignore[arg-type]


def _draw(**ranges: tuple[float, float]) -> Callable[[SceneLook, np.random.Generator], SceneLook]:
    """Each named field drawn uniformly from its (low, high), in the order given (the seed's draws follow it)."""
    return lambda look, rng: replace(
        look,
        **{name: float(rng.uniform(low, high)) for name, (low, high) in ranges.items()},  # type: ignore[arg-type]
    )


# Low-texture soles under heavy noise or with highlights that differ between the views can lose so much of
# the matched surface that a fair measurement refuses: those reasons are the right ones, "no sole" is not.
_SURFACE_LOST = frozenset({FailureKind.TOO_FEW_POINTS, FailureKind.SURFACE_NOT_MEASURED})

VARIATIONS: dict[str, Variation] = {
    v.name: v
    for v in (
        Variation("plain", "the plain scene", (), _set()),
        Variation("pointed-toe", "toe a 35-60 degree wedge with a 1-5 mm tip radius", ("toe",), _set(toe="pointed")),
        Variation(
            "pointed-heel", "heel a 35-60 degree wedge with a 1-5 mm tip radius", ("heel",), _set(heel="pointed")
        ),
        Variation("square-toe", "toe squared off (superelliptic cap)", ("toe",), _set(toe="square")),
        Variation("square-heel", "heel squared off (superelliptic cap)", ("heel",), _set(heel="square")),
        Variation("cusped-toe", "toe ending in a cusp (concave sides, zero tip radius)", ("toe",), _set(toe="cusped")),
        Variation("cusped-heel", "heel ending in a cusp", ("heel",), _set(heel="cusped")),
        # The lean starts 0-4 mm above the table: from the table itself, as a moulded sole's draft may, or above a
        # vertical foot (sole_profile.FOOT_MM, what every sloped wall had before).
        Variation(
            "sloped-wall",
            "side wall leaning out 8-20 degrees from 0-4 mm above the table",
            ("wall_slope_deg", "wall_foot_mm"),
            lambda look, rng: replace(
                look, wall_slope_deg=float(rng.uniform(8, 20)), wall_foot_mm=float(rng.uniform(0.0, FOOT_MM))
            ),
        ),
        # Outside the matrix so that its sets keep their soles. A mould's draft leans less than the cameras' view
        # of the sole's sides (3-6 degrees at the default rig): the wall hides behind the top edge from both, and
        # a result taken at the top edge is short by the wall's run (cellctl.vision.wall_draft). Measurable only
        # where the recipe states the draft (`cellctl bench-sole --declared-walls`).
        Variation(
            "draft",
            "side wall leaning out 1-6 degrees from the table (a mould's draft)",
            ("wall_slope_deg", "wall_foot_mm"),
            lambda look, rng: replace(look, wall_slope_deg=float(rng.uniform(1, 6)), wall_foot_mm=0.0),
            in_matrix=False,
        ),
        Variation(
            "rounded-edge",
            "top edge rounded, 3-5 mm radius",
            ("top_edge_radius_mm",),
            _draw(top_edge_radius_mm=(3, 5)),
        ),
        # Outside the matrix so that its sets keep their soles: a shape no set drew before session 36, a cupsole whose
        # footbed is sunk inside its sidewall. The top rises towards the outline, so the glue line 2 mm inside runs
        # on the lip's slope, curved across it.
        Variation(
            "lipped-edge",
            "a cupsole's raised lip: the top rises 1.5-4 mm over the last 5-12 mm before the outline",
            ("top_lip_mm", "top_lip_width_mm"),
            _draw(top_lip_mm=(1.5, 4.0), top_lip_width_mm=(5.0, 12.0)),
            in_matrix=False,
        ),
        # Outside the matrix: a lip round the heel only (a heel cup), which the glue normals' check reads over 80 mm
        # stretches rather than the whole path (cellctl.vision.checks.check_glue_tilt).
        Variation(
            "heel-cup",
            "a heel cup: the top rises 1.5-4 mm over its last 5-12 mm round the rear 25-35 % of the sole",
            ("top_lip_mm", "top_lip_width_mm", "top_lip_heel_share"),
            _draw(top_lip_mm=(1.5, 4.0), top_lip_width_mm=(5.0, 12.0), top_lip_heel_share=(0.25, 0.35)),
            in_matrix=False,
        ),
        Variation("flat", "flat sole, about 6 mm thick", ("height",), _set(height="flat")),
        Variation("tall", "tall sole, heel up to 50 mm", ("height",), _set(height="tall")),
        Variation("rim", "a contrasting band round the top edge and on the wall", ("colours",), _set(colours="rim")),
        Variation("logo", "a contrasting logo and lettering on the top surface", ("colours",), _set(colours="logo")),
        Variation(
            "patches", "multi-colour: patches of other colours on the top", ("colours",), _set(colours="patches")
        ),
        Variation("grey-table", "mid-grey table", ("table",), _set(table="grey")),
        Variation(
            "patterned-table",
            "grey table with a high-contrast cutting-mat pattern",
            ("table",),
            _set(table="patterned"),
        ),
        Variation("shadows", "low side light: long cast shadows", ("shadows",), _set(shadows=True)),
        # Outside the matrix so that its sets keep their soles: lights the simulated cell never had, as another cell
        # or simulator may (the bars' own shadows, which the matrix does not trace; a ring light round the lenses
        # leaves the walls dark and the top bright; one lamp or one bar to a side lights one side's walls and shades
        # the other's), each casting its shadows, and a room lighter or darker than the usual. Measurable like any
        # sole: a contact shadow beside the wall is what every physically lit scene has.
        Variation(
            "other-lights",
            "other lights: the bars' own shadows, a ring light, one overhead lamp or one side bar; 0.5-1.5 x ambient",
            ("lighting", "light_azimuth_deg", "ambient_scale"),
            lambda look, rng: replace(
                look,
                lighting=str(rng.choice(LIGHTINGS[1:])),
                light_azimuth_deg=float(rng.uniform(0.0, 360.0)),
                ambient_scale=float(rng.uniform(0.5, 1.5)),
            ),
            in_matrix=False,
        ),
        # Outside the matrix so that its sets keep their soles: the dark band a physically based renderer draws on
        # the table at the foot of the sole (the sole hides part of the room's light), which the simulator's uniform
        # ambient light never had. It lies on the table, in both views, in neither taught image; measurable.
        Variation(
            "ambient-occlusion",
            "the table darkened at the sole's foot where the sole hides the room's light (strength 0.6-1.0)",
            ("ambient_occlusion",),
            _draw(ambient_occlusion=(0.6, 1.0)),
            in_matrix=False,
        ),
        Variation("gain-low", "right camera 15-20 % darker", ("right_gain",), _draw(right_gain=(0.80, 0.85))),
        Variation("gain-high", "right camera 15-20 % brighter", ("right_gain",), _draw(right_gain=(1.15, 1.20))),
        Variation(
            "gamma",
            "right camera gamma 0.75-0.85 or 1.2-1.35",
            ("right_gamma",),
            lambda look, rng: replace(
                look, right_gamma=float(rng.choice([rng.uniform(0.75, 0.85), rng.uniform(1.2, 1.35)]))
            ),
        ),
        Variation(
            "gloss", "glossy sole: highlights differ between the views", ("gloss",), _set(gloss=True), _SURFACE_LOST
        ),
        Variation("heavy-noise", "heavy sensor noise", ("noise",), _set(noise="heavy"), _SURFACE_LOST),
        # Outside the matrix so that its sets keep their soles: between a clean camera and heavy noise, where the
        # cycle chooses between its last exposure and the mean of its exposures (cellctl.vision.image_noise).
        Variation(
            "moderate-noise",
            "a camera 1.5-3.5 times noisier than the normal sensor",
            ("noise", "noise_scale"),
            _draw(noise_scale=(1.5, 3.5)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix so that its sets keep their soles: optics and exposure the simulator's cameras never
        # had, as another simulator's or a real cell's may (judged like any entry: a softer image has less texture
        # for the matcher and the glue heights' fits, so too few points or an unmeasured surface are fair).
        Variation(
            "soft-focus",
            "each camera defocused by its own 0.3-1.2 px (Gaussian sigma beyond the usual blur)",
            ("left_defocus_px", "right_defocus_px"),
            _draw(left_defocus_px=(0.3, 1.2), right_defocus_px=(0.3, 1.2)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        Variation(
            "dim-exposure",
            "both cameras exposed at 0.4-0.8 of the usual level (darker images, coarser quantisation)",
            ("exposure_scale",),
            _draw(exposure_scale=(0.4, 0.8)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        Variation(
            "camouflage",
            "sole coloured like the grey table: unmeasurable by design",
            ("table", "colours", "camouflage"),
            _set(table="grey", camouflage=True),
            frozenset({FailureKind.COLOURS_TOO_SIMILAR}),
            in_matrix=False,
        ),
        Variation(
            "distorted-rig", "wide-angle rig: strong distortion, 2 degree misalignment", ("rig",), _set(rig="distorted")
        ),
        # Outside the matrix so that its sets keep their soles (a matrix sole's variations follow from its place in
        # MATRIX_ENTRIES), not because it is unmeasurable: a light sole stays measurable, a black one with half
        # the texture has too little of it for glue heights within 1 mm, and refusing it for that is right.
        Variation(
            "faint-texture",
            "sole texture contrast 50-65 % of its material's (a smoother moulding, finer grain)",
            ("texture_contrast",),
            _draw(texture_contrast=(0.50, 0.65)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix for the same reason: a satin finish, the reflection of the lights spread over the top
        # (rubber fresh from the mould, a sprayed or lacquered sole) rather than gloss's small saturated highlights.
        # Its brightness differs between the views by up to a third of a black sole's diffuse light, smoothly: the
        # census half of the cost is blind to it, the intensity half is not. Refusing the surface is fair.
        Variation(
            "satin",
            "a satin finish: a broad sheen (Blinn-Phong weight 0.12-0.3, exponent 12-50) that differs between the views",
            ("sheen_weight", "sheen_shininess"),
            _draw(sheen_weight=(0.12, 0.30), sheen_shininess=(12.0, 50.0)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix for the same reason: a regular pattern on the top, as a moulded or embossed sole may
        # have, where the matcher's cost repeats every period along the rows (a 1.5 mm period is 4 px, inside the
        # disparity range): a match a period off is a height 10-15 mm off. Refusing the surface is fair.
        Variation(
            "knurled-top",
            "a knurled top: a grid of bumps every 1.5-4 mm at any angle, 6-15 % brightness contrast",
            ("knurl_period_mm", "knurl_angle_deg", "knurl_contrast"),
            _draw(knurl_period_mm=(1.5, 4.0), knurl_angle_deg=(0.0, 90.0), knurl_contrast=(0.06, 0.15)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix for the same reason. The matrix's soles lie with their heel-toe axis along the image
        # rows (the epipolar lines: their long sides are the hardest edges for the matcher); another cell may feed
        # them across, and a judge may draw any heading.
        Variation(
            "any-heading",
            "the sole at any heading on the table, across the image rows too",
            ("heading",),
            _set(heading="any"),
            in_matrix=False,
        ),
        # Outside the matrix for the same reason: a white fixture plate. A black or grey sole stands out on it; a white
        # one is nearly its colour (0.70-0.73 against 0.78 albedo) and may be refused for that.
        Variation(
            "light-table",
            "a white fixture plate (albedo 0.78)",
            ("table",),
            _set(table="light"),
            frozenset({FailureKind.COLOURS_TOO_SIMILAR}),
            in_matrix=False,
        ),
        # Other rigs than the simulated one: a longer baseline (finer depth, larger occlusions at the walls) and a
        # shorter one (depth noise x1.5: glue heights may no longer hold 1 mm, and refusing for that is right).
        Variation(
            "wide-rig", "a rig with a 100 mm baseline (60 mm by default)", ("rig",), _set(rig="wide"), in_matrix=False
        ),
        Variation(
            "narrow-rig", "a rig with a 40 mm baseline", ("rig",), _set(rig="narrow"), _SURFACE_LOST, in_matrix=False
        ),
        # Other cameras than the simulated ones, at the same place and field of view: fewer pixels (depth 1.33 x
        # noisier, so refusing for the surface is right there) or more. Every size the measurement states in pixels
        # then stands for another size on the table.
        Variation(
            "coarse-rig",
            "cameras of 960 x 768 pixels (0.52 mm per pixel at the table; 1280 x 1024 by default)",
            ("rig",),
            _set(rig="coarse"),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        Variation(
            "fine-rig",
            "cameras of 1600 x 1280 pixels (0.31 mm per pixel at the table)",
            ("rig",),
            _set(rig="fine"),
            in_matrix=False,
        ),
        # Mounted lower with a wider lens, or higher with a longer one, seeing the same table through the same pixels:
        # the rays at the sole's edges lean further from the vertical (near) or less (far), and depth per disparity
        # pixel is finer or 1.36 x coarser (refusing the far rig's surface is right there). Its depth range is what a
        # line would configure (rig.depth_range_for).
        Variation(
            "near-rig",
            "the rig mounted 420 mm above the table with a wider lens (550 mm by default): more oblique views",
            ("rig",),
            _set(rig="near"),
            in_matrix=False,
        ),
        Variation(
            "far-rig",
            "the rig mounted 750 mm above the table with a longer lens: steeper views, coarser depth",
            ("rig",),
            _set(rig="far"),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix for the same reason: a rig mounted well off square to the table. The glue heights'
        # precision limit is calibrated up to 7 degrees and tighter beyond (checks.CALIBRATED_OBLIQUENESS_DEG), so
        # dark soles may be refused for the surface, and refusing them for that is right.
        Variation(
            "tilted-rig",
            "the rig mounted 8-12 degrees off square to the table",
            ("rig_tilt_deg",),
            _draw(rig_tilt_deg=(8.0, 12.0)),
            _SURFACE_LOST,
            in_matrix=False,
        ),
        # Outside the matrix for the same reason: the matrix's soles are 240-300 mm long; another cell feeds
        # children's and small women's soles, or the largest men's. Measurable like any sole.
        Variation("small-sole", "a short sole, 170-240 mm long", ("size",), _set(size="small"), in_matrix=False),
        Variation("large-sole", "a long sole, 300-340 mm long", ("size",), _set(size="large"), in_matrix=False),
        Variation(
            "narrow-sole",
            "a narrow sole (ball 28-32 % of the length)",
            ("width",),
            _set(width="narrow"),
            in_matrix=False,
        ),
        Variation(
            "wide-sole", "a wide sole (ball 40-46 % of the length)", ("width",), _set(width="wide"), in_matrix=False
        ),
        # Outside the matrix so that its sets keep their soles: a shape no set drew before session 37, a deeply
        # waisted sole on a strongly curved last (a court shoe's, a racing spike's): the medial arch cuts in 38-50 %
        # of the ball's half-width (20-35 % in the matrix), the lateral 10-20 % (4-12 %), the toe swings 3-6 % of
        # the length to the medial side (0-3 %). Measurable like any sole.
        Variation(
            "waisted-sole",
            "a deeply waisted sole on a curved last (medial arch 38-50 % of the ball's half-width, toe 3-6 % over)",
            ("waist",),
            _set(waist="deep"),
            in_matrix=False,
        ),
        # Outside the matrix so that its sets keep their soles: tops curved across far more than the matrix draws
        # (within 1.5 mm, 2 mm when tall), as a dished footbed or a domed midsole top is. The glue line runs where
        # the top slopes across it by up to ~12 degrees (dished: rising towards the outline, a broad lip; domed:
        # falling towards it, a broad rounded edge).
        Variation(
            "dished-top",
            "a dished footbed: the top's edge 3-6 mm above its middle across the sole",
            ("cross_curvature_mm",),
            lambda look, rng: replace(look, cross_curvature_mm=-float(rng.uniform(3.0, 6.0))),
            in_matrix=False,
        ),
        Variation(
            "domed-top",
            "a domed top: its middle 2-4 mm above its edge across the sole",
            ("cross_curvature_mm",),
            _draw(cross_curvature_mm=(2.0, 4.0)),
            in_matrix=False,
        ),
        # Outside the matrix so that its sets keep their soles: a running shoe's toe spring, the forefoot curving up
        # off the table by 10-16 mm at the toe's height point (20-35 mm at the tip), where the matrix lifts it by 1-8:
        # the toe's wall stands over a gap, the table under it in the sole's shadow and hidden from the cameras.
        Variation(
            "sprung-toe",
            "a running shoe's toe spring: the forefoot 10-16 mm off the table 10 % in from the toe tip",
            ("toe_spring_mm",),
            _draw(toe_spring_mm=(10.0, 16.0)),
            in_matrix=False,
        ),
        Variation(
            "off-image",
            "the sole runs off the image at one end: unmeasurable by design",
            ("placement",),
            _set(placement="off-image"),
            frozenset({FailureKind.SOLE_AT_BORDER}),
            in_matrix=False,
        ),
    )
}


def look_for(names: tuple[str, ...] | list[str], seed: int) -> SceneLook:
    """The scene look of a combination of variations; their numbers are drawn from `seed`."""
    rng = np.random.default_rng([seed, 23])
    look = SceneLook()
    taken: dict[str, str] = {}
    for name in names:
        if name not in VARIATIONS:
            raise ValueError(f"unknown variation {name!r}: choose from {', '.join(VARIATIONS)}")
        variation = VARIATIONS[name]
        for field_name in variation.fields:
            if field_name in taken:
                raise ValueError(f"variations {taken[field_name]!r} and {name!r} both set {field_name}: pick one")
            taken[field_name] = name
        look = variation.apply(look, rng)
    return look


def rig_refusals(rig: str) -> frozenset[FailureKind]:
    """The refusal kinds that are a correct answer to a scene shot through `rig` (a RIGS name): those of the
    variation that sets it (none for the default rig)."""
    if rig not in RIGS:
        raise ValueError(f"rig must be one of {', '.join(RIGS)}, got {rig!r}")
    rng = np.random.default_rng(0)
    setting = [v for v in VARIATIONS.values() if v.fields == ("rig",) and v.apply(SceneLook(), rng).rig == rig]
    return setting[0].refusals if setting else frozenset()


def fair_refusals(names: tuple[str, ...] | list[str]) -> frozenset[FailureKind]:
    """The refusal kinds that are a correct answer to a scene with these variations."""
    kinds: frozenset[FailureKind] = frozenset()
    for name in names:
        kinds |= VARIATIONS[name].refusals
    return kinds
