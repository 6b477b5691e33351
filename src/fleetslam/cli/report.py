"""`fleetslam report DIR`: the inspection report of a run (findings, map overview, coverage, accuracy, network)."""

from __future__ import annotations

import argparse
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", type=Path, metavar="DIR", help="the run's directory (what `fleetslam demo` wrote)")
    parser.add_argument("--out", type=Path, metavar="DIR", help="where to write (default: DIR/inspection)")
    parser.add_argument("--no-pdf", action="store_true", help="write report.html only (no Chromium needed)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from fleetslam.inspection.report import write_inspection_report

    html, pdf = write_inspection_report(args.run, args.out, pdf=not args.no_pdf)
    print(html)
    if pdf is not None:
        print(pdf)
    return 0
