import io
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from fleetslam.errors import ConfigError
from fleetslam.launch.description import (
    FleetDescription,
    ProcessSpec,
    RestartPolicy,
    format_host_instructions,
    load_fleet,
    resolve_processes,
)
from fleetslam.launch.supervisor import Supervisor, sample_process

from ..support import wait_until

FLEET = """
router: {endpoint: "tcp/10.1.2.2:7447", host: base}
domain_id: 3
environment: {FLEETSLAM_LOG_LEVEL: info}
agents:
  - name: c3po
    host: c3po
    listen: tcp/10.1.2.10:0
    nodes:
      - name: slam
        command: [slam, node]
        parameters: {odometry.max_features: 800}
        remaps: {odom: /c3po/wheel_odom}
  - name: r2d2
    host: r2d2
    nodes:
      - {name: sim, exec: [my_driver, --fast], environment: {EXTRA: "1"}}
hosts_nodes:
  - {name: station, host: base, command: [station, --port, "8080"]}
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "fleet.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def test_resolve_sets_environment_and_ros_args(tmp_path: Path) -> None:
    fleet = load_fleet(_write(tmp_path, FLEET))
    procs = {p.label: p for p in resolve_processes(fleet, python="py")}
    assert list(procs) == ["router", "c3po/slam", "r2d2/sim", "station"]
    slam = procs["c3po/slam"]
    assert slam.host == "c3po"
    assert slam.environment["FLEETSLAM_AGENT"] == "c3po"
    assert slam.environment["FLEETSLAM_ROUTER"] == "tcp/10.1.2.2:7447"
    assert slam.environment["FLEETSLAM_LISTEN"] == "tcp/10.1.2.10:0"
    assert slam.environment["ROS_DOMAIN_ID"] == "3"
    assert slam.environment["FLEETSLAM_LOG_LEVEL"] == "info"
    assert slam.argv == [
        "py", "-m", "fleetslam.cli.main", "slam", "node",
        "--ros-args", "-p", "odometry.max_features:=800", "-r", "odom:=/c3po/wheel_odom",
    ]  # fmt: skip
    sim = procs["r2d2/sim"]
    assert sim.argv == ["my_driver", "--fast"]
    assert sim.environment["EXTRA"] == "1" and sim.environment["FLEETSLAM_AGENT"] == "r2d2"
    assert "FLEETSLAM_AGENT" not in procs["station"].environment
    assert procs["router"].host == "base"


def test_a_secured_fleet_runs_every_process_with_the_keystore(tmp_path: Path) -> None:
    secured = FLEET.replace('endpoint: "tcp/10.1.2.2:7447"', 'endpoint: "tls/base:7447"') + "security: /etc/keys\n"
    procs = {p.label: p for p in resolve_processes(load_fleet(_write(tmp_path, secured)), python="py")}
    assert procs["router"].argv == ["py", "-m", "fleetslam.cli.main", "router", "--security", "/etc/keys"]
    for label in ("c3po/slam", "r2d2/sim", "station"):
        assert procs[label].environment["FLEETSLAM_SECURITY"] == "/etc/keys"
    assert procs["station"].environment["FLEETSLAM_IDENTITY"] == "station"
    assert "FLEETSLAM_IDENTITY" not in procs["c3po/slam"].environment  # an agent acts as itself
    with pytest.raises(ConfigError, match=r"router.endpoint must be tls/"):
        load_fleet(_write(tmp_path, FLEET + "security: /etc/keys\n"))


def test_print_hosts_groups_by_host(tmp_path: Path) -> None:
    text = format_host_instructions(load_fleet(_write(tmp_path, FLEET)))
    assert "# host base" in text and "# host c3po" in text and "# host r2d2" in text
    c3po = text.split("# host c3po")[1].split("# host")[0]
    assert "FLEETSLAM_AGENT=c3po" in c3po
    assert "FLEETSLAM_ROUTER=tcp/10.1.2.2:7447" in c3po
    assert "fleetslam slam node --ros-args" in c3po


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("agents: [{name: '9bad', nodes: []}]", r"fleet.yaml: key 'agents.0.name' = '9bad'"),
        ("agents: [{name: a, nodes: [{name: n}]}]", "give exactly one of 'command'"),
        ("agents: [{name: a}, {name: a}]", r"agent names must be unique, repeated: \['a'\]"),
        ("domain_id: -1", r"key 'domain_id' = -1"),
        ("agentz: []", r"key 'agentz' = \[\]: Extra inputs are not permitted"),
    ],
)
def test_validation_errors_name_file_key_value(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        load_fleet(_write(tmp_path, text))


def _py(code: str) -> list[str]:
    return [sys.executable, "-c", code]


def test_supervisor_prefixes_output_and_restarts_with_backoff() -> None:
    out = io.StringIO()
    crash = ProcessSpec(
        label="c3po/crashy",
        host="localhost",
        argv=_py("import sys; print('boom', flush=True); sys.exit(3)"),
        environment={},
        restart=RestartPolicy(initial_backoff_s=0.1, max_backoff_s=0.4, max_restarts=3),
    )
    ok = ProcessSpec(
        label="r2d2/once",
        host="localhost",
        argv=_py("import os; print('agent', os.environ['MARK'])"),
        environment={"MARK": "r2d2"},
        restart=RestartPolicy(),
    )
    supervisor = Supervisor([crash, ok], output=out, grace_s=1.0)
    start = time.monotonic()
    supervisor.run(poll_interval_s=0.02)
    elapsed = time.monotonic() - start
    text = out.getvalue()
    assert "[r2d2/once] agent r2d2" in text
    assert text.count("[c3po/crashy] boom") == 4  # first run + 3 restarts
    assert "[c3po/crashy] gave up after 3 restarts" in text
    status = supervisor.status()
    assert status["c3po/crashy"]["exit_codes"] == [3, 3, 3, 3]
    assert status["r2d2/once"]["exit_codes"] == [0]
    assert elapsed >= 0.1 + 0.2 + 0.4  # back-off doubled and capped


def test_supervisor_starts_a_process_at_its_niceness() -> None:
    out = io.StringIO()
    specs = [
        ProcessSpec(label=f"n{n}", host="localhost", argv=_py("import os; print('niceness', os.nice(0))"),
                    environment={}, restart=RestartPolicy(), niceness=n)
        for n in (0, 7)
    ]  # fmt: skip
    Supervisor(specs, output=out, grace_s=1.0).run(poll_interval_s=0.02)
    base = os.nice(0)
    assert f"[n0] niceness {base}" in out.getvalue()
    assert f"[n7] niceness {min(base + 7, 19)}" in out.getvalue()


def test_launch_cli_stops_children_on_ctrl_c(tmp_path: Path) -> None:
    marker = tmp_path / "child.pid"
    child = f"import os, time; open({str(marker)!r}, 'w').write(str(os.getpid())); time.sleep(60)"
    fleet = f"""
    router: {{embedded: false}}
    agents:
      - name: c3po
        nodes:
          - name: sleeper
            exec: [{sys.executable!r}, -c, {child!r}]
    """
    path = _write(tmp_path, fleet)
    proc = subprocess.Popen(
        [sys.executable, "-m", "fleetslam.cli.main", "launch", str(path), "--grace", "2"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    deadline = time.monotonic() + 20
    while not marker.exists() or not marker.read_text():
        assert time.monotonic() < deadline, "child never started"
        time.sleep(0.05)
    child_pid = int(marker.read_text())
    proc.send_signal(signal.SIGINT)
    output, _ = proc.communicate(timeout=20)
    assert proc.returncode == 0, output
    assert "[c3po/sleeper] started" in output
    with pytest.raises(ProcessLookupError):
        os.kill(child_pid, 0)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's prctl")
def test_children_end_when_the_launcher_is_killed(tmp_path: Path) -> None:
    """SIGKILL leaves the launcher no chance to stop its children; they are in their own process groups, so
    only the parent-death signal ends them."""
    marker = tmp_path / "child.pid"
    child = f"import os, time; open({str(marker)!r}, 'w').write(str(os.getpid())); time.sleep(60)"
    launcher = textwrap.dedent(f"""
        import sys
        from fleetslam.launch.description import ProcessSpec, RestartPolicy
        from fleetslam.launch.supervisor import Supervisor
        spec = ProcessSpec(label="c3po/sleeper", host="localhost", argv=[sys.executable, "-c", {child!r}],
                           environment={{}}, restart=RestartPolicy())
        Supervisor([spec], output=sys.stdout).run()
    """)
    proc = subprocess.Popen([sys.executable, "-c", launcher], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 20
    while not marker.exists() or not marker.read_text():
        assert time.monotonic() < deadline, "child never started"
        time.sleep(0.05)
    child_pid = int(marker.read_text())
    proc.kill()
    proc.wait(timeout=10)
    deadline = time.monotonic() + 10
    while not _gone(child_pid):
        if time.monotonic() > deadline:
            os.kill(child_pid, signal.SIGKILL)
            pytest.fail("the child outlived its killed launcher")
        time.sleep(0.05)


def _gone(pid: int) -> bool:
    """The process has ended: no such process, or a zombie that init has not reaped yet."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return True
    return stat.rsplit(")", 1)[-1].split()[0] in ("Z", "X")


