"""Middleware throughput and latency across two processes on loopback: fleetslam vs raw Zenoh vs rclpy (Fast DDS).

Prints one JSON line. For each payload (1 MB sensor_msgs/Image, 64-byte std_msgs/String) and each peer, trials of:
- throughput: a publisher process sends as fast as it can (reliable, blocking when congested) for ``--duration``
  seconds; the subscriber in this process counts what it receives in the steady middle of the run; both ends'
  CPU time per message (``pub_cpu_us_per_msg``, ``sub_cpu_us_per_msg``; the subscriber's includes the router,
  which runs in this process for every peer alike);
- latency: the publisher sends at a fixed rate, stamping the send time before serialization; the subscriber
  records receive − send (same machine, same clock), p50 and p99.
Peers: ``fleetslam`` (callbacks on the node's executor, the default), ``fleetslam_inline`` (``inline=True``:
callbacks on Zenoh's thread), raw ``zenoh`` (the same CDR bytes, an 8-byte attachment, one copy out of Zenoh)
and rclpy. The fleetslam peers publish an image through a loan (``Publisher.loan``: its array written once into
the publisher's payload, as raw Zenoh's payload is built once; each message's other fields written around it);
``fleetslam_copy`` (1 MB and Kinect) publishes the message itself, its array copied into the payload each time.
rclpy runs in its own virtual environment (created on first use under ~/.cache/fleetslam/bench-rclpy),
because its pip wheels re-execute the interpreter at import. Targets, fleetslam (executor) against raw Zenoh in
the same run: 1 MB throughput ≥ 0.8× and p50 latency ≤ 1.5×; 64 B throughput ≥ 0.5×; and ≥ 5× / ≥ 10× rclpy.

The comparison with raw Zenoh is made on medians of interleaved trials: a single trial per peer, one after the
other, lets a burst of other load or a change of CPU frequency during one peer's trial decide the ratio (the same
code's 64 B ratio moved by 0.2 from run to run that way). Each payload runs ``--trials`` rounds (default 5); a
round runs each fleetslam and raw Zenoh peer once (a fresh publisher process and subscriber per trial, a
throughput trial then a latency trial), in the order fleetslam, fleetslam_inline, (fleetslam_copy,) zenoh and
reversed in every other round. A peer's ``msgs_per_s``, ``latency_p50_ms``, ``latency_p99_ms``,
``pub_cpu_us_per_msg`` and ``sub_cpu_us_per_msg`` are the medians over its trials (each trial's figures are in its
``trials``; ``latency_samples`` is the total); ``ratio_vs_zenoh`` and ``latency_p50_vs_zenoh`` are ratios of those
medians, and ``targets_met`` judges the medians; ``ratio_vs_zenoh_pairs`` / ``latency_p50_vs_zenoh_pairs`` are the
ratios within each round and ``…_range`` their [min, max], the spread. rclpy is measured once per payload (one
throughput and one latency trial: its targets are far from the line). ``all_targets_met``: every payload's
``targets_met`` (the fleetslam executor peer). ``pub_threads_us_per_msg`` / ``sub_threads_us_per_msg``: each end's
CPU µs per message (sent / delivered) by kind of thread (``executor``, ``receive``, Zenoh's ``rx``/``tx``/``net``,
``Thread``: raw Zenoh's callback thread, ``MainThread``; Linux only), per trial and their medians.
``load_avg_1m_start``/``…_end`` give the machine's 1-minute load average around the run. A publisher starts sending
once its Zenoh publisher matches the subscriber (then 0.2 s), not after a fixed second, so that short trials stay
cheap.

``kinect``: a 640×480 rgb8 Image at 30 Hz and a 640×480 16UC1 depth Image at 30 Hz, each end's CPU % of one core
for fleetslam and raw Zenoh; ``layers_cpu_pct`` is the difference, what fleetslam's layers cost at each end
(serialization, attachment, statistics, hand-off, deserialization; the subscriber reads every image as an array).

``--layers N`` measures instead, in this one process, the thread CPU time per message of each layer at both ends
(N messages of 64 B, N/50 of 1 MB, on a real sample through a router): serialization, ``publish_raw`` (sequence
number, attachment, put) against raw Zenoh's put of the same payload to the same subscriber, the attachment, the
payload's copy out of Zenoh, the statistics, deserialization, and the subscription's own entry point on the thread
that receives (a KEEP_LAST subscription's receive thread, batched into the executor; KEEP_ALL's Zenoh callback
thread, one hand-off per sample; ``inline``) and its executor's share, and a KEEP_LAST executor taking the samples
from the ring itself (``sub_batched_executor_pull``: all of a sample's Python work, on one thread), against what the
raw Zenoh peer's callback does. Thread CPU time
depends far less than wall time on what else the machine runs, but not nothing: on a shared two-vCPU machine the
same row moved up to 2× between runs minutes apart, so compare versions in alternating runs, against the raw Zenoh
reference rows of the same run; the tables are in docs/middleware-api.md ("Cost per message").

    python benchmarks/middleware_throughput.py [--trials 5] [--duration 1.5] [--no-rclpy]
        [--payloads image_1mb,string_64b,kinect]
    python benchmarks/middleware_throughput.py --layers 100000 [--payloads string_64b,image_1mb]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import socket
import struct
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam.allocator import keep_freed_memory

PAYLOADS = {"image_1mb": 1 << 20, "string_64b": 64}
KINECT = {"rgb": ("rgb8", 3, np.uint8), "depth": ("16UC1", 1, np.uint16)}
"""The Kinect pair: topic /bench/kinect/<name> → (encoding, channels, dtype), 640×480 at 30 Hz each."""
KINECT_SIZE, KINECT_RATE = (640, 480), 30.0
IMPLS = ("fleetslam", "fleetslam_inline", "zenoh")
COPY_IMPL = "fleetslam_copy"
"""With an image: a fleetslam peer (executor) that publishes the message itself, its array copied into the payload,
beside the default peers that publish it through a loan."""
IMAGE_IMPLS = (*IMPLS[:2], COPY_IMPL, *IMPLS[2:])
"""The peers of the image payloads (1 MB, Kinect): the copying peer beside the others, raw Zenoh last."""
RCLPY_VENV = Path.home() / ".cache" / "fleetslam" / "bench-rclpy"
RCLPY_PACKAGES = ["ros-rclpy", "ros-std-msgs", "ros-sensor-msgs", "ros-rmw-fastrtps-cpp"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- messages --------------------------------------------------------------------------------------------------
def make_message(kind: str) -> tuple[str, Any]:
    from fleetslam.msg.typesys import get_type, header

    if kind == "image_1mb":
        image = get_type("sensor_msgs/msg/Image")
        width, height = 512, 512  # rgba8: 512*512*4 = 1 MiB
        data = np.random.default_rng(0).integers(0, 255, width * height * 4, dtype=np.uint8)
        msg = image(
            header=header("camera", 0), height=height, width=width, encoding="rgba8", is_bigendian=0,
            step=width * 4, data=data,
        )  # fmt: skip
        return "sensor_msgs/msg/Image", msg
    if kind.startswith("kinect/"):
        encoding, channels, dtype = KINECT[kind.split("/")[1]]
        width, height = KINECT_SIZE
        pixels = np.random.default_rng(0).integers(0, 255, (height, width, channels)).astype(dtype)
        msg = get_type("sensor_msgs/msg/Image")(
            header=header("camera", 0), height=height, width=width, encoding=encoding, is_bigendian=0,
            step=width * channels * pixels.itemsize, data=pixels.reshape(-1).view(np.uint8),
        )  # fmt: skip
        return "sensor_msgs/msg/Image", msg
    string = get_type("std_msgs/msg/String")
    return "std_msgs/msg/String", string(data="x" * (PAYLOADS[kind] - 8))


# -- publisher roles (run as subprocesses of this script) ------------------------------------------------------
def wait_matched(publishers: list[Any], timeout_s: float = 5.0) -> None:
    """Wait until each Zenoh publisher has a matching subscriber (the route through the router is up), then 0.2 s."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and not all(p.matching_status.matching for p in publishers):
        time.sleep(0.02)
    time.sleep(0.2)


