"""Recipes: one TOML file per shoe model, selected by the PLC by number before it triggers (map v2).

    book = RecipeBook.load(Path("/etc/cellctl/recipes"))
    recipe = book.get(3)                       # None for an unknown number
    failed = recipe.inspect(measurement)       # FeatureBit: features outside their tolerance

A recipe sets what the measurement needs (glue path offset and spacing, depth range) and what the result is
checked against (nominal length, heel and toe height with tolerances). Recipe number 0 is not a file: it is
the cell's own [measure] settings with no tolerance check, which is what a version 1 PLC always gets. Every
file is checked when the service starts, with the same rules as the config (unknown keys, impossible
values, duplicate numbers are errors naming the file and key), so a bad recipe stops the service instead
of failing soles on the line. Format and examples: deploy/recipes/*.toml, docs/recipes.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from cellctl.service.config import ConfigError, MeasureConfig, read_sole_wall
from cellctl.service.config_table import Table, read_toml
from firmware_io.registers import FeatureBit

#: The recipe number meaning "the cell's [measure] settings, no tolerances".
DEFAULT_RECIPE = 0
MAX_RECIPE_NUMBER = 0xFFFF  # one uint16 register


@dataclass(frozen=True)
class Tolerance:
    """A nominal value and how far below and above it a good sole may be (mm)."""

    nominal: float
    minus: float
    plus: float

    def accepts(self, value: float | None) -> bool:
        return value is not None and math.isfinite(value) and -self.minus <= value - self.nominal <= self.plus


@dataclass(frozen=True)
class Recipe:
    """What one shoe model needs from the cell."""

    number: int
    name: str
    glue_offset_mm: float
    glue_spacing_mm: float
    depth_range_mm: tuple[float, float]
    length_mm: Tolerance | None = None
    heel_height_mm: Tolerance | None = None
    toe_height_mm: Tolerance | None = None
    source: Path | None = None
    # [sole] wall, draft_deg: what the line knows of the model's wall (measure_sole's wall_draft_deg: None unknown,
    # 0 vertical, else its draft)
    wall_draft_deg: float | None = None

    @property
    def checks_tolerances(self) -> bool:
        return any(t is not None for t in (self.length_mm, self.heel_height_mm, self.toe_height_mm))

    def inspect(self, length_mm: float | None, heel_height_mm: float | None, toe_height_mm: float | None) -> FeatureBit:
        """Features of a measured sole outside this recipe's tolerances (0: all in, or none checked)."""
        failed = FeatureBit(0)
        for bit, tolerance, value in (
            (FeatureBit.LENGTH, self.length_mm, length_mm),
            (FeatureBit.HEEL_HEIGHT, self.heel_height_mm, heel_height_mm),
            (FeatureBit.TOE_HEIGHT, self.toe_height_mm, toe_height_mm),
        ):
            if tolerance is not None and not tolerance.accepts(value):
                failed |= bit
        return failed

    @classmethod
    def default(cls, measure: MeasureConfig) -> Recipe:
        """Recipe 0: the cell's [measure] settings, nothing checked."""
        return cls(
            DEFAULT_RECIPE,
            "cell default",
            measure.glue_offset_mm,
            measure.glue_spacing_mm,
            measure.depth_range_mm,
            wall_draft_deg=measure.sole_wall_draft_deg,
        )


