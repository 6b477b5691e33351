"""`fleetslam config dump [SECTION]`: every default setting, documented field by field."""

from __future__ import annotations

import argparse
import importlib

from pydantic import BaseModel

from fleetslam.config import dump_config

#: section name -> "module:ClassName" of its ConfigModel; imported lazily.
SECTIONS: dict[str, str] = {
    "robot": "fleetslam.robot.config:RobotConfig",
    "sim": "fleetslam.sim.config:SimConfig",
    "slam": "fleetslam.slam.config:SlamConfig",
    "mapping": "fleetslam.mapping.config:MappingConfig",
}


def load_section_model(section: str) -> type[BaseModel]:
    """The model class of a section."""
    module_name, _, class_name = SECTIONS[section].partition(":")
    model: type[BaseModel] = getattr(importlib.import_module(module_name), class_name)
    return model


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    dump = sub.add_parser("dump", help="print the defaults as YAML, each key with its documentation")
    dump.add_argument("section", nargs="?", choices=sorted(SECTIONS), help="one section (default: all)")
    dump.set_defaults(func=run_dump)


def run_dump(args: argparse.Namespace) -> int:
    sections = [args.section] if args.section else list(SECTIONS)
    chunks = []
    for section in sections:
        model = load_section_model(section)
        body = dump_config(model())
        indented = "".join(f"  {line}\n" if line else "\n" for line in body.splitlines())
        chunks.append(f"{section}:\n{indented}")
    print("\n".join(chunks), end="")
    return 0