def topics_of(kind: str) -> list[str]:
    """The payload kinds one run publishes: one, or the Kinect pair."""
    return [f"kinect/{name}" for name in KINECT] if kind == "kinect" else [kind]


def loaned(publisher: Any, msg: Any) -> Any:
    """The message through the publisher's loan when its type ends in a byte array (an Image), else itself."""
    from fleetslam.msg.typesys import trailing_array

    trailing = trailing_array(publisher.type_name)
    if trailing is None:
        return msg
    array = getattr(msg, trailing.field)
    message = publisher.loan(msg, array.size)
    np.copyto(getattr(message, trailing.field), array)
    return message


def run_publisher(
    impl: str, kind: str, endpoint: str, mode: str, duration: float, rate: float, copy_arrays: bool = False
) -> None:
    """Publish for ``duration`` s, then print one JSON line: messages sent, CPU s and wall s of the sending loop.
    A fleetslam peer publishes an image through a loan (:meth:`Publisher.loan`) unless ``copy_arrays``."""
    from fleetslam.msg.typesys import serialize

    messages = [(f"/bench/{k}", *make_message(k)) for k in topics_of(kind)]
    period = 1.0 / rate if mode in ("latency", "kinect") else 0.0
    sent = 0
    if impl.startswith("fleetslam"):
        from fleetslam.middleware import Context, Node, QoSProfile

        with Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}, statistics=False) as ctx:
            node = Node("bench_pub", context=ctx, statistics_period_s=0)
            qos = QoSProfile(history="keep_all") if mode == "throughput" else QoSProfile(depth=100)
            publishers = [(node.create_publisher(t, topic, qos), t, msg) for topic, t, msg in messages]
            wait_matched([publisher._publisher for publisher, _, _ in publishers])
            if not copy_arrays:  # an image is written into the publisher's loan once, as raw Zenoh's payload is
                publishers = [(p, t, loaned(p, msg)) for p, t, msg in publishers]
            threads0, cpu0, wall0 = thread_cpu_s(), time.process_time(), time.monotonic()
            deadline, next_time = wall0 + duration, wall0
            while time.monotonic() < deadline:
                for publisher, _, msg in publishers:
                    t0 = time.time_ns()  # stamped before serialization: the latency includes it
                    publisher.publish(msg, source_timestamp_ns=t0)
                    sent += 1
                if period:
                    next_time += period
                    time.sleep(max(0.0, next_time - time.monotonic()))
            cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
            threads = thread_cpu_delta(threads0, thread_cpu_s())
            time.sleep(0.5)
        print(json.dumps({"sent": sent, "cpu_s": cpu, "wall_s": wall, "threads_cpu_s": threads}), flush=True)
        return
    import zenoh

    from fleetslam.middleware.wire import topic_key

    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(config) as session:
        congestion = zenoh.CongestionControl.BLOCK if mode == "throughput" else zenoh.CongestionControl.DROP
        # Raw Zenoh carries the same CDR bytes (serialized once); the send time travels in an 8-byte attachment.
        puts = [
            (session.declare_publisher(topic_key(0, topic, t), congestion_control=congestion), serialize(msg, t))
            for topic, t, msg in messages
        ]
        wait_matched([zenoh_publisher for zenoh_publisher, _ in puts])
        threads0, cpu0, wall0 = thread_cpu_s(), time.process_time(), time.monotonic()
        deadline, next_time = wall0 + duration, wall0
        while time.monotonic() < deadline:
            for zenoh_publisher, payload in puts:
                zenoh_publisher.put(payload, attachment=struct.pack("<q", time.time_ns()))
                sent += 1
            if period:
                next_time += period
                time.sleep(max(0.0, next_time - time.monotonic()))
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        threads = thread_cpu_delta(threads0, thread_cpu_s())
        time.sleep(0.5)
    print(json.dumps({"sent": sent, "cpu_s": cpu, "wall_s": wall, "threads_cpu_s": threads}), flush=True)


