"""The ROS 1 bridge's figure: a rospy camera publishing 640×480 rgb8 at 30 Hz into a real roscore, bridged into
the fleet by `fleetslam bridge ros1` (its own process); one JSON line with the rate and latency (receive time
minus the header stamp, same clock) seen by a fleet subscriber, against the peer measured in the same run:
`rostopic hz` and `rostopic delay` on the ROS 1 topic itself (ROS 1 alone, no bridge).

Target: the fleet side keeps ≥ 95 % of the rate ROS 1 alone sees.

Needs Debian's ROS 1 (scripts/setup as root). Usage: python benchmarks/ros1_bridge.py [--duration 20] [--rate 30]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import xmlrpc.client
from pathlib import Path
from typing import Any

from fleetslam.middleware import Context, Node, QoSProfile, Router
from fleetslam.msg.typesys import ns_from_stamp

TOPIC = "/camera/rgb/image_raw"
CAMERA = Path(__file__).resolve().parent / "ros1_camera.py"
TARGET_RATE_RATIO = 0.95


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_master(uri: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            xmlrpc.client.ServerProxy(uri).getPid("/bench")
            return
        except OSError:
            time.sleep(0.2)
    raise SystemExit(f"roscore did not start at {uri}")


def _last_float(pattern: str, text: str) -> float | None:
    found = re.findall(pattern, text)
    return float(found[-1]) if found else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="seconds measured after warm-up")
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    args = parser.parse_args()

    master_port, router_port = _free_port(), _free_port()
    ros_home = tempfile.TemporaryDirectory(prefix="fleetslam-ros1-bench-")  # roscore's logs, removed at exit
    master = f"http://127.0.0.1:{master_port}"
    router = f"tcp/127.0.0.1:{router_port}"
    env = {**os.environ, "ROS_MASTER_URI": master, "ROS_IP": "127.0.0.1", "FLEETSLAM_ROUTER": router,
           "FLEETSLAM_LISTEN": "tcp/127.0.0.1:0", "ROS_HOME": ros_home.name}  # fmt: skip
    procs: list[subprocess.Popen[Any]] = []

    def spawn(cmd: list[str], **kw: Any) -> subprocess.Popen[Any]:
        proc = subprocess.Popen(cmd, env=env, start_new_session=True, **kw)
        procs.append(proc)
        return proc

    latencies: list[float] = []
    arrivals: list[float] = []
    lock = threading.Lock()
    measuring = threading.Event()

    def on_image(msg: Any) -> None:
        now = time.time_ns()
        if measuring.is_set():
            with lock:
                arrivals.append(time.monotonic())
                latencies.append((now - ns_from_stamp(msg.header.stamp)) / 1e6)

    with Router([router]):
        try:
            spawn(["roscore", "-p", str(master_port)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            _wait_master(master)
            print("benchmark: roscore up; starting the bridge and the camera", file=sys.stderr, flush=True)
            bridge_cmd = [sys.executable, "-c", "from fleetslam.cli.main import main; raise SystemExit(main())"]
            spawn([*bridge_cmd, "-q", "bridge", "ros1", "--from-ros1", "/camera/*"])
            spawn(["/usr/bin/python3", str(CAMERA), "--topic", TOPIC, "--rate", str(args.rate),
                   "--width", str(args.width), "--height", str(args.height)])  # fmt: skip
            with (
                Context(router=router, listen="tcp/127.0.0.1:0", environ={}) as ctx,
                Node("bench_viewer", context=ctx) as node,
            ):
                node.create_subscription("sensor_msgs/msg/Image", TOPIC, on_image, QoSProfile(depth=2))
                time.sleep(5.0)  # discovery, connections, first frames
                hz = spawn(["rostopic", "hz", TOPIC], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                delay = spawn(["rostopic", "delay", TOPIC], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
                time.sleep(2.0)  # rostopic's own connection
                measuring.set()
                print(f"benchmark: measuring for {args.duration:.0f} s", file=sys.stderr, flush=True)
                time.sleep(args.duration)
                measuring.clear()
                for tool in (hz, delay):
                    os.killpg(tool.pid, signal.SIGINT)
                hz_out = hz.communicate(timeout=20)[0]
                delay_out = delay.communicate(timeout=20)[0]
        finally:
            for proc in reversed(procs):
                if proc.poll() is None:
                    os.killpg(proc.pid, signal.SIGINT)
            for proc in procs:
                try:
                    proc.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()
            ros_home.cleanup()

    ros1_rate = _last_float(r"average rate: ([\d.]+)", hz_out)
    ros1_delay_ms = _last_float(r"average delay: ([\d.]+)", delay_out)
    fleet_rate = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0]) if len(arrivals) > 1 else 0.0
    result = {
        "benchmark": "ros1_bridge",
        "image": f"{args.width}x{args.height} rgb8",
        "publish_rate_hz": args.rate,
        "duration_s": args.duration,
        "fleet_rate_hz": round(fleet_rate, 2),
        "fleet_latency_ms_median": round(statistics.median(latencies), 2) if latencies else None,
        "fleet_latency_ms_p95": round(sorted(latencies)[int(0.95 * (len(latencies) - 1))], 2) if latencies else None,
        "peer": "rostopic hz / rostopic delay on the ROS 1 topic (no bridge)",
        "peer_rate_hz": ros1_rate,
        "peer_latency_ms_mean": None if ros1_delay_ms is None else round(1000 * ros1_delay_ms, 2),
        "rate_ratio": round(fleet_rate / ros1_rate, 3) if ros1_rate else None,
        "target_rate_ratio": TARGET_RATE_RATIO,
        "cpu_cores": os.cpu_count(),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
