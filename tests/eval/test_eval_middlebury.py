"""`cellctl eval middlebury`: report rows, pictures, progress bar and the command itself."""

from __future__ import annotations

import argparse
import csv
import io
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from cellctl.cli import eval as eval_command
from cellctl.cli.progress import ProgressBar
from cellctl.eval import middlebury, paper_table3
from cellctl.eval import pictures as middlebury_pictures
from cellctl.eval import report as middlebury_report
from cellctl.eval.middlebury import SCENES


def _result(method: str, scene: str, rates: tuple[float, float, float], seconds: float) -> middlebury.SceneResult:
    score = middlebury.Score(dict(zip(middlebury.REGIONS, rates)), invalid_percent=1.0)
    return middlebury.SceneResult(method, scene, np.zeros((1, 1), np.float32), score, seconds)


def test_rows_average_twelve_numbers_and_time_against_hh4() -> None:
    results = [
        _result(m, s, (i, i + 1.0, i + 2.0), t * (i + 1))
        for m, t in (("opencv-hh4", 0.1), ("sad-bm", 0.05))
        for i, s in enumerate(SCENES)
    ]
    rows = middlebury_report.build_rows(results)
    averages = {r.method: r for r in rows if r.scene == "average"}
    assert averages["sad-bm"].mean_percent == pytest.approx(np.mean([i + k for i in range(4) for k in range(3)]))
    assert averages["sad-bm"].bad_percent == pytest.approx({"nonocc": 1.5, "all": 2.5, "disc": 3.5})
    assert averages["sad-bm"].seconds == pytest.approx(0.05 * 2.5)
    assert averages["sad-bm"].time_vs_reference == pytest.approx(0.5)
    assert averages["Proposed"].source == "paper"
    assert (averages["Proposed"].mean_percent, averages["Proposed"].seconds) == (6.57, 5.68)  # as printed
    assert averages["Reference [18]"].mean_percent == pytest.approx(12.3875)  # not printed: mean of scenes
    # Per scene, the paper's four columns sit next to ours.
    tsukuba = [r for r in rows if r.scene == "tsukuba"]
    assert [r.method for r in tsukuba] == ["opencv-hh4", "sad-bm", *paper_table3.COLUMNS]
    assert tsukuba[-1].mean_percent == 5.94


def test_rows_of_a_partial_run_have_no_paper_average_and_no_ratio_without_hh4() -> None:
    rows = middlebury_report.build_rows([_result("sad-bm", "venus", (1.0, 2.0, 6.0), 0.2)])
    assert [(r.source, r.scene) for r in rows] == [("ours", "venus")] + [("paper", "venus")] * 4 + [("ours", "average")]
    assert rows[0].mean_percent == pytest.approx(3.0)
    assert rows[-1].time_vs_reference is None


def test_markdown_and_csv_carry_the_same_numbers() -> None:
    rows = middlebury_report.build_rows([_result("opencv-3way", "cones", (10.0, 20.0, 30.0), 0.25)])
    text = middlebury_report.markdown(rows)
    assert "| cones | opencv-3way | 10.00 | 20.00 | 30.00 | 20.00 | 1.00 | 0.250 |" in text
    assert "| cones | paper: Proposed | – | – | – | 6.88 | – | 6.600 |" in text
    records = list(csv.DictReader(io.StringIO(middlebury_report.csv_text(rows))))
    assert records[0]["method"] == "opencv-3way" and float(records[0]["disc_percent"]) == 30.0
    assert records[1]["source"] == "paper" and records[1]["nonocc_percent"] == ""


def test_error_map_colours_bad_invalid_and_unevaluated_pixels(tmp_path: Path) -> None:
    scene = middlebury.Scene(
        SCENES["tsukuba"],
        np.full((1, 4, 3), 200, np.uint8),
        np.full((1, 4, 3), 200, np.uint8),
        np.array([[5.0, 5.0, 5.0, 5.0]], np.float32),
        {r: np.array([[True, True, True, False]]) for r in middlebury.REGIONS},
    )
    picture = middlebury_pictures.error_colour(np.array([[6.0, 7.0, np.nan, 0.0]], np.float32), scene)
    assert picture[0].tolist() == [
        [100, 100, 100],
        list(middlebury_pictures.BAD_COLOUR),
        list(middlebury_pictures.INVALID_COLOUR),
        [0, 0, 0],
    ]
    colours = middlebury_pictures.disparity_colour(np.array([[0.0, 15.0, np.nan]], np.float32), 0, 16)
    assert colours[0, 2].tolist() == [0, 0, 0] and colours[0, 0].tolist() != colours[0, 1].tolist()


