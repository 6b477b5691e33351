"""Try a multi-host fleet on one machine (root): a router host and two agents in their own network namespaces.

    sudo python examples/multi_host_netns.py [--outage 5]

The host namespace runs `fleetslam router`; agents c3po and r2d2 each run examples/graph_agent.py configured
only by FLEETSLAM_ROUTER / FLEETSLAM_AGENT / FLEETSLAM_LISTEN; c3po subscribes to r2d2's graph and back. A
viewer in the host namespace prints `fleetslam stats` for both agents; then r2d2's link is taken down for a
few seconds and brought back, and the statistics show the gap and the recovery. Everything is removed at exit.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from fleetslam.launch.netns import VirtualNetwork

HERE = Path(__file__).resolve().parent


def fleetslam(*args: str) -> list[str]:
    return [sys.executable, "-m", "fleetslam.cli.main", *args]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--outage", type=float, default=5.0, help="seconds r2d2's link stays down")
    args = parser.parse_args()
    with VirtualNetwork(["c3po", "r2d2"]) as net:
        processes = [net.popen("host", fleetslam("router", "--listen", f"tcp/{net.host.address}:7447"))]
        time.sleep(1.0)
        for agent, peer in (("c3po", "r2d2"), ("r2d2", "c3po")):
            processes.append(net.popen(agent, [sys.executable, str(HERE / "graph_agent.py"), "--peers", peer]))
        try:
            time.sleep(4.0)
            print(net.run("host", fleetslam("stats", "--once", "--wait", "2.5")).stdout, flush=True)
            print(f"--- taking r2d2's link down for {args.outage} s", flush=True)
            net.set_link("r2d2", up=False)
            time.sleep(args.outage)
            net.set_link("r2d2", up=True)
            print("--- link up again", flush=True)
            time.sleep(3.0)
            print(net.run("host", fleetslam("stats", "--once", "--wait", "2.5")).stdout, flush=True)
        finally:
            for process in processes:
                process.terminate()
            for process in processes:
                try:
                    process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    process.kill()


if __name__ == "__main__":
    main()
