"""Lazy attributes of a package: its modules and re-exported names are imported on first access.

One policy for the top-level package and the subpackages whose modules pull in heavy libraries (``view``:
matplotlib and PyVista; ``editor``: anywidget; ``analysis``: libigl's peers), so ``import defop`` stays light.
"""

from __future__ import annotations

import sys
from importlib import import_module

__all__ = ["attach"]


def attach(package, modules=(), names=None):
    """``(__getattr__, __dir__)`` for ``package``: the given submodules and names load on first access.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    modules : sequence of str
        Submodules (or subpackages) reached as attributes, e.g. ``dop.view.plot``.
    names : dict of str -> str, optional
        Re-exported names and the submodule each comes from: ``{"BrowserEditor": "browser"}`` makes
        ``package.BrowserEditor`` be ``package.browser.BrowserEditor``.

    Returns
    -------
    __getattr__, __dir__ : callables
        To assign at the package's module level (PEP 562); a loaded attribute is kept on the package.
    """
    modules, names = tuple(modules), dict(names or {})

    def __getattr__(name):
        if name in modules:
            value = import_module(f".{name}", package)
        elif name in names:
            value = getattr(import_module(f".{names[name]}", package), name)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(modules) | set(names))

    return __getattr__, __dir__
