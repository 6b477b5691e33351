import subprocess
import sys

from fleetslam.cli.main import COMMANDS, main


def test_help_lists_installed_commands(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "usage: fleetslam" in out


def test_unknown_command_fails_with_usage(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["no-such-command"]) == 2
    assert "unknown command 'no-such-command'" in capsys.readouterr().err


def test_every_registered_module_configures_a_parser() -> None:
    import argparse
    import importlib
    import importlib.util

    for name, (module_name, _) in COMMANDS.items():
        if importlib.util.find_spec(module_name) is None:
            continue
        parser = argparse.ArgumentParser(prog=f"fleetslam {name}")
        importlib.import_module(module_name).configure(parser)
        assert parser.format_help()


def test_console_script_runs() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "fleetslam.cli.main", "--version"], capture_output=True, text=True, check=True
    )
    assert result.stdout.startswith("fleetslam ")
