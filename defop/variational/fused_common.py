"""What the fused numba kernels share: their compile options, 1/√2 and the guard of non-finite values."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: numba's options for every fused kernel. error_model "numpy": a division by zero gives inf or nan, as in the numpy
#: path (and costs no check); ``cache``: compiled once, cached beside the module
JIT = {"cache": True, "nogil": True, "boundscheck": False, "error_model": "numpy"}
#: 1/√2, the norm of the 2×2 rotation, reflection, twist and flip modes
R2 = 1 / math.sqrt(2.0)


@njit(**JIT)
def finite(x):
    """x where finite, else 0."""
    return x if np.isfinite(x) else 0.0
