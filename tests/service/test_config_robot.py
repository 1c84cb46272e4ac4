"""The config sections of issue 14: [plc] map_version, [recipes], [robot], [opcua]; defaults keep old cells as they were."""

from __future__ import annotations

from pathlib import Path

import pytest

from cellctl.service.config import CellConfig, ConfigError
from cellctl.service.glue_output import GlueOutput
from firmware_io.registers import GlueFrame
from tests.service.test_config import DEPLOY, MINIMAL, write


def test_an_old_config_gets_map_v1_no_recipes_table_frame_and_no_opcua(tmp_path: Path) -> None:
    config = CellConfig.load(write(tmp_path, MINIMAL))
    assert config.plc.map_version == 1 and config.recipes.directory is None
    assert config.robot.publish_frame == "table" and not config.opcua.enabled and not config.opcua.allow_anonymous
    assert config.robot_frame_path == DEPLOY / "robot-frame.json"  # beside the calibration
    assert GlueOutput.from_config(config).frame is GlueFrame.TABLE


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        ("[plc]\nmap_version = 3\n", "map_version: 3 is impossible"),
        ('[recipes]\ndir = "nowhere"\n', "recipe directory"),
        ('[robot]\npublish_frame = "camera"\n', "publish_frame: 'camera' is not one of"),
        ("[opcua]\nenabled = true\n", "needs username and password_file"),
        ('[opcua]\nendpoint = "http://x"\n', "not an opc.tcp:// URL"),
        ('[opcua]\nenabled = true\nusername = "mes"\npassword_file = "nope"\n', "password_file"),
        ("[opcua]\nport = 4840\n", "unknown key(s) port"),
    ],
)
def test_mistakes_are_refused_by_key(tmp_path: Path, extra: str, words: str) -> None:
    with pytest.raises(ConfigError) as caught:
        CellConfig.load(write(tmp_path, MINIMAL + extra))
    assert words in str(caught.value)


def test_robot_frame_asked_for_but_not_taught_says_what_to_run(tmp_path: Path) -> None:
    config = CellConfig.load(
        write(tmp_path, MINIMAL + f'[robot]\npublish_frame = "robot"\nframe_file = "{tmp_path / "f.json"}"\n')
    )
    with pytest.raises(ConfigError, match="cellctl teach-robot"):
        GlueOutput.from_config(config)


def test_the_shipped_configs_use_map_v2_and_the_recipe_examples() -> None:
    config = CellConfig.load(DEPLOY / "cell-sim.toml")
    assert config.plc.map_version == 2 and config.recipes.directory == DEPLOY / "recipes"
