"""Lazy package faces: a package's public names, imported from their modules on first use.

A face lists ``{module: (names, ...)}``; ``from tracker.fitting import Tracker`` then imports only
``tracker.fitting.tracking``, so importing one module of a package stays light and faces never
create import cycles between the modules they list.

    __all__, __getattr__, __dir__ = lazy_face(__name__, {"tracker.fitting.tracking": ("Tracker",)})
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable, Mapping, Sequence

__all__ = ["lazy_face"]


def lazy_face(package: str, exports: Mapping[str, Sequence[str]]) -> tuple[list[str], Callable, Callable]:
    """The ``__all__``, module ``__getattr__`` and ``__dir__`` of a lazy package face.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    exports : mapping of str to sequence of str
        Module -> the public names it provides to the face.

    Returns
    -------
    all_names : list of str
    getattr_ : callable (name) -> object
        Imports the name's module on first use and caches the value in the package.
    dir_ : callable () -> list of str
    """
    where = {name: module for module, names in exports.items() for name in names}

    def getattr_(name: str):
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def dir_() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return sorted(where), getattr_, dir_
