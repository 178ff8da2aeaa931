"""Lazy attributes of a package: its modules and re-exported names are imported on first access.

One policy for the top-level package and the subpackages whose modules pull in heavy libraries (``view``:
matplotlib and PyVista; ``editor``: anywidget; ``rivals``: libigl), so ``import defop`` stays light. :func:`moved`
keeps a moved module's old names working, and :func:`renamed` a module's renamed names, each with a
``DeprecationWarning``: the one deprecation policy of the library.
"""

from __future__ import annotations

import sys
import warnings
from importlib import import_module

__all__ = ["attach", "from_import_probe", "moved", "renamed"]


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


def moved(old, new, load, names=None, stacklevel=2):
    """``(__getattr__, __dir__)`` for a module whose public names moved: each access warns and returns the new one.

    Parameters
    ----------
    old : str
        The old module's ``__name__`` (named in the warning).
    new : str
        The new module's name, for names that are not functions or classes (those name their own module).
    load : callable
        ``load()`` returns the new module. Write its import inside ``load`` (``from ..rivals import peers``),
        so the import graph and import-linter see the link.
    names : collection of str, optional
        The names forwarded; by default the new module's ``__all__`` (else every public name).
    stacklevel : int
        The warning's, counted from ``__getattr__`` (2: the code that reads the old name).

    Returns
    -------
    __getattr__, __dir__ : callables
        To assign at the old module's level (PEP 562). Each access raises a ``DeprecationWarning`` that names
        the new home.
    """

    def forwarded(module):
        if names is not None:
            return sorted(n for n in names if hasattr(module, n))
        return sorted(getattr(module, "__all__", [n for n in dir(module) if not n.startswith("_")]))

    def __getattr__(name):
        module = load()
        if name == "__all__":  # ``from old import *``: every forwarded name, each warning as it is read
            return forwarded(module)
        if name not in forwarded(module):
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        value = getattr(module, name)
        home = getattr(value, "__module__", None) if callable(value) else None
        home = home if isinstance(home, str) else new
        if not from_import_probe(stacklevel):
            warnings.warn(
                f"{old}.{name} is deprecated and will be removed: use {home}.{name}",
                DeprecationWarning,
                stacklevel=stacklevel,
            )
        return value

    def __dir__():
        return forwarded(load())

    return __getattr__, __dir__


def renamed(module, names, stacklevel=2):
    """``__getattr__`` for a module some of whose names were renamed: each old name warns and returns the new object.

    Parameters
    ----------
    module : str
        The module's ``__name__``.
    names : dict of str -> str
        Old name -> new name, both in ``module``.
    stacklevel : int
        The warning's, counted from ``__getattr__`` (2: the code that reads the old name).

    Returns
    -------
    __getattr__ : callable
        To assign at the module's level (PEP 562).
    """
    names = dict(names)

    def __getattr__(name):
        if name not in names:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        if not from_import_probe(stacklevel):
            warnings.warn(
                f"{module}.{name} is renamed {names[name]} and will be removed: use {module}.{names[name]}",
                DeprecationWarning,
                stacklevel=stacklevel,
            )
        return getattr(sys.modules[module], names[name])

    return __getattr__


def from_import_probe(stacklevel):
    """Whether the code a shim's warning would name (``stacklevel`` counted from the shim's ``__getattr__``) is
    importlib's check of ``from package import name``, which reads the name once (``hasattr``) before the import
    statement reads it again: that statement's read warns, so the user sees one warning, not two."""
    code = sys._getframe(stacklevel).f_code  # 0: this function, 1: the shim's __getattr__
    return code.co_name == "_handle_fromlist" and "importlib" in code.co_filename
