from __future__ import annotations

from pathlib import Path

import pytest

from fleetslam.config import load_config
from fleetslam.errors import ConfigError
from fleetslam.robot.config import RobotConfig
from fleetslam.robot.teleop import JOY_PRESETS, load_joy_preset

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_robot_yaml_holds_the_defaults() -> None:
    assert load_config(RobotConfig, CONFIG / "robot.yaml") == RobotConfig()


@pytest.mark.parametrize("name", sorted(JOY_PRESETS))
def test_joy_presets_file_matches_the_built_in_presets(name: str) -> None:
    assert load_joy_preset(f"{CONFIG / 'joy_presets.yaml'}:{name}") == JOY_PRESETS[name]
    assert load_joy_preset(name) == JOY_PRESETS[name]


def test_joy_preset_from_a_single_preset_file_and_errors(tmp_path: Path) -> None:
    path = tmp_path / "pad.yaml"
    path.write_text("enable_button: 9\nenable_turbo_button: 10\n")
    preset = load_joy_preset(str(path))
    assert (preset.enable_button, preset.enable_turbo_button, preset.axis_linear) == (9, 10, 1)
    path.write_text("enable_buton: 9\n")
    with pytest.raises(ConfigError, match="enable_buton"):
        load_joy_preset(str(path))
    with pytest.raises(ConfigError, match="no preset named 'gamecube'"):
        load_joy_preset(f"{CONFIG / 'joy_presets.yaml'}:gamecube")
    with pytest.raises(ConfigError, match="built-in preset"):
        load_joy_preset("nintendo")


def test_robot_config_rejects_bad_values_naming_the_key() -> None:
    with pytest.raises(ConfigError, match="wheel_radius"):
        load_config(RobotConfig, overrides=["wheel_radius=-1"])