class RecipeBook:
    """The recipes of a cell by number; recipe 0 is always there (the cell's defaults)."""

    def __init__(self, default: Recipe, recipes: list[Recipe]) -> None:
        self._by_number: dict[int, Recipe] = {DEFAULT_RECIPE: default}
        for recipe in recipes:
            known = self._by_number.get(recipe.number)
            if known is not None:
                raise ConfigError(
                    f"{recipe.source}: recipe number {recipe.number} is already used by {known.source}: "
                    "give each recipe file its own number"
                )
            self._by_number[recipe.number] = recipe

    @classmethod
    def load(cls, directory: Path | None, measure: MeasureConfig) -> RecipeBook:
        """Every *.toml in `directory` (None: only recipe 0); ConfigError naming the file and key."""
        default = Recipe.default(measure)
        if directory is None:
            return cls(default, [])
        if not directory.is_dir():
            raise ConfigError(f"recipe directory {directory} does not exist (see deploy/recipes/ for examples)")
        return cls(default, [load_recipe(path, measure) for path in sorted(directory.glob("*.toml"))])

    def get(self, number: int) -> Recipe | None:
        return self._by_number.get(number)

    def wall_note(self) -> str | None:
        """A line for the log naming the recipes whose sole wall is unknown, and what that costs (docs/recipes.md);
        None where every recipe states it."""
        unknown = [str(r.number) for r in self if r.wall_draft_deg is None]
        if not unknown:
            return None
        return (
            f"sole wall unknown in recipe(s) {', '.join(unknown)}: flat soles are refused (wall_too_low) and a wall "
            "leaning out by a mould's draft the cameras cannot see (under ~4 degrees) is measured at its top edge, "
            'short by its run; state it per recipe ([sole] wall = "vertical" or "drafted" with draft_deg)'
        )

    def __iter__(self):  # noqa: ANN204 - Iterator[Recipe]
        return iter(sorted(self._by_number.values(), key=lambda r: r.number))

    def __len__(self) -> int:
        return len(self._by_number)


def load_recipe(path: Path, measure: MeasureConfig) -> Recipe:
    """One recipe file; keys it leaves out take the cell's [measure] values."""
    root = Table(read_toml(path), "recipe", path)
    number = int(root.number("number", low=1, high=MAX_RECIPE_NUMBER))
    if number != root.data["number"]:
        raise root.fail("number", f"{root.data['number']!r} is not a whole number")
    name = root.get("name", str)
    if not name.strip():
        raise root.fail("name", 'empty: name the shoe model, e.g. "Runner 42 left"')
    glue = root.table("glue")
    sole = root.table("sole")
    depth = root.get("depth_range_mm", list, list(measure.depth_range_mm))
    if len(depth) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in depth):
        raise root.fail("depth_range_mm", f"expected [near, far] in mm, got {depth!r}")
    if not 0 < depth[0] < depth[1]:
        raise root.fail("depth_range_mm", f"{depth!r} is impossible: need 0 < near < far")
    recipe = Recipe(
        number=number,
        name=name,
        glue_offset_mm=glue.number("offset_mm", measure.glue_offset_mm, low=0, high=50),
        glue_spacing_mm=glue.number("spacing_mm", measure.glue_spacing_mm, above=0, high=50),
        depth_range_mm=(float(depth[0]), float(depth[1])),
        length_mm=_tolerance(root, "length_mm"),
        heel_height_mm=_tolerance(root, "heel_height_mm"),
        toe_height_mm=_tolerance(root, "toe_height_mm"),
        source=path,
        wall_draft_deg=read_sole_wall(sole, "wall", "draft_deg", measure.sole_wall_draft_deg),
    )
    glue.finish()
    sole.finish()
    root.finish()
    return recipe


def _tolerance(root: Table, key: str) -> Tolerance | None:
    """[key] nominal = ..., tolerance = ± or minus/plus; absent: that feature is not checked."""
    if key not in root.data:
        root.get(key, dict, None)
        return None
    t = root.table(key)
    nominal = t.number("nominal", above=0)
    symmetric = t.optional_number("tolerance", above=0)
    minus = t.optional_number("minus", symmetric, above=0)
    plus = t.optional_number("plus", symmetric, above=0)
    t.finish()
    if minus is None or plus is None:
        raise t.fail("tolerance", "required: `tolerance = 1.0` (±) or both `minus` and `plus` (mm)")
    return Tolerance(nominal, minus, plus)
