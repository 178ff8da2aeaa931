"""The checks of a solve's arguments: tolerances, iteration limits, handles, targets and starts.

Each returns the value in the form the solver uses, or raises a ValueError naming the argument and the condition.
"""

from __future__ import annotations

import numpy as np

from .. import options as opt
from . import energies as en

#: targets farther than this many bounding-box diagonals from the mesh are rejected (the energy overflows)
MAX_TARGET_DISTANCE = 1e6


def count_flips(mesh, X):
    """Number of elements with det J ≤ 0 (flipped or collapsed).

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X : (n, d) numpy array

    Returns
    -------
    n : int
    """
    return int(np.count_nonzero(mesh.flipped(X)))


def check_tol(tol, name="tol"):
    """A tolerance: a finite float ≥ 0, else ValueError."""
    try:
        t = float(tol)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number >= 0, got {tol!r}") from None
    if not (np.isfinite(t) and t >= 0):
        raise ValueError(f"{name} must be a finite number >= 0, got {tol!r}")
    return t


def check_max_iter(max_iter):
    """An iteration limit: an integer ≥ 1 (an integer-valued float is accepted), else ValueError."""
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer, float, np.floating)):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    if not (np.isfinite(max_iter) and max_iter >= 1 and float(max_iter) == int(max_iter)):
        raise ValueError(f"max_iter must be a positive integer, got {max_iter!r}")
    return int(max_iter)


def check_handles(mesh, handles):
    """Validate point handles: vertex indices, or a boolean mask with one entry per vertex.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int array-like or (n_vertices,) bool array-like
        Integer-valued floats (``[3.0, 7.0]``) are accepted as indices; other floats are rejected.
        Order is kept; duplicates are allowed
        (:meth:`defop.variational.problem.ReducedProblem.targets_of` checks their targets agree).

    Returns
    -------
    handles : (h,) int64 numpy array

    Raises
    ------
    ValueError
        Empty, not 1-d, non-integer, out of range, or a mask of the wrong length.
    """
    h = np.asarray(handles)
    n = mesh.n_vertices
    if h.dtype == bool:
        if h.shape != (n,):
            raise ValueError(f"a boolean handle mask needs one entry per vertex ({n}), got shape {h.shape}")
        h = np.flatnonzero(h)
    if h.ndim != 1 or len(h) == 0:
        raise ValueError(f"handles must be a non-empty 1-d array of vertex indices, got shape {h.shape}")
    if not np.issubdtype(h.dtype, np.integer):
        if not np.issubdtype(h.dtype, np.floating):
            raise ValueError(f"handles must be integer vertex indices, got dtype {h.dtype}")
        bad = np.flatnonzero(~np.isfinite(h) | (np.mod(h, 1) != 0))
        if len(bad):
            k = int(bad[0])
            raise ValueError(f"handles must be integer vertex indices; handle {k} is {float(h[k])!r}")
    h = h.astype(np.int64)
    bad = np.flatnonzero((h < 0) | (h >= n))
    if len(bad):
        raise ValueError(
            f"handle {int(bad[0])} is vertex index {int(h[bad[0]])}, out of range for a mesh of {n} vertices"
        )
    return h


def check_handle_span(mesh, handles):
    """In 3D, refuse handles that all lie on one line: a rotation about it costs nothing (singular Hessian).

    The rotations of R^d that fix every handle form a group of dimension (d − k)(d − k − 1)/2, with k the dimension
    of the handles' affine hull (at rest). In 3D that is 1 for handles on one line (two handles, say) and 3 for one
    point: problem (6) then has a circle (or sphere) of minima and its reduced Hessian a null space. In 2D the
    group is the rotations about a single handle, whose problem keeps its old treatment: its minimum is the rest
    pose moved rigidly (E = 0), which the solver starts from.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    handles : (h,) int numpy array
        Valid vertex indices (fixed and moving handles together).

    Raises
    ------
    ValueError
        d ≥ 3 and the handles' rest positions span less than a plane (to 1e-9 of the bounding-box diagonal).
    """
    d = mesh.V.shape[1]
    if d < 3:
        return
    P = mesh.V[np.unique(handles)]
    sv = np.linalg.svd(P - P.mean(axis=0), compute_uv=False)
    k = int(np.count_nonzero(sv > 1e-9 * mesh.bbox_diagonal))
    if k < d - 1:
        where = "one point" if k == 0 else "one line"
        raise ValueError(
            f"handles must not all lie on one line in {d}D (a rotation about it is free and the Hessian singular): "
            f"the {len(P)} distinct handle vertices lie on {where}; add a handle off it (at least three "
            "non-collinear handles, or a small handle patch)"
        )


def check_targets(targets, handles, mesh=None, dim=2):
    """Validate targets: one finite row per handle, not absurdly far from the mesh.

    Parameters
    ----------
    targets : (h, d) array-like
    handles : (h,) int numpy array
    mesh : defop.geometry.mesh.Mesh, optional
        When given, d is ``mesh.V.shape[1]`` and targets farther than ``MAX_TARGET_DISTANCE`` bounding-box
        diagonals from the mesh's centre are rejected (the energy would overflow to inf: e.g. a target at 1e300).
    dim : int
        d when no mesh is given.

    Returns
    -------
    T : (h, d) float numpy array
    """
    d = dim if mesh is None else mesh.V.shape[1]
    T = opt.real_array("targets", targets)
    if T.shape != (len(handles), d):
        raise ValueError(f"targets must have shape ({len(handles)}, {d}), one row per handle, got {T.shape}")
    if not np.isfinite(T).all():
        k = int(np.argwhere(~np.isfinite(T))[0, 0])
        raise ValueError(f"target {k} of handle vertex {int(handles[k])} is not finite: {T[k]}")
    if mesh is not None:
        diag = mesh.bbox_diagonal
        far = np.abs(T - mesh.V.mean(axis=0)).max(axis=1) / diag  # max-norm: no overflow at 1e300
        if far.max() > MAX_TARGET_DISTANCE:
            k = int(np.argmax(far))
            raise ValueError(
                f"target {k} of handle vertex {int(handles[k])} is {far[k]:.3g} bounding-box diagonals from the "
                f"mesh (more than {MAX_TARGET_DISTANCE:g}): the energy would overflow"
            )
    return T


def check_start(mesh, X0, energy):
    """A copy of the start X0 (n, d), or of the rest pose when None; ValueError if it is not a valid start.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    X0 : (n, d) array-like or None
    energy : str
        A barrier energy (:func:`defop.variational.energies.is_barrier`) needs a start without flipped elements.
    """
    if X0 is None:
        return mesh.V.copy()
    X = opt.real_array("X0", X0).copy()
    if X.shape != mesh.V.shape:
        raise ValueError(f"X0 must have shape {mesh.V.shape}, got {X.shape}")
    if not np.isfinite(X).all():
        raise ValueError("X0 has NaN or infinite entries")
    if en.is_barrier(energy) and np.any(mesh.flipped(X)):
        bad = np.flatnonzero(mesh.flipped(X))
        raise ValueError(
            f"X0 has {len(bad)} flipped triangle(s) (first: triangle {int(bad[0])}); "
            f"the {energy} energy is a barrier and needs a flip-free start"
        )
    return X
