"""A package's public names loaded on first use (PEP 562), so that importing one light module of
it (``markergraph.estimator.types``) does not load the heavy ones (GTSAM, OpenCV) beside it."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Mapping
from types import ModuleType
from typing import Any

__all__ = ["lazy_package"]


class _LazyPackage(ModuleType):
    """A package whose exported names are imported from their homes when first read."""

    _homes: dict[str, str]  # exported name -> the module that defines it

    def __getattr__(self, name: str) -> Any:  # only called for names not yet in the package
        home = self._homes.get(name)
        if home is None:
            raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home), name)
        ModuleType.__setattr__(self, name, value)
        return value

    def __setattr__(self, name: str, value: Any) -> None:
        # Importing a submodule binds it on its package under its own name: where an exported
        # name is also a submodule's (``estimate`` the function, ``estimate.py`` the module),
        # the export keeps the name, as it did when the package imported everything eagerly.
        if isinstance(value, ModuleType) and name in self._homes:
            return
        ModuleType.__setattr__(self, name, value)

    def __dir__(self) -> list[str]:
        return sorted({*super().__dir__(), *self._homes})


def lazy_package(package: str, homes: Mapping[str, tuple[str, ...]]) -> None:
    """Make ``package`` (already importing: pass ``__name__``) load its public names on use.

    Args:
        package: the package's module name.
        homes: each defining module's name -> the names the package exports from it.
    """
    module = sys.modules[package]
    by_name = {name: home for home, names in homes.items() for name in names}
    ModuleType.__setattr__(module, "_homes", by_name)
    module.__class__ = _LazyPackage