# -- per-thread CPU time (Linux) ------------------------------------------------------------------------------
def thread_cpu_s() -> dict[int, tuple[str, float]]:
    """This process's threads: id → (kind, CPU s); empty where /proc is not there. The kind is the thread's Python
    name (``executor:…`` → ``executor``, ``receive:…`` → ``receive``, ``Thread-3 (…)`` → ``Thread``: raw Zenoh's
    callback thread) or its OS name (Zenoh's ``rx-0`` → ``rx``, ``tx``, ``net``; ``python``: unnamed native threads)."""
    names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
    tick = os.sysconf("SC_CLK_TCK")
    threads = {}
    try:
        ids = os.listdir("/proc/self/task")
    except OSError:
        return {}
    for tid in ids:
        try:
            stat = Path(f"/proc/self/task/{tid}/stat").read_text()
        except OSError:
            continue  # ended meanwhile
        fields = stat[stat.rindex(")") + 2 :].split()  # utime and stime are fields 14 and 15
        name = names.get(int(tid)) or stat[stat.index("(") + 1 : stat.rindex(")")]
        threads[int(tid)] = (re.sub(r"-\d.*$", "", name.split(":")[0]), (int(fields[11]) + int(fields[12])) / tick)
    return threads


def thread_cpu_delta(before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]]) -> dict[str, float]:
    """CPU s per kind of thread between two :func:`thread_cpu_s` readings (threads started between them included)."""
    spent: dict[str, float] = {}
    for tid, (kind, cpu) in after.items():
        spent[kind] = spent.get(kind, 0.0) + cpu - before.get(tid, (kind, 0.0))[1]
    return {kind: round(cpu, 3) for kind, cpu in sorted(spent.items()) if cpu > 0}


# -- subscriber side (this process) -----------------------------------------------------------------------------
class Receiver:
    def __init__(self) -> None:
        self.times: list[float] = []
        self.latencies_ns: list[int] = []
        self.lock = threading.Lock()
        self.sub_cpu_s = 0.0
        """This process's CPU time while the publisher ran (subscriber and router)."""
        self.sub_threads_cpu_s: dict[str, float] = {}
        """The same per kind of thread (see thread_cpu_s)."""
        self.publisher: dict[str, Any] = {}
        """The publisher's line: sent, cpu_s, wall_s of its sending loop."""

    def record(self, send_ns: int) -> None:
        now = time.time_ns()
        with self.lock:
            self.times.append(time.monotonic())
            self.latencies_ns.append(now - send_ns)


def steady_rate(times: list[float]) -> float:
    if len(times) < 10:
        return float(len(times))
    start, stop = times[0], times[-1]
    lo, hi = start + 0.2 * (stop - start), start + 0.9 * (stop - start)
    inside = [t for t in times if lo <= t <= hi]
    return len(inside) / (hi - lo) if hi > lo else 0.0


