"""A node's typed parameters: its ConfigModel, validated from a YAML file, ``key=value`` overrides and the
environment (see :func:`fleetslam.config.load_config`)."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from fleetslam.config import ConfigModel, load_config, read_yaml

log = logging.getLogger("fleetslam.middleware.node")


def load_parameters(
    model: type[ConfigModel] | None,
    path: str | Path | None,
    overrides: Sequence[str],
    *,
    node_name: str,
    fq_name: str,
) -> Any:
    """The node's parameters: ``model`` validated from ``path`` (the whole file, or its ``<node_name>`` key if
    that holds a mapping) and ``overrides``; None (with a warning if values were given) when the node declares
    no model."""
    if model is None:
        if overrides or path:
            log.warning("%s: parameters given but the node declares none; ignored", fq_name)
        return None
    section = None
    if path is not None:
        data = read_yaml(path)
        section = node_name if node_name in data and isinstance(data[node_name], dict) else None
    return load_config(model, path, overrides=list(overrides), section=section)
