"""OctoMap file IO speed: fleetslam's numba readers/writers vs OctoMap 1.10 (octomap-python) on geb079.bt.

Prints one JSON line: best-of-N seconds for reading and writing geb079.bt (532,566 nodes) and its `.ot` form,
ours and OctoMap's, the ratios, and whether our bytes equal the original. Numba compile (or cache load) time is
excluded and reported as ``jit_warmup_s``.

    python benchmarks/octomap_io.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import io
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

GEB079 = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "octomap" / "geb079.bt"


def best_of(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    import octomap

    from fleetslam.mapping.octomap_io import bt_bytes, read_octree_file, write_ot

    data = GEB079.read_bytes()
    start = time.perf_counter()
    tree = read_octree_file(data)
    bt_bytes(tree.resolution, tree.leaves)
    write_ot(io.BytesIO(), tree.resolution, tree.leaves)
    warmup = time.perf_counter() - start

    ot_buffer = io.BytesIO()
    write_ot(ot_buffer, tree.resolution, tree.leaves)
    ot_data = ot_buffer.getvalue()
    with tempfile.TemporaryDirectory() as folder:
        ot_path = Path(folder) / "geb079.ot"
        ot_path.write_bytes(ot_data)

        def octomap_read_bt() -> object:
            reference = octomap.OcTree(0.1)
            reference.readBinary(data)
            return reference

        loaded = octomap_read_bt()
        figures = {
            "file": "geb079.bt",
            "nodes": tree.num_nodes,
            "read_bt_s": best_of(lambda: read_octree_file(data), args.repeats),
            "octomap_read_bt_s": best_of(octomap_read_bt, args.repeats),
            # writeBinary() runs toMaxLikelihood()+prune() like ours; on an already-ML tree both are no-ops.
            "write_bt_s": best_of(lambda: bt_bytes(tree.resolution, tree.leaves), args.repeats),
            "octomap_write_bt_s": best_of(lambda: loaded.writeBinary(), args.repeats),  # type: ignore[attr-defined]
            "read_ot_s": best_of(lambda: read_octree_file(ot_data), args.repeats),
            "octomap_read_ot_s": best_of(lambda: octomap.OcTree.read(str(ot_path)), args.repeats),
            "write_ot_s": best_of(lambda: write_ot(io.BytesIO(), tree.resolution, tree.leaves), args.repeats),
            "jit_warmup_s": warmup,
            "bt_round_trip_identical": bt_bytes(tree.resolution, tree.leaves) == data,
        }
    for kind in ("read_bt", "write_bt", "read_ot"):
        figures[f"{kind}_speedup_vs_octomap"] = figures[f"octomap_{kind}_s"] / figures[f"{kind}_s"]
    print(json.dumps({k: round(v, 6) if isinstance(v, float) else v for k, v in figures.items()}))


if __name__ == "__main__":
    main()
