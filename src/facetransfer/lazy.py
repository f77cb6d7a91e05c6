"""A package's public names imported on first use (PEP 562): :func:`lazy_names` makes the
module-level ``__getattr__`` and ``__dir__`` of :mod:`facetransfer.datasets` and
:mod:`facetransfer.correspond`, whose submodules bring SciPy's solvers or the renderer that a
caller of one small submodule should not pay for."""

from __future__ import annotations

import importlib
import sys
from typing import Callable, Iterable, Mapping

__all__ = ["lazy_names"]


def lazy_names(package: str, names: Mapping[str, str], submodules: Iterable[str] = ()
               ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for the package ``package``.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    names : mapping of str to str
        Each public name and the submodule that defines it: imported at its first use, then kept
        in the package's globals.
    submodules : iterable of str
        Submodules an attribute access imports (``package.fitting``).
    """
    subs = tuple(submodules)

    def __getattr__(name: str):
        if name in subs:
            return importlib.import_module(f".{name}", package)
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f".{module}", package), name)
        vars(sys.modules[package])[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(names) | set(subs))

    return __getattr__, __dir__
