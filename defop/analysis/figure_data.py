"""Deprecated: the lessons' figure data moved to :mod:`defop.lessons.figure_data`; its 3D patch sampling
(``patch_motions``, ``twist_bend_samples``) to :mod:`defop.training.sampling`."""

from ..lazy import moved

_SAMPLING = ("patch_motions", "twist_bend_samples")


def _load():
    from ..lessons import figure_data

    return figure_data


def _load_sampling():
    from ..training import sampling

    return sampling


_figure_data = moved(__name__, "defop.lessons.figure_data", _load, stacklevel=3)
_sampling = moved(__name__, "defop.training.sampling", _load_sampling, names=_SAMPLING, stacklevel=3)


def __getattr__(name):
    if name == "__all__":  # ``from defop.analysis.figure_data import *``: both homes' names
        return __dir__()
    return (_sampling if name in _SAMPLING else _figure_data)[0](name)


def __dir__():
    return sorted(_figure_data[1]() + _sampling[1]())