def measure_in_process(impl: str, kind: str, mode: str, duration: float, rate: float) -> Receiver:
    from fleetslam.middleware import Context, MessageInfo, Node, QoSProfile, Router
    from fleetslam.middleware.wire import topic_key

    kinds = topics_of(kind)
    type_name, _ = make_message(kinds[0])
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    receiver = Receiver()
    with Router([endpoint]):
        if impl.startswith("fleetslam"):
            ctx = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}, statistics=False)
            node = Node("bench_sub", context=ctx, statistics_period_s=0)

            def on_message(msg: Any, info: MessageInfo) -> None:
                if kind == "kinect":  # the image as an array, as a consumer reads it (a view, no copy)
                    np.asarray(msg.data).reshape(msg.height, msg.width, -1)
                receiver.record(info.source_timestamp_ns)

            for k in kinds:
                node.create_subscription(
                    type_name, f"/bench/{k}", on_message, QoSProfile(depth=1000), inline=impl == "fleetslam_inline"
                )
            closer: Any = ctx
        else:
            import zenoh

            config = zenoh.Config()
            config.insert_json5("connect/endpoints", json.dumps([endpoint]))
            config.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
            config.insert_json5("scouting/multicast/enabled", "false")
            session = zenoh.open(config)

            def on_sample(sample: Any) -> None:
                payload = sample.payload.to_bytes()  # the same copy out of Zenoh that fleetslam makes
                if kind == "kinect":
                    np.frombuffer(payload, np.uint8)
                del payload
                receiver.record(struct.unpack("<q", sample.attachment.to_bytes())[0])

            for k in kinds:
                session.declare_subscriber(topic_key(0, f"/bench/{k}", type_name), on_sample)
            closer = session
        threads0, cpu0 = thread_cpu_s(), time.process_time()
        proc = subprocess.Popen(
            [sys.executable, __file__, "--role", "pub", "--impl", impl, "--kind", kind, "--endpoint", endpoint,
             "--mode", mode, "--duration", str(duration), "--rate", str(rate)],
            stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        out, _ = proc.communicate(timeout=duration + 30)
        time.sleep(0.3)
        receiver.sub_cpu_s = time.process_time() - cpu0
        receiver.sub_threads_cpu_s = thread_cpu_delta(threads0, thread_cpu_s())
        closer.close()
    lines = out.strip().splitlines()
    receiver.publisher = json.loads(lines[-1]) if lines else {}
    return receiver


# -- rclpy peer -------------------------------------------------------------------------------------------------
RCLPY_SCRIPT = textwrap.dedent(
    """
    import sys, time, json, threading
    import numpy as np
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy, HistoryPolicy
    from sensor_msgs.msg import Image
    from std_msgs.msg import String
    role, kind, mode, duration, rate = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
    rclpy.init()
    node = Node("bench_" + role)
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
    if kind == "image_1mb":
        msg_type = Image
    else:
        msg_type = String
    if role == "pub":
        pub = node.create_publisher(msg_type, "/bench/" + kind, qos)
        if kind == "image_1mb":
            msg = Image(height=512, width=512, encoding="rgba8", step=2048)
            msg.data = np.random.default_rng(0).integers(0, 255, 512 * 512 * 4, dtype=np.uint8).tobytes()
        time.sleep(2.0)
        deadline = time.monotonic() + duration
        period = 1.0 / rate if mode == "latency" else 0.0
        nxt = time.monotonic()
        while time.monotonic() < deadline:
            t = time.time_ns()
            if kind == "image_1mb":
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
            else:
                msg = String(data=str(t).ljust(56, "x"))
            try:
                pub.publish(msg)
            except Exception:  # Fast DDS refuses to publish when its history is full: back off, go on
                time.sleep(0.001)
                continue
            if period:
                nxt += period
                time.sleep(max(0.0, nxt - time.monotonic()))
        time.sleep(0.5)
    else:
        times, lat = [], []
        def cb(m):
            now = time.time_ns()
            if kind == "image_1mb":
                sent = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            else:
                sent = int(m.data[:19])
            times.append(time.monotonic()); lat.append(now - sent)
        node.create_subscription(msg_type, "/bench/" + kind, cb, qos)
        end = time.monotonic() + duration + 4.0
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        print(json.dumps({"times": times, "lat": lat}))
    node.destroy_node()
    rclpy.shutdown()
    """
)


def ensure_rclpy_venv() -> tuple[Path | None, str]:
    python = RCLPY_VENV / "bin" / "python"
    if not python.exists():
        try:
            subprocess.run([sys.executable, "-m", "venv", str(RCLPY_VENV)], check=True, capture_output=True)
            subprocess.run(
                [str(python), "-m", "pip", "install", "-q", *RCLPY_PACKAGES],
                check=True,
                capture_output=True,
                timeout=900,
            )
        except (subprocess.CalledProcessError, subprocess.TimeoutExpired) as err:
            return None, f"could not create the rclpy environment: {err}"
    check = subprocess.run([str(python), "-c", "import rclpy"], capture_output=True, text=True, timeout=120)
    if check.returncode != 0:
        return None, f"rclpy does not import: {check.stderr.strip()[-300:]}"
    return python, ""


def measure_rclpy(python: Path, kind: str, mode: str, duration: float, rate: float) -> Receiver:
    script = Path(os.environ.get("TMPDIR", "/tmp")) / "fleetslam_bench_rclpy.py"
    script.write_text(RCLPY_SCRIPT)
    env = {**os.environ, "RMW_IMPLEMENTATION": "rmw_fastrtps_cpp", "ROS_LOCALHOST_ONLY": "1", "ROS_DOMAIN_ID": "77"}
    sub = subprocess.Popen(
        [str(python), str(script), "sub", kind, mode, str(duration), str(rate)],
        env=env,
        stdout=subprocess.PIPE,
        text=True,
    )
    time.sleep(1.0)
    pub = subprocess.run(
        [str(python), str(script), "pub", kind, mode, str(duration), str(rate)], env=env, timeout=duration + 60
    )
    del pub
    out, _ = sub.communicate(timeout=duration + 60)
    data = json.loads(out.strip().splitlines()[-1])
    receiver = Receiver()
    receiver.times, receiver.latencies_ns = data["times"], data["lat"]
    return receiver


# -- layers: thread CPU time per message of each of fleetslam's layers, in one process ---------------------------
def _us_per_message(work: Any, count: int) -> float:
    """Thread CPU µs per call of ``work(count)`` (independent of what else runs on the machine, unlike wall time)."""
    import gc

    gc.collect()
    start = time.thread_time_ns()
    work(count)
    return round((time.thread_time_ns() - start) / count / 1000, 3)


def measure_layers(kind: str, count: int) -> dict[str, float]:
    """Each layer of both ends on a real sample (a fleetslam publisher's, through a router), ``count`` times.

    The totals run the subscription's own entry point on that sample: on Zenoh's thread (checks, statistics,
    queueing; with ``inline`` also decoding and the callback) and on the executor (hand-off, decoding, callback).
    """
    from fleetslam.middleware import Context, Node, QoSProfile, Router
    from fleetslam.middleware.statistics import SubscriptionStatistics
    from fleetslam.msg.typesys import deserialize, serialize_payload

    type_name, msg = make_message(kind)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rows: dict[str, float] = {}
    with Router([endpoint]):
        ctx = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}, statistics=False)
        peer = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}, statistics=False)
        node = Node("bench_layers", context=ctx, statistics_period_s=0)
        publisher = node.create_publisher(type_name, "/bench/layers", QoSProfile(history="keep_all"))
        samples: list[Any] = []
        remote = peer.session.declare_subscriber(  # the puts go on the wire; the first sample is kept
            publisher.key, lambda received: samples.append(received) if not samples else None
        )
        time.sleep(0.5)
        publisher.publish(msg)
        deadline = time.monotonic() + 5.0
        while not samples and time.monotonic() < deadline:
            time.sleep(0.01)
        sample = samples[0]
        payload = serialize_payload(msg, type_name)
        unpack = struct.Struct("<qqB16s").unpack

        def serialize(n: int) -> None:
            for _ in range(n):
                serialize_payload(msg, type_name)

        def publish_raw(n: int) -> None:
            for _ in range(n):
                publisher.publish_raw(payload)

        def publish(n: int) -> None:
            for _ in range(n):
                publisher.publish(msg)

        raw_publisher = ctx.session.declare_publisher(publisher.key)

        def zenoh_put(n: int) -> None:
            attachment = struct.pack("<q", 0)
            for _ in range(n):
                raw_publisher.put(payload, attachment=attachment)

        rows["pub_serialize"] = _us_per_message(serialize, count)
        for _ in range(2):  # alternately, the better of two: a put may wait for the previous run's backlog
            for name, work in (("pub_zenoh_put_ref", zenoh_put), ("pub_publish_raw", publish_raw)):
                time.sleep(0.3)
                rows[name] = min(rows.get(name, math.inf), _us_per_message(work, count))
        time.sleep(0.3)
        rows["pub_total"] = _us_per_message(publish, count)
        loaned_msg = loaned(publisher, msg)
        if loaned_msg is not msg:  # an image through the publisher's loan: no copy of its array before Zenoh's

            def publish_loaned(n: int) -> None:
                for _ in range(n):
                    publisher.publish(loaned_msg)

            time.sleep(0.3)
            rows["pub_total_loaned"] = _us_per_message(publish_loaned, count)
        time.sleep(0.5)
        remote.undeclare()

        def attachment(n: int) -> None:
            for _ in range(n):
                unpack(sample.attachment.to_bytes())

        def payload_copy(n: int) -> None:
            for _ in range(n):
                zbytes = sample.payload
                len(zbytes)
                zbytes.to_bytes()

        statistics = SubscriptionStatistics(time.time_ns())
        gid = unpack(sample.attachment.to_bytes())[3]

        def statistics_update(n: int) -> None:
            for i in range(n):
                statistics.on_sample(gid, i + 1, 0, time.time_ns(), 64)

        data = sample.payload.to_bytes()

        def decode(n: int) -> None:
            for _ in range(n):
                deserialize(data, type_name)

        rows["sub_attachment"] = _us_per_message(attachment, count)
        rows["sub_payload_copy"] = _us_per_message(payload_copy, count)
        rows["sub_statistics"] = _us_per_message(statistics_update, count)  # with the receive time_ns()
        rows["sub_deserialize"] = _us_per_message(decode, count)
        for path in ("batched", "executor", "inline"):
            rows.update(_subscription_path(node, type_name, sample, count, path=path))
        if kind == "string_64b":  # 1 MB samples left in the ring would measure cold caches and page faults
            rows["sub_batched_executor_pull"] = _executor_pull(node, publisher, msg, type_name, count)

        def zenoh_callback(n: int) -> None:  # what the raw Zenoh peer's subscriber does with each sample
            for _ in range(n):
                sample.payload.to_bytes()
                struct.unpack("<q", sample.attachment.to_bytes()[:8])

        rows["sub_zenoh_callback_ref"] = _us_per_message(zenoh_callback, count)
        peer.close()
        ctx.close()
    return rows


