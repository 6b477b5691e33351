"""``fleetslam eval ape|rpe GT EST``: trajectory errors with the TUM tools' conventions (via evo)."""

from __future__ import annotations

import argparse
import json


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="eval_command", required=True)
    ape = sub.add_parser("ape", help="absolute pose error (translation) after SE(3) alignment")
    rpe = sub.add_parser("rpe", help="relative pose error (translation)")
    for p in (ape, rpe):
        p.add_argument("gt", help="ground-truth TUM file")
        p.add_argument("est", help="estimated TUM file")
        p.add_argument("--max-diff", type=float, default=0.02, help="timestamp association tolerance [s]")
        p.add_argument("--json", action="store_true", help="print one JSON object")
    ape.add_argument("--align", action=argparse.BooleanOptionalAction, default=True, help="Umeyama SE(3) alignment")
    ape.add_argument("--scale", action="store_true", help="also correct scale (Sim(3))")
    ape.add_argument("--plot", help="write a PNG plot")
    ape.set_defaults(func=_ape)
    rpe.add_argument("--delta", type=float, default=1.0, help="pair distance")
    rpe.add_argument("--delta-unit", choices=["f", "m"], default="f", help="frames or metres")
    rpe.set_defaults(func=_rpe)


def _print(result: object, as_json: bool) -> None:
    from fleetslam.eval import ErrorStats

    assert isinstance(result, ErrorStats)
    if as_json:
        print(json.dumps(result.as_dict()))
        return
    print(result.conventions)
    for key in ("rmse", "mean", "median", "std", "min", "max"):
        print(f"  {key:6s} {getattr(result, key):.6f}")
    print(f"  pairs  {result.pairs}")


def _ape(args: argparse.Namespace) -> int:
    from fleetslam.eval import ape, plot_ape
    from fleetslam.trajectory import read_tum

    gt, est = read_tum(args.gt), read_tum(args.est)
    _print(ape(gt, est, align=args.align, scale=args.scale, max_diff=args.max_diff), args.json)
    if args.plot:
        plot_ape(gt, est, args.plot, align=args.align, scale=args.scale, max_diff=args.max_diff)
    return 0


def _rpe(args: argparse.Namespace) -> int:
    from fleetslam.eval import rpe
    from fleetslam.trajectory import read_tum

    _print(
        rpe(
            read_tum(args.gt), read_tum(args.est), delta=args.delta, delta_unit=args.delta_unit, max_diff=args.max_diff
        ),
        args.json,
    )
    return 0
