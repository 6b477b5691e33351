"""The public API: every subpackage documents itself and exports its names in ``__all__``; importing a package
loads no heavy extra; a missing extra fails with MissingExtraError naming what to install."""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import re
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path
from types import ModuleType

import pytest

import fleetslam
from fleetslam._imports import DISTRIBUTIONS, require
from fleetslam.errors import MissingExtraError

ROOT = Path(fleetslam.__file__).parent
PACKAGES = sorted(m.name for m in pkgutil.walk_packages(fleetslam.__path__, "fleetslam.") if m.ispkg)
#: Optional dependencies (import names) that no package may load when it is imported.
HEAVY = ("numba", "llvmlite", "cv2", "gtsam", "mujoco", "evo", "matplotlib", "pygame", "aiohttp")


def _package(name: str) -> ModuleType:
    return importlib.import_module(name)


def test_every_subpackage_is_found() -> None:
    assert {"fleetslam.mapping", "fleetslam.slam", "fleetslam.middleware", "fleetslam.cli"} <= set(PACKAGES)
    on_disk = {f"fleetslam.{p.parent.name}" for p in ROOT.glob("*/__init__.py")}
    assert on_disk == set(PACKAGES)


SHARED_CORE = {"fleetslam.intrinsics", "fleetslam.geometry", "fleetslam.trajectory", "fleetslam.errors"}
"""Top-level modules every package builds on; a package may re-export their names."""


@pytest.mark.parametrize("name", PACKAGES)
def test_package_documents_and_exports(name: str) -> None:
    package = _package(name)
    assert package.__doc__ and package.__doc__.strip(), f"{name} has no module docstring"
    exported = package.__dict__.get("__all__")
    assert isinstance(exported, list) and all(isinstance(n, str) for n in exported), f"{name} has no __all__ list"
    assert len(exported) == len(set(exported)), f"{name}.__all__ has duplicates"
    listing = dir(package)
    for symbol in exported:
        value = getattr(package, symbol)
        assert symbol in listing, f"{name}.{symbol} is missing from dir()"
        assert not isinstance(value, ModuleType), f"{name}.{symbol} is a module, not a public name"
        if inspect.isclass(value) or inspect.isfunction(value):
            # A package exports its own names, and may re-export the shared core's (fleetslam.intrinsics, ...).
            own = value.__module__.startswith(f"{name}.")
            shared_core = value.__module__ in SHARED_CORE
            assert own or shared_core, f"{name}.{symbol} comes from {value.__module__}"
            assert inspect.getdoc(value), f"{name}.{symbol} has no docstring"
    namespace: dict[str, object] = {}
    exec(f"from {name} import *", namespace)
    assert set(exported) <= set(namespace)


@pytest.mark.parametrize("name", PACKAGES)
def test_exports_survive_importing_every_submodule(name: str) -> None:
    """A public name equal to a submodule's name would be replaced by that submodule once it is imported."""
    package = _package(name)
    for info in pkgutil.iter_modules(package.__path__, f"{name}."):
        if not info.ispkg:
            importlib.import_module(info.name)
    for symbol in package.__all__:
        assert not isinstance(getattr(package, symbol), ModuleType), f"{name}.{symbol} is shadowed by a submodule"


@pytest.mark.parametrize("name", PACKAGES)
def test_exports_are_visible_to_type_checkers(name: str) -> None:
    """Every name in ``__all__`` is bound by an import in ``__init__.py`` (under TYPE_CHECKING for the lazy
    packages), so mypy sees its real type, and every name imported there from the package is exported."""
    init = ROOT / name.split(".", 1)[1] / "__init__.py"
    imported = {
        alias.asname or alias.name
        for node in ast.walk(ast.parse(init.read_text()))
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith(f"{name}.")
        for alias in node.names
    }
    assert imported == set(_package(name).__all__)


