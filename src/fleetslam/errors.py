"""One exception hierarchy for fleetslam.

Every error raised by library code is a :class:`FleetslamError`. Messages name the file, field and value at
fault so that a user can fix the input without reading the code. Raise with ``from err`` when wrapping.
"""

from __future__ import annotations


class FleetslamError(Exception):
    """Base class of every fleetslam error."""

    exit_code: int = 1


class ConfigError(FleetslamError):
    """A configuration file, parameter or environment variable is invalid."""

    exit_code = 2


class MiddlewareError(FleetslamError):
    """The middleware (Zenoh session, names, types, services) failed."""


class RouterUnreachableError(MiddlewareError):
    """No Zenoh router answers at the configured endpoint."""

    exit_code = 3


class MessageError(MiddlewareError):
    """A message could not be serialized or deserialized, or its type is unknown."""


class ServiceError(MiddlewareError):
    """A service call failed or timed out."""


class DatasetError(FleetslamError):
    """A dataset (TUM folder, recording, simulator export) is missing or malformed."""


class MapFileError(FleetslamError):
    """An occupancy map file is corrupt, truncated or of an unsupported kind."""


class SimulationError(FleetslamError):
    """The simulator could not be built or stepped."""


class SlamError(FleetslamError):
    """The SLAM pipeline failed (tracking, database, optimisation)."""


class MissingExtraError(FleetslamError):
    """An optional dependency is not installed; the message names the extra to install."""

    def __init__(self, module: str, extra: str) -> None:
        super().__init__(
            f"the optional dependency '{module}' is not installed; install it with: pip install 'fleetslam[{extra}]'"
        )
        self.module = module
        self.extra = extra


class UnsafePathError(FleetslamError):
    """A file name given by a request (a service's save path) would leave its directory or is not a plain name."""


class FindingError(FleetslamError):
    """An inspection finding is invalid (a field's value) or unknown, or the findings file is malformed."""


def worth_logging(count: int) -> bool:
    """Whether the ``count``-th ignored bad input of one kind is logged: the 1st, 10th, 100th and every 1000th, so a
    hostile stream costs a node a bounded log, and its count still shows in the message."""
    return count in (1, 10, 100) or count % 1000 == 0
