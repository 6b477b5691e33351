"""`fleetslam sim export-tum` through the launcher."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("mujoco")

from fleetslam.cli.main import main
from fleetslam.trajectory import read_tum


def test_export_tum_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "seq"
    code = main(["sim", "export-tum", str(out), "--frames", "4", "--resolution", "80x60", "--no-progress"])
    assert code == 0
    assert "4 frames" in capsys.readouterr().out
    assert len(read_tum(out / "groundtruth.txt")) == 4
    assert (out / "camera.txt").read_text().splitlines()[1].split()[4:6] == ["80", "60"]


def test_bad_resolution_is_a_clear_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["sim", "export-tum", str(tmp_path / "x"), "--resolution", "big"])
    assert code != 0
    assert "--resolution" in capsys.readouterr().err
