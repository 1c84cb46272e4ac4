"""Recipe files: the shipped examples load, tolerances decide the feature bits, bad files are refused by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.service.config import ConfigError, MeasureConfig
from cellctl.service.recipes import RecipeBook, Tolerance, load_recipe
from firmware_io.registers import FeatureBit

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
MEASURE = MeasureConfig(depth_range_mm=(450.0, 650.0), glue_offset_mm=2.0, glue_spacing_mm=2.0)


def test_the_shipped_examples_load_and_recipe_0_is_the_cell_default() -> None:
    book = RecipeBook.load(DEPLOY / "recipes", MEASURE)
    assert [r.number for r in book] == [0, 1, 2, 3]
    default, runner, trail, sandal = list(book)
    assert default.name == "cell default" and not default.checks_tolerances and default.glue_offset_mm == 2.0
    assert runner.toe_height_mm == Tolerance(8.0, 1.0, 2.0) and runner.glue_spacing_mm == 2.0
    assert trail.glue_offset_mm == 3.5 and trail.toe_height_mm is None and trail.depth_range_mm == (450.0, 650.0)
    assert sandal.wall_draft_deg == 0.0 and default.wall_draft_deg is runner.wall_draft_deg is trail.wall_draft_deg
    assert default.wall_draft_deg is None
    assert book.get(4) is None


def test_the_log_names_the_recipes_whose_wall_is_unknown() -> None:
    note = RecipeBook.load(DEPLOY / "recipes", MEASURE).wall_note()
    assert note is not None and note.startswith("sole wall unknown in recipe(s) 0, 1, 2:")  # 3 states it
    assert RecipeBook.load(None, MeasureConfig(sole_wall_draft_deg=2.0)).wall_note() is None


def test_the_sole_wall_is_unknown_unless_the_recipe_or_the_cell_states_it(tmp_path: Path) -> None:
    path = tmp_path / "flat.toml"
    path.write_text('number = 5\nname = "flat"\n')
    assert load_recipe(path, MEASURE).wall_draft_deg is None
    vertical_cell = MeasureConfig(sole_wall_draft_deg=0.0)
    default = RecipeBook.load(None, vertical_cell).get(0)
    assert load_recipe(path, vertical_cell).wall_draft_deg == 0.0 and default is not None
    assert default.wall_draft_deg == 0.0
    path.write_text('number = 5\nname = "flat"\n[sole]\nwall = "unknown"\n')
    assert load_recipe(path, vertical_cell).wall_draft_deg is None  # the recipe's word counts over the cell's
    path.write_text('number = 5\nname = "moulded"\n[sole]\nwall = "drafted"\ndraft_deg = 2.5\n')
    assert load_recipe(path, MEASURE).wall_draft_deg == 2.5
    path.write_text('number = 5\nname = "moulded"\n[sole]\nwall = "drafted"\n')
    assert load_recipe(path, MeasureConfig(sole_wall_draft_deg=3.0)).wall_draft_deg == 3.0  # the cell's draft


@pytest.mark.parametrize(
    ("sole", "problem"),
    [
        ('wall = "drafted"', "needs the mould's draft in degrees"),
        ('wall = "vertical"\ndraft_deg = 2', 'a draft goes with wall = "drafted"'),
        ("draft_deg = 2", 'a draft goes with wall = "drafted"'),
        ('wall = "drafted"\ndraft_deg = 0', "draft_deg"),
        ('wall = "drafted"\ndraft_deg = 12', "draft_deg"),
        ('wall = "leaning"', "is not one of"),
    ],
)
def test_a_wall_stated_wrongly_is_refused_by_name(tmp_path: Path, sole: str, problem: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(f'number = 5\nname = "moulded"\n[sole]\n{sole}\n')
    with pytest.raises(ConfigError, match=problem):
        load_recipe(path, MEASURE)


@pytest.mark.parametrize(
    ("length", "heel", "toe", "failed"),
    [
        (268.0, 18.0, 8.0, FeatureBit(0)),
        (270.0, 16.5, 10.0, FeatureBit(0)),  # every bound is inclusive
        (270.1, 18.0, 8.0, FeatureBit.LENGTH),
        (268.0, 19.6, 6.9, FeatureBit.HEEL_HEIGHT | FeatureBit.TOE_HEIGHT),
        (268.0, 18.0, float("nan"), FeatureBit.TOE_HEIGHT),  # no value is never in tolerance
    ],
)
def test_features_outside_their_tolerance_get_their_bit(
    length: float, heel: float, toe: float, failed: FeatureBit
) -> None:
    runner = load_recipe(DEPLOY / "recipes" / "runner-42.toml", MEASURE)
    assert runner.inspect(length, heel, toe) == failed


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ('name = "x"\n', "missing the required key 'number'"),
        ('number = 0\nname = "x"\n', "number: 0 is impossible"),
        ('number = 1.5\nname = "x"\n', "not a whole number"),
        ('number = 1\nname = "x"\ncolour = "red"\n', "unknown key(s) colour"),
        ('number = 1\nname = "x"\n[length_mm]\nnominal = 250\n', "tolerance"),
        ('number = 1\nname = "x"\n[glue]\noffset_mm = -1\n', "offset_mm: -1 is impossible"),
        ('number = 1\nname = "x"\n[length_mm]\nnominal = 250\ntolerence = 2\n', "unknown key(s) tolerence"),
        ('number = 1\nname = "x"\ndepth_range_mm = [600, 500]\n', "need 0 < near < far"),
        ('number = 1\nname = "x"\n[sole]\nwall = "slanted"\n', "wall: 'slanted' is not one of 'unknown', 'vertical'"),
        ('number = 1\nname = "x"\n[sole]\nheight = 6\n', "unknown key(s) height"),
        ("number = 1\nname = \n", "not valid TOML"),
    ],
)
def test_a_bad_recipe_file_is_refused_naming_file_and_key(tmp_path: Path, text: str, words: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="bad.toml") as caught:
        load_recipe(path, MEASURE)
    assert words in str(caught.value)


def test_two_files_with_one_number_are_refused(tmp_path: Path) -> None:
    (tmp_path / "a.toml").write_text('number = 4\nname = "a"\n')
    (tmp_path / "b.toml").write_text('number = 4\nname = "b"\n')
    with pytest.raises(ConfigError, match="recipe number 4 is already used"):
        RecipeBook.load(tmp_path, MEASURE)
