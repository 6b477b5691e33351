"""Optional dependencies and lazy package exports.

:func:`require` imports an optional dependency or raises :class:`~fleetslam.errors.MissingExtraError` naming the
``fleetslam[extra]`` to install; it is the only place that turns a missing extra into that error.

:func:`lazy_exports` gives a package a module-level ``__getattr__`` and ``__dir__`` (PEP 562, as zenoh-python's
``__init__.py`` does) so that ``from fleetslam.mapping import OccupancyOctree`` works while ``import
fleetslam.mapping`` loads none of its submodules, and so none of the heavy extras (numba, OpenCV, GTSAM, MuJoCo)
or Zenoh until a name that needs them is used.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from types import ModuleType
from typing import Any

from fleetslam.errors import MissingExtraError

#: The pip distribution of an optional module whose import name differs from it.
DISTRIBUTIONS = {"cv2": "opencv-python-headless", "llvmlite": "numba"}


def require(module: str, extra: str) -> ModuleType:
    """Import ``module`` (dotted names allowed: ``"numba.cuda"``) or raise MissingExtraError naming the
    distribution to install and the ``fleetslam[extra]`` that brings it."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        top = module.partition(".")[0]
        raise MissingExtraError(DISTRIBUTIONS.get(top, top), extra) from err


def lazy_exports(
    package: str, exports: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package`` exporting, per submodule (relative name), its public names.

    A name's submodule is imported on first access and the value cached in the package's namespace, so later
    lookups do not come back here.
    """
    where = {name: submodule for submodule, names in exports.items() for name in names}
    namespace = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> Any:
        submodule = where.get(name)
        if submodule is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{submodule}"), name)
        namespace[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *where})

    return __getattr__, __dir__