def _subscription_path(node: Any, type_name: str, sample: Any, count: int, *, path: str) -> dict[str, float]:
    """Thread CPU µs per sample of a subscription's entry point on its receiving thread and of its executor's share.

    ``batched``: a KEEP_LAST subscription (its receive thread's work per sample, drained by the executor in
    batches); ``executor``: KEEP_ALL (Zenoh's callback thread, one executor post per sample); ``inline``.
    """
    from fleetslam.middleware import QoSProfile

    delivered = [0]

    def callback(msg: Any, info: Any) -> None:
        delivered[0] += 1

    qos = QoSProfile(depth=count) if path == "batched" else QoSProfile(history="keep_all")
    subscription = node.create_subscription(type_name, "/bench/layers_copy", callback, qos, inline=path == "inline")
    executor_cpu: list[int] = []
    marks = [threading.Event(), threading.Event()]

    def mark(index: int) -> None:
        executor_cpu.append(time.thread_time_ns())
        marks[index].set()

    node.call_soon(lambda: mark(0))
    marks[0].wait(5.0)
    receive = subscription._on_sample
    thread = "receive_thread" if path == "batched" else "zenoh_thread"
    rows = {f"sub_{path}_{thread}": _us_per_message(lambda n: [receive(sample) for _ in range(n)], count)}
    deadline = time.monotonic() + 120.0
    while delivered[0] < count and time.monotonic() < deadline:  # a drain delivers a bounded batch per turn
        time.sleep(0.01)
    node.call_soon(lambda: mark(1))
    marks[1].wait(120.0)
    rows[f"sub_{path}_executor_thread"] = round((executor_cpu[1] - executor_cpu[0]) / count / 1000, 3)
    if delivered[0] != count:
        raise RuntimeError(f"layers: {delivered[0]} of {count} samples delivered ({path})")
    subscription.destroy()
    return rows


