"""The layering rule, read from the source with ``ast``: algorithms do not import the middleware.

Only node modules (``node.py``, ``*_node.py``), the station, the launcher, the CLI and the ROS 1 bridge may import
``fleetslam.middleware``; the algorithm packages stay pure, testable offline with arrays in and arrays out.
"""

from __future__ import annotations

import ast
from pathlib import Path

import fleetslam

ROOT = Path(fleetslam.__file__).parent
MIDDLEWARE = "fleetslam.middleware"
#: Packages and modules (relative to src/fleetslam) that must not import the middleware, node modules excepted.
PURE = (
    "slam",
    "mapping",
    "fusion",
    "robot",
    "sim",
    "datasets",
    "drivers",
    "eval",
    "inspection",
    "msg",
    "geometry.py",
    "trajectory.py",
)
#: Those that may: besides node modules anywhere. ``topics.py`` holds the topic contracts that node modules share;
#: its ``Topic.qos`` builds the middleware's QoSProfile (imported there, on first use).
ALLOWED = ("middleware", "station", "launch", "cli", "ros1", "topics.py")


def imported_modules(source: str, module: str, *, is_package: bool = False) -> set[str]:
    """Absolute names of the modules that ``source`` (the text of ``module``) imports, anywhere in it (inside
    functions and ``TYPE_CHECKING`` blocks too); relative imports resolved, ``from a import b`` giving ``a.b``."""
    package = module if is_package else module.rpartition(".")[0]
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*parent, base] if base else parent)
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _is_node_module(path: Path) -> bool:
    return path.stem == "node" or path.stem.endswith("_node")


def middleware_importers() -> dict[str, set[str]]:
    """Source file (relative to src/fleetslam) → the middleware modules it imports."""
    found = {}
    for path in sorted(ROOT.rglob("*.py")):
        names = imported_modules(path.read_text(), _module_name(path), is_package=path.name == "__init__.py")
        hits = {n for n in names if n == MIDDLEWARE or n.startswith(MIDDLEWARE + ".")}
        if hits:
            found[path.relative_to(ROOT).as_posix()] = hits
    return found


def test_algorithms_do_not_import_the_middleware() -> None:
    offenders = {
        where: names
        for where, names in middleware_importers().items()
        if where.split("/")[0] in PURE and not _is_node_module(ROOT / where)
    }
    assert not offenders, f"algorithm modules import the middleware (move the code into a node module): {offenders}"


def test_only_node_modules_and_front_ends_import_the_middleware() -> None:
    offenders = {
        where: names
        for where, names in middleware_importers().items()
        if where.split("/")[0] not in ALLOWED and not _is_node_module(ROOT / where)
    }
    assert not offenders, f"only node modules, {', '.join(ALLOWED)} may import the middleware: {offenders}"


def test_the_scan_sees_the_known_importers() -> None:
    """The scan finds the node modules that do import the middleware, so a test passing is not a scan finding
    nothing."""
    importers = middleware_importers()
    for where in ("slam/node.py", "mapping/node.py", "fusion/node.py", "sim/node.py", "robot/node.py"):
        assert where in importers, where
    assert "geometry.py" not in importers


def test_the_scan_reads_every_import_form() -> None:
    source = """
from typing import TYPE_CHECKING
import fleetslam.middleware.node
from fleetslam import middleware
from ..middleware import wire
if TYPE_CHECKING:
    from fleetslam.middleware.context import Context
def later():
    from .sibling import thing
"""
    names = imported_modules(source, "fleetslam.slam.odometry")
    assert {
        "fleetslam.middleware.node",
        "fleetslam.middleware",
        "fleetslam.middleware.wire",
        "fleetslam.middleware.context",
        "fleetslam.slam.sibling",
    } <= names
    assert "fleetslam.middleware" in imported_modules("from .. import middleware", "fleetslam.slam", is_package=True)
