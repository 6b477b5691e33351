"""The ``fleetslam`` launcher: a registry of subcommand groups, each in its own module, imported lazily.

Each module named in :data:`COMMANDS` exposes ``configure(parser: argparse.ArgumentParser) -> None``, which
adds its arguments (and sub-subcommands) and sets ``func`` via ``parser.set_defaults(func=...)``; ``func``
takes the parsed namespace and returns an exit code (int) or None. Importing lazily keeps ``fleetslam topic
list`` from loading MuJoCo or GTSAM. Known errors become one clear line on stderr and an exit code.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import logging
import os
import sys
from collections.abc import Sequence

from fleetslam import __version__
from fleetslam.allocator import keep_freed_memory
from fleetslam.errors import FleetslamError

#: command name -> (module, one-line help). Order is the order shown by ``fleetslam --help``.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("fleetslam.cli.demo", "run the whole fleet on this machine: sim, SLAM, maps, console"),
    "router": ("fleetslam.cli.router", "run a Zenoh router, the fleet's discovery service"),
    "node": ("fleetslam.cli.graph", "list nodes of the running system"),
    "topic": ("fleetslam.cli.topic", "list, inspect, echo, publish and measure topics"),
    "service": ("fleetslam.cli.service", "list and call services"),
    "stats": ("fleetslam.cli.stats", "live network statistics per agent and topic"),
    "record": ("fleetslam.cli.record", "record topics to a rosbag2 folder with MCAP storage"),
    "play": ("fleetslam.cli.play", "replay a recording with its original timing"),
    "convert": ("fleetslam.cli.convert", "convert a recording to a ROS 1 bag"),
    "bridge": ("fleetslam.cli.bridge", "bridge the fleet to other middleware (ROS 1)"),
    "sim": ("fleetslam.cli.sim", "run the simulated plant, export datasets"),
    "robot": ("fleetslam.cli.robot", "run a robot's base controller"),
    "teleop": ("fleetslam.cli.teleop", "drive a robot with the keyboard or a joystick"),
    "slam": ("fleetslam.cli.slam", "run the RGB-D graph SLAM offline or as a node"),
    "map": ("fleetslam.cli.map", "build, inspect and convert occupancy octree maps"),
    "eval": ("fleetslam.cli.eval", "evaluate trajectories (APE/RPE, TUM conventions)"),
    "report": ("fleetslam.cli.report", "write a run's inspection report (HTML and PDF)"),
    "fleet": ("fleetslam.cli.fleet", "fuse the agents' maps into the fleet map"),
    "launch": ("fleetslam.cli.launch", "launch and supervise a fleet from a YAML description"),
    "station": ("fleetslam.cli.station", "run the operator web console"),
    "config": ("fleetslam.cli.config", "print the default configuration with documentation"),
    "security": ("fleetslam.cli.security", "make a fleet's certificates and secured Zenoh configs"),
}


def _available_commands() -> dict[str, tuple[str, str]]:
    """Commands whose module is part of this installation."""
    found = {}
    for name, (module, help_text) in COMMANDS.items():
        if importlib.util.find_spec(module) is not None:
            found[name] = (module, help_text)
    return found


def _usage(commands: dict[str, tuple[str, str]]) -> str:
    width = max((len(n) for n in commands), default=0)
    lines = [
        f"usage: fleetslam [--version] [-v|-q] <command> [args...]   (fleetslam {__version__})",
        "",
        "commands:",
    ]
    lines += [f"  {name.ljust(width)}  {help_text}" for name, (_, help_text) in commands.items()]
    lines += ["", "Run 'fleetslam <command> --help' for a command's options."]
    return "\n".join(lines)


def _configure_logging(verbosity: int) -> None:
    levels = {-1: logging.WARNING, 0: logging.INFO, 1: logging.DEBUG}
    level = levels[max(-1, min(1, verbosity))]
    named = logging.getLevelName(os.environ.get("FLEETSLAM_LOG_LEVEL", "").upper())
    if isinstance(named, int):
        level = named
    logging.basicConfig(level=level, format="%(asctime)s %(levelname).1s %(name)s: %(message)s", datefmt="%H:%M:%S")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``fleetslam`` console script; returns the process exit code."""
    args = list(sys.argv[1:] if argv is None else argv)
    verbosity = 0
    while args and args[0] in ("-v", "--verbose", "-q", "--quiet", "--version"):
        flag = args.pop(0)
        if flag == "--version":
            print(f"fleetslam {__version__}")
            return 0
        verbosity += 1 if flag in ("-v", "--verbose") else -1
    commands = _available_commands()
    if not args or args[0] in ("-h", "--help", "help"):
        print(_usage(commands))
        return 0 if args else 2
    name = args.pop(0)
    if name not in commands:
        print(f"fleetslam: unknown command '{name}'\n\n{_usage(commands)}", file=sys.stderr)
        return 2
    _configure_logging(verbosity)
    keep_freed_memory()  # every frame's buffers reused, not faulted in afresh (fleetslam.allocator)
    module = importlib.import_module(commands[name][0])
    parser = argparse.ArgumentParser(prog=f"fleetslam {name}", description=commands[name][1])
    module.configure(parser)
    # `--ros-args ...` (remaps, parameters, as the launcher passes them) is for the node, not for argparse.
    ros_args: list[str] = []
    if "--ros-args" in args:
        cut = args.index("--ros-args")
        args, ros_args = args[:cut], args[cut:]
    namespace = parser.parse_args(args)
    namespace.ros_args = ros_args
    func = getattr(namespace, "func", None)
    if func is None:
        parser.print_help()
        return 2
    try:
        result = func(namespace)
    except FleetslamError as err:
        print(f"fleetslam {name}: error: {err}", file=sys.stderr)
        return err.exit_code
    except KeyboardInterrupt:
        return 130
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())
