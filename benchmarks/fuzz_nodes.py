"""Hostile samples on every subscribed topic of the robot, SLAM, mapping, fleet-map and console nodes (issue 18).

Runs ``tests/fuzz`` with ``--count`` samples (default 100,000; CI runs 10,000) over a real router on loopback and
prints one JSON line: the count, whether every node was alive and at its rate afterwards, and the seconds taken.

    python benchmarks/fuzz_nodes.py [--count 100000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=100_000)
    args = parser.parse_args()
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(ROOT / "tests" / "fuzz")],
        cwd=ROOT, env={**os.environ, "FLEETSLAM_FUZZ_COUNT": str(args.count)}, capture_output=True, text=True,
    )  # fmt: skip
    print(json.dumps({"benchmark": "fuzz_nodes", "samples": args.count, "nodes_alive_at_rate": result.returncode == 0,
                      "seconds": round(time.perf_counter() - start, 1)}))  # fmt: skip
    if result.returncode != 0:
        print(result.stdout[-4000:], file=sys.stderr)
    return result.returncode


if __name__ == "__main__":
    raise SystemExit(main())