def test_empty_fleet_is_valid() -> None:
    assert FleetDescription().agents == []


TICKS = os.sysconf("SC_CLK_TCK")
#: A child that uses ``cpu_s`` of CPU time (its own clock: the same amount however loaded the machine is), holds
#: ``mib`` MiB of written memory, then waits to be stopped.
_BURNER = """
import sys, time
cpu_s, mib = float(sys.argv[1]), int(sys.argv[2])
held = b"x" * (mib << 20)  # written, so resident
while time.process_time() < cpu_s:
    pass
print("burnt", flush=True)
time.sleep(60)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="usage is read from Linux's /proc")
def test_supervisor_reports_cpu_and_peak_memory_of_its_children() -> None:
    out = io.StringIO()
    burner = ProcessSpec(label="c3po/burner", host="localhost", argv=[*_py(_BURNER), "0.6", "120"], environment={},
                         restart=RestartPolicy())  # fmt: skip
    idle = ProcessSpec(label="r2d2/idle", host="localhost", argv=_py("import time; time.sleep(60)"), environment={},
                       restart=RestartPolicy())  # fmt: skip
    supervisor = Supervisor([burner, idle], output=out, grace_s=1.0)
    thread = threading.Thread(target=supervisor.run, kwargs={"poll_interval_s": 0.05}, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: "[c3po/burner] burnt" in out.getvalue(), 30.0), out.getvalue()
        time.sleep(0.3)
        usage = {u.label: u for u in supervisor.usage()}
    finally:
        supervisor.stop()
        thread.join(10)
    hot, cold = usage["c3po/burner"], usage["r2d2/idle"]
    assert hot.pid is not None and cold.pid is not None and hot.restarts == 0
    # The loop ran until the process had used 0.6 s (its start included); /proc counts whole clock ticks (1/100 s
    # on Linux) for user and system time apiece, truncated: up to two ticks fewer. Its sleep costs nothing.
    assert 0.6 - 2 / TICKS <= hot.cpu_s < 1.0, hot
    assert hot.wall_s >= hot.cpu_s - 0.05  # one thread cannot use more CPU than time passed
    assert 0.0 < hot.cpu_percent <= 105.0, hot
    assert cold.cpu_s < 0.6 and cold.cpu_percent < hot.cpu_percent, (cold, hot)
    # The burner held 120 MiB of bytes on top of the interpreter (~10 MiB); the sleeper only the interpreter.
    assert 120 <= hot.peak_rss_mib < 400, hot
    assert 1 < cold.peak_rss_mib < 100, cold
    assert hot.as_dict()["label"] == "c3po/burner" and hot.as_dict()["cpu_percent"] == round(hot.cpu_percent, 2)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="usage is read from Linux's /proc")
def test_supervisor_usage_counts_every_run_of_a_restarted_process() -> None:
    crash = ProcessSpec(
        label="c3po/crashy",
        host="localhost",
        argv=_py("import sys, time\nwhile time.process_time() < 0.3: pass\ntime.sleep(0.5)\nsys.exit(3)"),
        environment={},
        restart=RestartPolicy(initial_backoff_s=0.1, max_restarts=1),
    )
    supervisor = Supervisor([crash], output=io.StringIO(), grace_s=1.0)
    supervisor.run(poll_interval_s=0.02)  # returns once it gave up: two runs
    (usage,) = supervisor.usage()
    assert supervisor.status()["c3po/crashy"]["exit_codes"] == [3, 3]
    # Each run used 0.3 s of CPU (start included) and slept 0.5 s; its final figures are read when it has exited,
    # before it is reaped, so both runs count in full (less up to two truncated clock ticks each, as above).
    assert usage.restarts == 1
    # Wall time too is read in clock ticks: two runs of at least 0.8 s read 1.5999999999985 in a clean-clone run.
    assert 0.6 - 4 / TICKS <= usage.cpu_s < 1.0 and usage.wall_s >= 1.6 - 2 / TICKS, usage


def test_sample_process_reads_proc_stat_and_status(tmp_path: Path) -> None:
    """Fields counted after the command name's last ')' (a name may hold spaces and parentheses)."""
    ticks = TICKS
    (tmp_path / "42").mkdir()
    # state ppid pgrp session tty tpgid flags minflt cminflt majflt cmajflt | utime stime cutime cstime | priority
    # nice num_threads itrealvalue | starttime (proc(5) fields 3-22)
    fields = ["S", "1", "42", "42", "0", "-1", "4194560", "100", "0", "0", "0",
              str(3 * ticks), str(ticks), str(ticks // 2), str(ticks // 2),
              "20", "0", "5", "0", str(100 * ticks)]  # fmt: skip
    (tmp_path / "42" / "stat").write_text("42 (my (odd) name) " + " ".join(fields) + " 0 0\n")
    (tmp_path / "42" / "status").write_text("Name:\tx\nVmHWM:\t  204800 kB\nVmRSS:\t  1024 kB\n")
    (tmp_path / "uptime").write_text("130.00 200.00\n")
    sample = sample_process(42, proc=tmp_path)
    assert sample is not None
    assert sample.cpu_s == pytest.approx(5.0)  # user 3 + system 1 + waited-for children 0.5 + 0.5
    assert sample.wall_s == pytest.approx(30.0)  # up 130 s, started at 100 s
    assert sample.peak_rss_mib == pytest.approx(200.0)
    assert sample_process(43, proc=tmp_path) is None