def _executor_pull(node: Any, publisher: Any, msg: Any, type_name: str, count: int) -> float:
    """Thread CPU µs per sample of a KEEP_LAST subscription's executor taking the samples from the ring itself (what
    it does while it keeps up with the ring): ``try_recv``, checks, statistics (one call per batch), decoding and
    the callback, all of a sample's Python work on one thread. Real samples of ``publisher``, batch by batch."""
    import gc

    import zenoh

    from fleetslam.middleware import QoSProfile
    from fleetslam.middleware.subscription import RECEIVE_RING_CAPACITY

    delivered = [0]

    def callback(msg: Any, info: Any) -> None:
        delivered[0] += 1

    subscription = node.create_subscription(type_name, "/bench/layers_pull", callback, QoSProfile(depth=count))
    batch = min(count, RECEIVE_RING_CAPACITY)
    ring = node.context.session.declare_subscriber(publisher.key, zenoh.handlers.RingChannel(batch))
    subscription._try_recv = ring.handler.try_recv
    cpu_ns = taken = 0
    while taken < count:
        for _ in range(min(batch, count - taken)):
            publisher.publish(msg)
        time.sleep(0.1)
        gc.collect()
        subscription._executor_pulls = True
        start = time.thread_time_ns()
        pulled = 0
        while pulled_now := subscription._pull(batch):
            pulled += pulled_now
        cpu_ns += time.thread_time_ns() - start
        if not pulled:
            raise RuntimeError("layers: the ring received nothing (executor pull)")
        taken += pulled
    ring.undeclare()
    subscription.destroy()
    if delivered[0] != taken:
        raise RuntimeError(f"layers: {delivered[0]} of {taken} samples delivered (executor pull)")
    return round(cpu_ns / taken / 1000, 3)


# -- main -------------------------------------------------------------------------------------------------------
def summarize(throughput: Receiver, latency: Receiver) -> dict[str, Any]:
    lat_ms = np.asarray(latency.latencies_ns, dtype=np.float64) / 1e6
    received = len(throughput.times)
    sent = throughput.publisher.get("sent", 0)
    return {
        "msgs_per_s": round(steady_rate(throughput.times), 1),
        "latency_p50_ms": round(float(np.percentile(lat_ms, 50)), 3) if lat_ms.size else None,
        "latency_p99_ms": round(float(np.percentile(lat_ms, 99)), 3) if lat_ms.size else None,
        "latency_samples": int(lat_ms.size),
        "pub_cpu_us_per_msg": round(throughput.publisher["cpu_s"] / sent * 1e6, 2) if sent else None,
        "sub_cpu_us_per_msg": (
            round(throughput.sub_cpu_s / received * 1e6, 2) if received and throughput.publisher else None
        ),
        "pub_threads_us_per_msg": {
            kind: round(cpu / sent * 1e6, 2) for kind, cpu in throughput.publisher.get("threads_cpu_s", {}).items()
        }
        if sent
        else {},
        "sub_threads_us_per_msg": {
            kind: round(cpu / received * 1e6, 2) for kind, cpu in throughput.sub_threads_cpu_s.items()
        }
        if received
        else {},
    }


