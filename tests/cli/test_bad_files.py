"""Issue 18, item 6: every bad file ends in one line naming the file and what is wrong, a non-zero exit, no
traceback (before: `map build` and `slam run` printed tracebacks on garbage or truncated MCAP and truncated .bz2,
`launch` and `slam run --config` on non-UTF-8 YAML, and an empty launch file ran a router on every interface)."""

from __future__ import annotations

import bz2
from pathlib import Path

import pytest

from fleetslam.cli.main import main

from ..datasets.test_mcap_source import _write


def _bad_files(tmp_path: Path) -> dict[str, Path]:
    rng_bytes = bytes((k * 97 + 13) % 256 for k in range(3000))
    files = {"garbage.mcap": rng_bytes, "bad.yaml": b"robots: \xff\xfe\n", "empty.yaml": b"",
             "points.xyz.bz2": bz2.compress(b"0 0 1\n1 1 1\n" * 100)[:40], "empty.xyz": b"# no points\n",
             "nan.xyz": b"nan nan nan\nnan 1 2\ninf 0 0\n",
             "endpoint.yaml": b"router: {endpoint: '???'}\nagents: [{name: c3po}]\n"}  # fmt: skip
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    _write(tmp_path / "whole.mcap", 4)
    whole = (tmp_path / "whole.mcap").read_bytes()
    (tmp_path / "truncated.mcap").write_bytes(whole[: len(whole) * 2 // 3])
    return {name: tmp_path / name for name in [*files, "truncated.mcap"]}


@pytest.mark.parametrize(
    ("command", "file", "says"),
    [
        (["map", "build", "{f}", "-o", "{out}/m.bt"], "garbage.mcap", "not a readable MCAP file"),
        (["map", "build", "{f}", "-o", "{out}/m.bt"], "truncated.mcap", "MCAP"),
        (["map", "build", "{f}", "-o", "{out}/m.bt"], "points.xyz.bz2", "corrupt or truncated .bz2 file"),
        (["slam", "run", "{f}", "--out", "{out}/s"], "garbage.mcap", "not a readable MCAP file"),
        (["slam", "run", "{f}", "--out", "{out}/s"], "truncated.mcap", "MCAP"),
        (["slam", "run", "{out}/garbage.mcap", "--out", "{out}/s", "--config", "{f}"], "bad.yaml", "not UTF-8 text"),
        (["map", "build", "{f}", "-o", "{out}/m.bt"], "empty.xyz", "no points"),
        (["map", "build", "{f}", "-o", "{out}/m.bt"], "nan.xyz", "all 3 points are NaN or infinite"),
        (["launch", "{f}"], "bad.yaml", "not UTF-8 text"),
        (["launch", "{f}", "--print-hosts"], "empty.yaml", "empty fleet file"),
        (["launch", "{f}", "--print-hosts"], "endpoint.yaml", "'???' is not a Zenoh endpoint"),
    ],
)
def test_bad_files_end_in_one_line_naming_the_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: list[str], file: str, says: str
) -> None:
    path = _bad_files(tmp_path)[file]
    code = main([part.format(f=path, out=tmp_path) for part in command])
    err = capsys.readouterr().err
    assert code != 0
    assert "Traceback" not in err and str(path) in err and says in err, err
    assert len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("command", [["router", "--listen", "???"], ["topic", "list"]])
def test_a_bad_endpoint_is_one_line_not_a_restart_loop(
    command: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("FLEETSLAM_ROUTER", "???")
    assert main(command) != 0
    err = capsys.readouterr().err
    assert "'???' is not a Zenoh endpoint" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
