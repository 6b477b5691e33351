"""`fleetslam config dump [SECTION]`: every default setting, documented field by field."""

from __future__ import annotations

import argparse

from fleetslam.config import CONFIG_SECTIONS, dump_sections


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    dump = sub.add_parser("dump", help="print the defaults as YAML, each key with its documentation")
    dump.add_argument("section", nargs="?", choices=sorted(CONFIG_SECTIONS), help="one section (default: all)")
    dump.set_defaults(func=run_dump)


def run_dump(args: argparse.Namespace) -> int:
    print(dump_sections([args.section] if args.section else None), end="")
    return 0
