from pathlib import Path

import pytest
import yaml

from fleetslam.config import ConfigModel, dump_config, load_config
from fleetslam.errors import ConfigError


class Inner(ConfigModel):
    gain: float = 1.5
    """Proportional gain."""


class Sample(ConfigModel):
    rate_hz: float = 10.0
    """How often to publish, in hertz."""
    name: str = "c3po"
    """Agent name."""
    inner: Inner = Inner()
    """Controller settings."""


def test_defaults_file_env_and_overrides(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("sample:\n  rate_hz: 20\n  inner:\n    gain: 2.0\n")
    cfg = load_config(
        Sample,
        path,
        section="sample",
        env_prefix="sample",
        environ={"FLEETSLAM_SAMPLE__NAME": "r2d2"},
        overrides=["inner.gain=3.5"],
    )
    assert cfg.rate_hz == 20.0
    assert cfg.name == "r2d2"
    assert cfg.inner.gain == 3.5


def test_errors_name_file_key_and_value(tmp_path: Path) -> None:
    path = tmp_path / "c.yaml"
    path.write_text("rate_hz: fast\n")
    with pytest.raises(ConfigError, match=r"c.yaml: key 'rate_hz' = 'fast'"):
        load_config(Sample, path)
    path.write_text("rate: 3\n")
    with pytest.raises(ConfigError, match=r"key 'rate' = 3: Extra inputs are not permitted"):
        load_config(Sample, path)
    path.write_text("rate_hz: [1\n")
    with pytest.raises(ConfigError, match=r"c.yaml:\d+:\d+: invalid YAML"):
        load_config(Sample, path)
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        load_config(Sample, overrides=["rate_hz"])


def test_dump_documents_every_field_and_loads_back() -> None:
    text = dump_config(Sample())
    assert "# How often to publish, in hertz." in text
    assert "# Proportional gain." in text
    assert yaml.safe_load(text) == Sample().model_dump()


def test_every_config_section_dumps_its_defaults_as_yaml_that_loads_back() -> None:
    """`fleetslam config dump`: each section under its name, and what it prints is the defaults, key for key."""
    from fleetslam.config import CONFIG_SECTIONS, dump_sections, section_model

    text = dump_sections()
    data = yaml.safe_load(text)
    assert list(data) == list(CONFIG_SECTIONS) == ["robot", "sim", "slam", "mapping"]
    for section in CONFIG_SECTIONS:
        model = section_model(section)
        assert model.model_validate(data[section]) == model(), section
    assert yaml.safe_load(dump_sections(["mapping"])) == {"mapping": data["mapping"]}


def test_config_dump_command_prints_the_sections(capsys: pytest.CaptureFixture[str]) -> None:
    from fleetslam.cli.main import main
    from fleetslam.config import dump_sections

    assert main(["config", "dump", "slam"]) == 0
    assert capsys.readouterr().out == dump_sections(["slam"])
