"""Launching a fleet: the fleet description (YAML), the process supervisor, the Zenoh router process and
network namespaces for multi-host tests.

Names are loaded on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleetslam._imports import lazy_exports

if TYPE_CHECKING:
    from fleetslam.launch.description import FleetDescription, ProcessSpec, RestartPolicy, load_fleet, resolve_processes
    from fleetslam.launch.netns import VirtualNetwork, netns_available
    from fleetslam.launch.router_process import RouterProcess
    from fleetslam.launch.supervisor import Supervisor

__all__ = [
    "FleetDescription",
    "ProcessSpec",
    "RestartPolicy",
    "RouterProcess",
    "Supervisor",
    "VirtualNetwork",
    "load_fleet",
    "netns_available",
    "resolve_processes",
]

# Hidden from type checkers, so that a misspelt name is an error there rather than Any.
if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(
        __name__,
        {
            "description": ["FleetDescription", "ProcessSpec", "RestartPolicy", "load_fleet", "resolve_processes"],
            "supervisor": ["Supervisor"],
            "router_process": ["RouterProcess"],
            "netns": ["VirtualNetwork", "netns_available"],
        },
    )
