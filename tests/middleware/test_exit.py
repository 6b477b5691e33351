"""A program that exits with contexts still open exits cleanly: no hang, no abort inside Zenoh's native code,
and no context closed under a thread that still uses it.

Without the exit hooks a main-thread context with a subscription keeps the interpreter waiting for its callback
thread forever, and a context owned by a busy daemon thread is torn down mid-callback at finalization, which
aborts the process ("FATAL: exception not rethrown", exit 134), as a test process running the demo did.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from ..support import free_port

PROGRAM = textwrap.dedent(
    """
    import sys, threading, time
    from fleetslam.middleware import Context, Node, QoSProfile, Router
    from fleetslam.msg.typesys import get_type

    endpoint = f"tcp/127.0.0.1:{sys.argv[1]}"
    router = Router([endpoint])  # never closed either
    String = get_type("std_msgs/msg/String")
    received = []

    def busy_node(ctx):
        node = Node("busy", context=ctx, statistics_period_s=0)
        node.create_subscription("std_msgs/msg/String", "/chatter", lambda m: (received.append(m), time.sleep(1e-3)),
                                 QoSProfile(depth=10))
        return node.create_publisher("std_msgs/msg/String", "/chatter")

    main_ctx = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={})
    busy_node(main_ctx).publish(String(data="hello"))

    def daemon_owner():
        ctx = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={})
        publisher = busy_node(ctx)
        while not ctx.closed:
            try:
                publisher.publish(String(data="x" * 100))
            except Exception:
                return
            time.sleep(5e-4)

    threading.Thread(target=daemon_owner, daemon=True).start()
    deadline = time.monotonic() + 20
    while len(received) < 200 and time.monotonic() < deadline:
        time.sleep(0.01)
    print("received", len(received), flush=True)
    """
)


def test_open_contexts_close_at_exit() -> None:
    # The abort is a race, so a few runs; each must end by itself, with status 0.
    for _ in range(3):
        done = subprocess.run(
            [sys.executable, "-c", PROGRAM, str(free_port())], capture_output=True, text=True, timeout=30
        )
        assert done.returncode == 0, done.stderr[-2000:]
        assert int(done.stdout.split()[-1]) >= 200, done.stdout


WORKER_PROGRAM = textwrap.dedent(
    """
    import sys, threading, time
    from fleetslam.middleware import Context, Node, QoSProfile, Router
    from fleetslam.msg.typesys import get_type

    endpoint = f"tcp/127.0.0.1:{sys.argv[1]}"
    router = Router([endpoint])
    ctx = Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={})
    node = Node("worker", context=ctx, statistics_period_s=0)
    received = []
    node.create_subscription("std_msgs/msg/String", "/work", received.append, QoSProfile(depth=100))
    publisher = node.create_publisher("std_msgs/msg/String", "/work")
    main_done = threading.Event()

    def worker():  # a non-daemon thread that goes on using the context after the main thread has returned
        main_done.wait()
        time.sleep(0.5)
        for i in range(20):
            publisher.publish(get_type("std_msgs/msg/String")(data=str(i)))
            time.sleep(0.01)
        deadline = time.monotonic() + 10
        while len(received) < 20 and time.monotonic() < deadline:
            time.sleep(0.01)
        print("worker received", len(received), flush=True)
        ctx.close()

    threading.Thread(target=worker).start()
    main_done.set()
    """
)


def test_exit_waits_for_threads_that_still_use_a_context() -> None:
    done = subprocess.run(
        [sys.executable, "-c", WORKER_PROGRAM, str(free_port())], capture_output=True, text=True, timeout=30
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["worker", "received", "20"], done.stdout + done.stderr[-2000:]


SLOW_CALLBACK_PROGRAM = textwrap.dedent(
    """
    import sys, threading, time
    from pathlib import Path
    from fleetslam.middleware import Context, Node, Router

    endpoint = f"tcp/127.0.0.1:{sys.argv[1]}"
    marker = Path(sys.argv[2])
    router = Router([endpoint])
    started = threading.Event()

    def slow_callback():  # longer than the executor's 2 s join when the node is destroyed
        started.set()
        time.sleep(3.0)
        marker.write_text("finished")

    with Context(router=endpoint, listen="tcp/127.0.0.1:0", environ={}) as ctx:
        node = Node("slow", context=ctx, statistics_period_s=0)
        timer = node.create_timer(0.05, slow_callback)
        started.wait(10)
        timer.cancel()
    """
)


def test_exit_waits_for_a_callback_still_running(tmp_path: Path) -> None:
    # A daemon executor still inside a callback when the interpreter finalizes is killed mid-call (inside Zenoh's
    # native code that aborts the process); the exit waits for it instead.
    marker = tmp_path / "finished"
    done = subprocess.run(
        [sys.executable, "-c", SLOW_CALLBACK_PROGRAM, str(free_port()), str(marker)],
        capture_output=True, text=True, timeout=30,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert marker.exists() and marker.read_text() == "finished"