TRIAL_KEYS = ("msgs_per_s", "latency_p50_ms", "latency_p99_ms", "pub_cpu_us_per_msg", "sub_cpu_us_per_msg")
"""A trial's figures; a peer's headline figure of each is the median over its trials."""


def _median(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return round(float(np.median(present)), 3) if present else None


def _ratio(ours: float | None, theirs: float | None) -> float | None:
    return round(ours / theirs, 3) if ours is not None and theirs else None


def measure_interleaved(kind: str, impls: tuple[str, ...], trials: int, duration: float, rate: float) -> dict[str, Any]:
    """``trials`` rounds of one throughput and one latency trial per peer, the peers in turn, the order reversed
    every other round (fleetslam, …, zenoh; zenoh, …, fleetslam), so that a burst of other load or a change of CPU
    frequency falls on all peers alike rather than deciding a ratio. Each peer's figures are the medians of its
    trials (``trials`` lists each one); ``ratio_vs_zenoh`` is the ratio of the medians, ``ratio_vs_zenoh_pairs``
    the ratio within each round (its spread is ``ratio_vs_zenoh_range``)."""
    runs: dict[str, list[dict[str, Any]]] = {impl: [] for impl in impls}
    for index in range(trials):
        for impl in impls if index % 2 == 0 else impls[::-1]:
            trial = summarize(
                measure_in_process(impl, kind, "throughput", duration, rate),
                measure_in_process(impl, kind, "latency", min(duration, 2.0), rate),
            )
            runs[impl].append(trial)
            print(
                f"[bench] {kind} trial {index + 1}/{trials} {impl}: {trial['msgs_per_s']:,.0f} msg/s, "
                f"p50 {trial['latency_p50_ms']} ms",
                file=sys.stderr,
                flush=True,
            )
    entry: dict[str, Any] = {}
    for impl, peer_trials in runs.items():
        entry[impl] = {key: _median([t[key] for t in peer_trials]) for key in TRIAL_KEYS}
        entry[impl]["latency_samples"] = sum(t["latency_samples"] for t in peer_trials)
        for end in ("pub", "sub"):
            kinds = sorted({kind for t in peer_trials for kind in t[f"{end}_threads_us_per_msg"]})
            entry[impl][f"{end}_threads_us_per_msg"] = {
                kind: _median([t[f"{end}_threads_us_per_msg"].get(kind, 0.0) for t in peer_trials]) for kind in kinds
            }
        entry[impl]["trials"] = peer_trials
    for impl in impls:
        if impl.startswith("fleetslam") and "zenoh" in runs:
            prefix = "" if impl == "fleetslam" else impl.removeprefix("fleetslam_") + "_"
            pairs = zip(runs[impl], runs["zenoh"], strict=True)
            throughput = [_ratio(ours["msgs_per_s"], zen["msgs_per_s"]) for ours, zen in pairs]
            entry[f"{prefix}ratio_vs_zenoh_pairs"] = throughput
            entry[f"{prefix}ratio_vs_zenoh_range"] = _range(throughput)
            pairs = zip(runs[impl], runs["zenoh"], strict=True)
            latency = [_ratio(ours["latency_p50_ms"], zen["latency_p50_ms"]) for ours, zen in pairs]
            entry[impl]["latency_p50_vs_zenoh_pairs"] = latency
            entry[impl]["latency_p50_vs_zenoh_range"] = _range(latency)
    return entry


def _range(values: list[float | None]) -> list[float] | None:
    present = [v for v in values if v is not None]
    return [min(present), max(present)] if present else None


def measure_kinect(impls: tuple[str, ...], duration: float) -> dict[str, Any]:
    """Each end's CPU % of one core for the Kinect pair; fleetslam's layers = fleetslam − raw Zenoh."""
    entry: dict[str, Any] = {"streams": "640x480 rgb8 30 Hz + 640x480 16UC1 30 Hz"}
    for impl in impls:
        print(f"[bench] kinect {impl} ...", file=sys.stderr, flush=True)
        r = measure_in_process(impl, "kinect", "kinect", duration, KINECT_RATE)
        wall = r.publisher.get("wall_s") or duration
        entry[impl] = {
            "received_per_s": round(len(r.times) / wall, 1),
            "pub_cpu_pct": round(100 * r.publisher.get("cpu_s", 0.0) / wall, 2),
            "sub_cpu_pct": round(100 * r.sub_cpu_s / wall, 2),  # the subscriber and the router
        }
    for impl in impls:
        if impl.startswith("fleetslam") and "zenoh" in entry:
            entry[impl]["layers_cpu_pct"] = {
                end: round(entry[impl][f"{end}_cpu_pct"] - entry["zenoh"][f"{end}_cpu_pct"], 2)
                for end in ("pub", "sub")
            }
    return entry


def check_targets(kind: str, entry: dict[str, Any], impl: str = "fleetslam") -> dict[str, Any]:
    """The issue's targets, a fleetslam peer against raw Zenoh in this run; notes the p50 latency ratio."""
    ours, zen = entry[impl], entry["zenoh"]
    ratio = ours["msgs_per_s"] / zen["msgs_per_s"] if zen["msgs_per_s"] else None
    want = 0.8 if kind == "image_1mb" else 0.5
    met = {"throughput_vs_zenoh": ratio is not None and ratio >= want}
    slower = (
        ours["latency_p50_ms"] / zen["latency_p50_ms"] if ours["latency_p50_ms"] and zen["latency_p50_ms"] else None
    )
    ours["latency_p50_vs_zenoh"] = round(slower, 2) if slower is not None else None
    if kind == "image_1mb":
        met["latency_p50_vs_zenoh"] = slower is not None and slower <= 1.5
    return met


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--role", default="main", choices=["main", "pub"])
    parser.add_argument("--impl", default="fleetslam")
    parser.add_argument("--kind", default="image_1mb")
    parser.add_argument("--endpoint", default="")
    parser.add_argument("--mode", default="throughput")
    parser.add_argument("--duration", type=float, default=1.5, help="seconds of one throughput trial")
    parser.add_argument("--trials", type=int, default=5, help="trials of each peer, interleaved (rounds)")
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--no-rclpy", action="store_true", help="skip the rclpy peer")
    parser.add_argument(
        "--layers",
        type=int,
        default=0,
        metavar="N",
        help="instead: thread CPU µs per message of each layer, N messages (1 MB: N/50), in this process",
    )
    parser.add_argument(
        "--payloads", default="image_1mb,string_64b,kinect", help="comma-separated subset of the default"
    )
    args = parser.parse_args()
    # Every process of the run (each peer's publisher, the subscribers here) runs with the allocator setting the
    # fleetslam command gives its nodes: the same for raw Zenoh's peer as for fleetslam's.
    keep_freed_memory()
    if args.role == "pub":
        copy_arrays = args.impl == COPY_IMPL
        run_publisher(args.impl, args.kind, args.endpoint, args.mode, args.duration, args.rate, copy_arrays)
        return
    if args.layers:
        wanted_layers = [k.strip() for k in args.payloads.split(",") if k.strip() in PAYLOADS]
        layer_rows = {
            k: measure_layers(k, args.layers if k == "string_64b" else max(1, args.layers // 50)) for k in wanted_layers
        }
        print(json.dumps({"benchmark": "middleware_layers", "us_per_msg_thread_cpu": layer_rows}))
        return

    results: dict[str, Any] = {
        "benchmark": "middleware_throughput",
        "machine": f"{platform.machine()} {os.cpu_count()} cores",
        "duration_s": args.duration,
        "trials": args.trials,
        "load_avg_1m_start": round(os.getloadavg()[0], 2),
    }
    wanted = [k.strip() for k in args.payloads.split(",") if k.strip()]
    rclpy_python, rclpy_reason = (None, "skipped (--no-rclpy)") if args.no_rclpy else ensure_rclpy_venv()
    for kind in (k for k in PAYLOADS if k in wanted):
        rate = 50.0 if kind == "image_1mb" else 200.0
        impls = IMPLS if kind == "string_64b" else IMAGE_IMPLS
        entry = measure_interleaved(kind, impls, args.trials, args.duration, rate)
        if rclpy_python is not None:
            print(f"[bench] {kind} rclpy ...", file=sys.stderr, flush=True)
            entry["rclpy"] = summarize(
                measure_rclpy(rclpy_python, kind, "throughput", args.duration, rate),
                measure_rclpy(rclpy_python, kind, "latency", min(args.duration, 2.0), rate),
            )
        else:
            entry["rclpy"] = {"msgs_per_s": None, "reason": rclpy_reason}
        ours = entry["fleetslam"]["msgs_per_s"]
        entry["ratio_vs_zenoh"] = _ratio(ours, entry["zenoh"]["msgs_per_s"])  # of the medians
        for impl in impls[1:-1]:  # the other fleetslam peers, noted beside the default
            name = impl.removeprefix("fleetslam_")
            entry[f"{name}_ratio_vs_zenoh"] = _ratio(entry[impl]["msgs_per_s"], entry["zenoh"]["msgs_per_s"])
        rclpy_rate = entry["rclpy"].get("msgs_per_s")
        entry["ratio_vs_rclpy"] = round(ours / rclpy_rate, 2) if rclpy_rate else None
        target_zenoh, target_rclpy = (0.8, 5.0) if kind == "image_1mb" else (0.5, 10.0)
        entry["targets"] = {"vs_zenoh": target_zenoh, "vs_rclpy": target_rclpy}
        entry["targets_met"] = check_targets(kind, entry)
        for impl in impls[1:-1]:
            entry[f"{impl.removeprefix('fleetslam_')}_targets_met"] = check_targets(kind, entry, impl)
        results[kind] = entry
    if "kinect" in wanted:
        results["kinect"] = measure_kinect(IMAGE_IMPLS, args.duration)
    results["all_targets_met"] = all(all(results[k]["targets_met"].values()) for k in PAYLOADS if k in results)
    results["load_avg_1m_end"] = round(os.getloadavg()[0], 2)
    print(json.dumps(results))


if __name__ == "__main__":
    main()
