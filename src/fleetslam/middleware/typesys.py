"""Moved to :mod:`fleetslam.msg.typesys` (usable without the middleware); this module re-exports it unchanged."""

from fleetslam.msg.typesys import *  # noqa: F403  (the names listed in its __all__)
from fleetslam.msg.typesys import __all__ as __all__
