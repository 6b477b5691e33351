"""The fleet's findings over the middleware: one node serves them to every console.

- ``/fleet/findings/create`` (``fleetslam_msgs/srv/CreateFinding``) records a finding and answers its id;
  ``/fleet/findings/update`` (``UpdateFinding``) changes its title, severity, status or note. A refusal says which
  field and value are at fault.
- ``/fleet/findings`` (latched, :data:`fleetslam.topics.FINDINGS`) carries every finding after each change, so a
  console that starts later sees them at once.
- Each finding's position is recomputed from its keyframe's current pose (the agent's ``path``) and the agent's
  placement in the fleet frame (``slam/fleet_transform``) and written with the findings (``findings.json``) in
  the run's directory, for the report.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from fleetslam import topics
from fleetslam.errors import FindingError
from fleetslam.inspection.findings import Finding, FindingStore, anchored_position
from fleetslam.middleware import Context, Node
from fleetslam.msg.conversions import pose_matrix, transform_matrix
from fleetslam.msg.typesys import get_type, header, ns_from_stamp

log = logging.getLogger(__name__)

__all__ = ["CREATE_SERVICE", "UPDATE_SERVICE", "FindingsNode", "finding_from_msg", "finding_msg"]

CREATE_SERVICE = "/fleet/findings/create"
UPDATE_SERVICE = "/fleet/findings/update"
CREATE_TYPE = "fleetslam_msgs/srv/CreateFinding"
UPDATE_TYPE = "fleetslam_msgs/srv/UpdateFinding"


def finding_msg(finding: Finding) -> Any:
    """A ``fleetslam_msgs/Finding`` of a finding."""
    point = get_type("geometry_msgs/msg/Point")
    return get_type("fleetslam_msgs/msg/Finding")(
        header=header("camera", finding.stamp_ns), id=finding.id, title=finding.title, severity=finding.severity,
        status=finding.status, note=finding.note, agent=finding.agent, keyframe_id=finding.keyframe_id,
        point=point(x=finding.point[0], y=finding.point[1], z=finding.point[2]), u=finding.pixel[0],
        v=finding.pixel[1], photo_format="jpeg" if finding.photo else "",
        photo=np.frombuffer(finding.photo, dtype=np.uint8), crop=np.frombuffer(finding.crop, dtype=np.uint8),
    )  # fmt: skip


def finding_from_msg(msg: Any) -> Finding:
    """The finding a ``fleetslam_msgs/Finding`` carries (not validated)."""
    return Finding(
        id=msg.id, title=msg.title, severity=msg.severity, status=msg.status, note=msg.note, agent=msg.agent,
        keyframe_id=int(msg.keyframe_id), point=(msg.point.x, msg.point.y, msg.point.z),
        pixel=(float(msg.u), float(msg.v)), stamp_ns=ns_from_stamp(msg.header.stamp),
        photo=bytes(np.asarray(msg.photo, dtype=np.uint8)), crop=bytes(np.asarray(msg.crop, dtype=np.uint8)),
    )  # fmt: skip


class FindingsNode:
    """Serves, publishes and persists the fleet's findings (in ``directory``; None: in memory only)."""

    def __init__(self, context: Context, directory: Path | None = None, *, position_period_s: float = 2.0) -> None:
        self.store = FindingStore.load(directory) if directory is not None else FindingStore()
        self.node = Node("findings", context=context, namespace="/")
        self._lock = threading.Lock()
        self._keyframes: dict[str, list[NDArray[np.float64]]] = {}
        """Per agent, its keyframes' current poses (its ``path``, in id order)."""
        self._placements: dict[str, NDArray[np.float64]] = {}
        """Per agent, ``T_fleet_map`` once its SLAM placed it in the fleet frame."""
        self._watched: set[str] = set()
        self._positions_changed = False
        self._publisher = self.node.create_publisher(topics.FINDINGS.type, topics.FINDINGS.name, topics.FINDINGS.qos())
        self.node.create_service(CREATE_TYPE, CREATE_SERVICE, self._on_create)
        self.node.create_service(UPDATE_TYPE, UPDATE_SERVICE, self._on_update)
        self.node.create_timer(position_period_s, self._refresh_positions)
        for finding in self.store.findings:
            self._watch(finding.agent)
        self._publish()

    def close(self) -> None:
        """Write the findings with their latest positions, then leave the fleet."""
        self._refresh_positions()
        with self._lock:
            self.store.save()
        self.node.destroy()

    def __enter__(self) -> FindingsNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- services ------------------------------------------------------------------------------------------------
    def _on_create(self, request: Any) -> Any:
        response = get_type(f"{CREATE_TYPE}_Response")
        try:
            draft = replace(finding_from_msg(request.finding), status=request.finding.status or "open")
            with self._lock:
                finding = self.store.create(draft)
        except (FindingError, OSError) as err:
            log.warning("finding refused: %s", err)
            return response(success=False, message=str(err), id="")
        log.info("finding %s (%s) by %s", finding.id, finding.severity, finding.agent)
        self._watch(finding.agent)
        with self._lock:
            self._positions_changed = True
        self._refresh_positions()
        self._publish()
        return response(success=True, message=f"finding {finding.id} recorded", id=finding.id)

    def _on_update(self, request: Any) -> Any:
        response = get_type(f"{UPDATE_TYPE}_Response")
        try:
            with self._lock:
                finding = self.store.update(
                    request.id, title=request.title or None, severity=request.severity or None,
                    status=request.status or None, note=request.note or None,
                )  # fmt: skip
        except (FindingError, OSError) as err:
            return response(success=False, message=str(err))
        self._publish()
        return response(success=True, message=f"finding {finding.id} is {finding.status}")

    def _publish(self) -> None:
        with self._lock:
            findings = [finding_msg(f) for f in self.store.findings]
        array = get_type(topics.FINDINGS.type)(header=header("fleet", self.node.now_ns()), findings=findings)
        self._publisher.publish(array)

    # -- positions -----------------------------------------------------------------------------------------------
    def _watch(self, agent: str) -> None:
        if agent in self._watched:
            return
        self._watched.add(agent)
        path, placement = topics.PATH, topics.FLEET_TRANSFORM
        self.node.create_subscription(path.type, path.of(agent), lambda m: self._on_path(agent, m), path.qos(depth=1))
        self.node.create_subscription(
            placement.type, placement.of(agent), lambda m: self._on_placement(agent, m), placement.qos(depth=1)
        )

    def _on_path(self, agent: str, msg: Any) -> None:
        with self._lock:
            self._keyframes[agent] = [pose_matrix(s.pose) for s in msg.poses]
            self._positions_changed = True

    def _on_placement(self, agent: str, msg: Any) -> None:
        with self._lock:
            self._placements[agent] = transform_matrix(msg.transform)
            self._positions_changed = True

    def positions(self) -> dict[str, tuple[NDArray[np.float64], NDArray[np.float64] | None]]:
        """Each finding's current position: in its agent's map frame and in the fleet frame (None: not placed);
        findings whose keyframe is not known (yet) are left out."""
        out: dict[str, tuple[NDArray[np.float64], NDArray[np.float64] | None]] = {}
        with self._lock:
            for finding in self.store.findings:
                keyframes = self._keyframes.get(finding.agent, [])
                if finding.keyframe_id >= len(keyframes):
                    continue
                in_map = anchored_position(finding.point, keyframes[finding.keyframe_id])
                placement = self._placements.get(finding.agent)
                out[finding.id] = (in_map, None if placement is None else anchored_position(in_map, placement))
        return out

    def _refresh_positions(self) -> None:
        with self._lock:
            if not self._positions_changed:
                return
            self._positions_changed = False
        positions = self.positions()
        with self._lock:
            if self.store.set_positions(positions):
                try:
                    self.store.save()
                except OSError as err:
                    log.warning("findings not saved: %s", err)