def test_progress_bar_writes_one_line_per_step_to_a_log() -> None:
    stream = io.StringIO()
    bar = ProgressBar(2, stream, width=4)
    bar.advance("a")
    bar.advance("b")
    bar.finish()
    lines = stream.getvalue().splitlines()
    assert lines[:2] == ["[....] 0/2 a", "[##..] 1/2 b"]
    assert lines[2].startswith("[####] 2/2 done in")


def _cellctl(argv: list[str]) -> int:
    """Run the command as `cellctl` would, with only this sub-command registered."""
    parser = argparse.ArgumentParser(prog="cellctl")
    eval_command.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


def test_command_writes_tables_json_and_pictures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status = _cellctl(
        [
            "eval",
            "middlebury",
            "--methods",
            "sad-bm",
            "opencv-3way",
            "--scenes",
            "tsukuba",
            "--repeat",
            "1",
            "--json",
            "--out",
            str(tmp_path),
        ]
    )
    assert status == 0
    captured = capsys.readouterr()
    document = json.loads(captured.out)
    ours = [row for row in document["rows"] if row["source"] == "ours"]
    assert [(r["method"], r["scene"]) for r in ours] == [
        ("sad-bm", "tsukuba"),
        ("opencv-3way", "tsukuba"),
        ("sad-bm", "average"),
        ("opencv-3way", "average"),
    ]
    assert 0.0 < ours[1]["nonocc_percent"] < 12.0
    assert "2/2 done" in captured.err
    assert json.loads((tmp_path / "middlebury.json").read_text()) == document
    assert (tmp_path / "middlebury.md").read_text().startswith("| scene | method |")
    assert len(list(csv.DictReader((tmp_path / "middlebury.csv").open()))) == len(document["rows"])
    grid = cv2.imread(str(tmp_path / "middlebury-tsukuba.png"))
    tile = middlebury_pictures.LABEL_HEIGHT + 288
    gap = middlebury_pictures.GAP
    assert grid.shape == (3 * tile + 2 * gap, 2 * 384 + gap, 3)  # image+gt row, then one row per method


def test_command_names_a_missing_data_folder(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not found"):
        _cellctl(["eval", "middlebury", "--data", str(tmp_path / "missing"), "--methods", "sad-bm"])


def test_command_rejects_an_unknown_method(capsys: pytest.CaptureFixture[str]) -> None:
    # Checked when the command runs (the method table loads the matcher, too slow for `cellctl --help`).
    with pytest.raises(ValueError, match="unknown method.*fast-sgm.*choose from"):
        _cellctl(["eval", "middlebury", "--methods", "fast-sgm"])
    with pytest.raises(ValueError, match="--repeat must be at least 1"):
        _cellctl(["eval", "middlebury", "--repeat", "0"])


def test_command_rejects_a_file_as_output_folder(tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("")
    with pytest.raises(ValueError, match="is a file"):
        _cellctl(["eval", "middlebury", "--methods", "sad-bm", "--out", str(tmp_path / "taken")])


def test_command_on_a_2014_folder_compares_with_hh4_fill_and_checks_radiometry(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.eval.test_layouts import _folder_2014

    _folder_2014(tmp_path / "data")
    status = _cellctl(
        ["eval", "middlebury", "--data", str(tmp_path / "data"), "--repeat", "1", "--radiometric", "--json"]
    )
    assert status == 0
    captured = capsys.readouterr()
    document = json.loads(captured.out)
    [scene] = document["comparison"]["scenes"]
    assert scene["scene"] == "Synth" and scene["set"] == "2014"
    [summary] = document["comparison"]["sets"]
    assert summary["scenes"] == 1 and summary["time_ratio"] > 0
    assert set(document["radiometric"]) == {"plain", "gain", "gamma", "offset", "all"}
    # 3 methods (ours, HH4 + fill, HH4) on one scene, plain and four variants
    assert "15/15 done" in captured.err
