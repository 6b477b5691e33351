"""Where services may write: a file name from a request, resolved inside one configured directory (pure).

A save service (``map/save``, ``slam/save_map``, ``/fleet/map/save``) takes its file name from the request, and the
request comes from anyone on the router. So the name must be a plain file name: no directories, no absolute path,
no ``..``, no hidden file, an expected suffix; and the file it names must not be a link (writing through a link
would land outside the directory). Anything else raises :class:`~fleetslam.errors.UnsafePathError` saying what is
wrong, and nothing is written.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from fleetslam.errors import UnsafePathError

_PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}")


def save_path(directory: str | Path, name: str, *, suffixes: Sequence[str]) -> Path:
    """``directory / name`` when ``name`` is a plain file name with one of ``suffixes`` (see the module docstring).

    The directory is created if missing. Raises UnsafePathError naming the request's value and the rule it breaks.
    """
    if not _PLAIN_NAME.fullmatch(name):
        raise UnsafePathError(
            f"save path {name!r} is not a plain file name (letters, digits, '_', '-', '.'; no directories, no '..', "
            f"at most 128 characters); files are written only inside the maps directory {str(directory)!r}"
        )
    if Path(name).suffix not in suffixes:
        raise UnsafePathError(f"save path {name!r} must end in {' or '.join(suffixes)}")
    root = Path(directory).expanduser()
    root.mkdir(parents=True, exist_ok=True)
    path = root / name
    if path.is_symlink():
        raise UnsafePathError(f"save path {name!r} is a link in {str(root)!r}; refusing to write through it")
    if path.resolve().parent != root.resolve():
        raise UnsafePathError(f"save path {name!r} resolves outside the maps directory {str(root)!r}")
    return path