def test_lazy_exports_import_on_first_use() -> None:
    code = """
        import sys
        import fleetslam.mapping as mapping
        assert "fleetslam.mapping.octree" not in sys.modules and "numba" not in sys.modules
        assert "OccupancyOctree" in dir(mapping)
        from fleetslam.mapping import OccupancyOctree
        from fleetslam.mapping.octree import OccupancyOctree as direct
        assert OccupancyOctree is direct and "numba" in sys.modules
        try:
            mapping.NoSuchName
        except AttributeError as err:
            assert "NoSuchName" in str(err)
        else:
            raise AssertionError("an unknown name did not raise AttributeError")
    """
    _run(code)


def test_importing_a_package_loads_no_heavy_extra_and_no_zenoh() -> None:
    """With every heavy extra (and Zenoh) made unimportable, every package but the middleware still imports and
    lists its names; the middleware is Zenoh itself, so only the heavy extras are blocked for it."""
    others = [p for p in PACKAGES if p != "fleetslam.middleware"]
    code = f"""
        import importlib, sys
        for blocked in {(*HEAVY, "zenoh")!r}:
            sys.modules[blocked] = None
        for name in {others!r}:
            package = importlib.import_module(name)
            assert set(package.__all__) <= set(dir(package)), name
        sys.modules.pop("zenoh")
        import fleetslam.middleware
        assert all(sys.modules.get(m) is None for m in {HEAVY!r})
    """
    _run(code)


#: Each heavy extra blocked in turn: the public call that needs it, and the module and extra its error names.
MISSING = [
    ("numba", "from fleetslam.mapping import OccupancyOctree", "numba", "mapping"),
    ("numba", "from fleetslam.fusion import FleetMap", "numba", "mapping"),
    ("cv2", "from fleetslam.slam import FeatureExtractor; FeatureExtractor()", "opencv-python-headless", "slam"),
    ("gtsam", "from fleetslam.slam import PoseGraph; PoseGraph()", "gtsam", "slam"),
    ("mujoco", "from fleetslam.sim import Plant; Plant()", "mujoco", "sim"),
    ("evo", "from fleetslam.eval import ape; ape(None, None)", "evo", "eval"),
]


@pytest.mark.parametrize(("blocked", "call", "module", "extra"), MISSING)
def test_missing_extra_names_what_to_install(blocked: str, call: str, module: str, extra: str) -> None:
    code = f"""
        import sys
        sys.modules[{blocked!r}] = None
        from fleetslam.errors import MissingExtraError
        try:
            {call}
        except MissingExtraError as err:
            assert (err.module, err.extra) == ({module!r}, {extra!r}), (err.module, err.extra)
            assert "pip install 'fleetslam[{extra}]'" in str(err), str(err)
        else:
            raise AssertionError("no MissingExtraError")
    """
    _run(code)


def test_require_imports_or_names_the_extra() -> None:
    assert require("json", "slam") is sys.modules["json"]
    with pytest.raises(MissingExtraError, match=r"'fleetslam_no_such_module'.*fleetslam\[sim\]") as caught:
        require("fleetslam_no_such_module.sub", "sim")
    assert isinstance(caught.value.__cause__, ImportError)


def test_required_extras_exist_and_bring_the_module() -> None:
    """Every ``require(module, extra)`` in the sources names an extra of pyproject.toml that lists the module's
    distribution."""
    pyproject = tomllib.loads((ROOT.parents[1] / "pyproject.toml").read_text())
    extras = {
        extra: {re.split(r"[<>=\[ ]", req, maxsplit=1)[0] for req in reqs}
        for extra, reqs in pyproject["project"]["optional-dependencies"].items()
    }
    calls = []
    for path in ROOT.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "require":
                module, extra = (ast.literal_eval(a) for a in node.args)
                calls.append((path.relative_to(ROOT), module, extra))
    assert len(calls) > 20
    for where, module, extra in calls:
        top = module.partition(".")[0]
        assert extra in extras, f"{where}: no extra {extra!r} in pyproject.toml"
        assert DISTRIBUTIONS.get(top, top) in extras[extra], f"{where}: fleetslam[{extra}] does not bring {module}"


def _run(code: str) -> None:
    result = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
