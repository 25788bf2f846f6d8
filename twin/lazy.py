"""Package names that load their module on first use.

A package whose ``__init__`` imported its modules would load MuJoCo, Numba or SciPy for anyone
importing one light module of it (a command's parser, ``twin CMD --help``). Such a package
declares what it exports and where it lives instead::

    __getattr__, __dir__ = lazy_exports(__name__, {"Plant": "twin.sim.plant", ...})

and imports the same names under ``typing.TYPE_CHECKING`` for the type checker.
"""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable, Mapping

__all__ = ["lazy_exports"]


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The module-level ``__getattr__`` and ``__dir__`` of ``package``: ``exports`` maps each name to
    the module it is imported from when first asked for (then kept in the package's globals)."""

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | exports.keys())

    return __getattr__, __dir__
