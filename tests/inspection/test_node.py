"""The findings node over real Zenoh sessions: services, the latched topic, positions from the keyframes' poses."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from fleetslam import topics
from fleetslam.geometry import pose_from_xyz_rpy, transform_points
from fleetslam.inspection.findings import Finding
from fleetslam.inspection.node import (
    CREATE_SERVICE,
    CREATE_TYPE,
    UPDATE_SERVICE,
    UPDATE_TYPE,
    FindingsNode,
    finding_msg,
)
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import pose_msgs, transform_msg
from fleetslam.msg.typesys import get_type, header, message_from_dict

from ..support import wait_until

FINDING = Finding(
    id="", title="cracked weld", severity="medium", status="", note="", agent="c3po", keyframe_id=1,
    point=(0.2, -0.1, 2.0), pixel=(10.0, 20.0), stamp_ns=5_000_000_000, photo=b"\xff\xd8fake-but-tagged",
)  # fmt: skip


def _path(poses: list[np.ndarray]) -> Any:
    stamped = get_type("geometry_msgs/msg/PoseStamped")
    stamp = header("c3po/map", 1)
    return get_type("nav_msgs/msg/Path")(header=stamp, poses=[stamped(header=stamp, pose=p) for p in pose_msgs(poses)])


def test_findings_are_served_shared_and_follow_their_keyframe(
    make_context: Callable[..., Context], tmp_path: Path
) -> None:
    folder = tmp_path / "findings"
    keyframes = [pose_from_xyz_rpy(x, 0.0, 0.3, -np.pi / 2, 0.0, -np.pi / 2) for x in (0.0, 1.0, 2.0)]
    with FindingsNode(make_context(), folder, position_period_s=0.1) as findings:
        operator = Node("operator", context=make_context())
        create = operator.create_client(CREATE_TYPE, CREATE_SERVICE)
        update = operator.create_client(UPDATE_TYPE, UPDATE_SERVICE)
        request = get_type(f"{CREATE_TYPE}_Request")
        refused = create.call(request(finding=finding_msg(Finding(**{**FINDING.__dict__, "severity": "bad"}))), 10)
        assert not refused.success and "severity 'bad' is not one of" in refused.message
        answer = create.call(request(finding=finding_msg(FINDING)), 10)
        assert (answer.success, answer.id) == (True, "F001"), answer.message
        closed = update.call(
            message_from_dict(f"{UPDATE_TYPE}_Request", {"id": "F001", "status": "closed", "note": "ground off"}), 10
        )
        assert closed.success, closed.message

        # A console that starts now still gets every finding (latched), photo included.
        seen: list[Any] = []
        late = Node("late", context=make_context())
        late.create_subscription(topics.FINDINGS.type, topics.FINDINGS.name, seen.append, topics.FINDINGS.qos())
        assert wait_until(lambda: bool(seen) and len(seen[-1].findings) == 1, 10)
        got = seen[-1].findings[0]
        assert (got.id, got.status, got.note, bytes(got.photo)) == ("F001", "closed", "ground off", FINDING.photo)

        # The keyframes' poses arrive, then the agent is placed in the fleet frame: positions follow.
        robot = Node("slam", context=make_context("c3po"))
        path_pub = robot.create_publisher(topics.PATH.type, topics.PATH.name, topics.PATH.qos())
        placed = robot.create_publisher(
            topics.FLEET_TRANSFORM.type, topics.FLEET_TRANSFORM.name, topics.FLEET_TRANSFORM.qos()
        )
        expected = transform_points(keyframes[1], [FINDING.point])[0]

        def position() -> tuple[Any, Any]:
            document = json.loads((folder / "findings.json").read_text())
            entry = document["findings"][0]
            return entry["position"], entry["fleet_position"]

        assert wait_until(lambda: (path_pub.publish(_path(keyframes)), position()[0] is not None)[1], 10, 0.2)
        assert np.allclose(position()[0], expected, atol=1e-3)
        T_fleet_map = pose_from_xyz_rpy(5.0, -1.0, 0.0, 0.0, 0.0, 0.5)
        placed.publish(transform_msg(T_fleet_map, "fleet", "c3po/map", 1).transforms[0])
        assert wait_until(lambda: position()[1] is not None, 10)
        assert np.allclose(position()[1], transform_points(T_fleet_map, [expected])[0], atol=1e-3)
        # Re-optimised: keyframe 1 moved 0.4 m along y.
        moved = [k.copy() for k in keyframes]
        moved[1][1, 3] += 0.4
        path_pub.publish(_path(moved))
        assert wait_until(lambda: abs(position()[0][1] - expected[1] - 0.4) < 1e-3, 10)
        operator.destroy(), late.destroy(), robot.destroy()
        del findings
