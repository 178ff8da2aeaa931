"""The page's compact encoding of a payload: the factor B on a power-of-two grid per row, Rice-coded, and the mesh's
indices in 16 bits.

A standalone page carries its numbers as base64 of typed arrays (:func:`defop.editor.payload.encode_payload`).
Most of them are the factor B of W_F ≈ A B ((r, d n_vertices), :mod:`defop.operator.compress`). The page ships B
on a grid per row: every entry of row j is an integer code times 2^e_j (:func:`on_grid`). The steps share the
error equally between the rows (:func:`grid_exponents`): row j enters the training displacements
Y = S A B M^{1/2} through the column S A_j, so its step is inversely proportional to ‖S A_j‖, and all steps are
scaled so that the grid's expected error on Y is :data:`GRID_TOL` of ‖Y‖_F (below the compression's own
:data:`defop.operator.compress.TOL`). The codes are at most 16 bits, so B is exact in float32, and the rounding is
idempotent: the factors the page evaluates are known in Python bit for bit
(:func:`defop.editor.payload.page_factors`). B is zero on the handle columns (code 0) and multiplies δψ(P) = 0:
the handles (Prop. 2) and the rest pose (8b) do not depend on the grid.

The codes are Rice-coded (:func:`rice_pack`: zigzag, then per row a unary quotient and k_j remainder bits): a
row's codes are mostly small, so this costs about the entropy of the codes instead of the bits of the largest.
``decodePayload`` of ``static/defop_editor.js`` undoes :func:`compact_payload`: it decodes ``B_rice`` with
``B_k`` and ``B_exponent`` into B and, for the 2D canvas fallback, rebuilds the edges E from F.
"""

from __future__ import annotations

import numpy as np

#: the grid's expected error on the training displacements Y = S A B M^{1/2}, relative to ‖Y‖_F
#: (:func:`grid_exponents`). On octopus_3d (2,502 vertices, rank 105) the grid then changes a frame by at most
#: 1.2e-4 of the diagonal over random poses within the training reach, as 12 bits per row did, in 6.6 bits per
#: entry instead of 12.
GRID_TOL = 2e-3
#: the largest code of a row: 16 bits with the sign, so every grid value is exact in float32
CODE_MAX = 2**15 - 1
#: the largest Rice parameter of a row (codes of at most 16 bits)
K_MAX = 16


def grid_exponents(B, SA, mass, tol=GRID_TOL):
    """The power-of-two step 2^e_j of every row of B that shares the grid's error equally between the rows.

    Row j's rounding (uniform, step s_j) enters Y = S A B M^{1/2} as the column S A_j times it, with expected
    squared norm ‖S A_j‖² s_j² Σ mass / 12. With s_j = c / ‖S A_j‖ the rows add r c² Σ mass / 12, set to
    (tol ‖Y‖_F)²; each step is rounded down to a power of two, and clipped to codes of at most
    :data:`CODE_MAX` (and to at least the row's largest entry).

    Parameters
    ----------
    B : (r, c) numpy array
        Finite.
    SA : (m, r) numpy array
        The training samples' δψ times A (the identity times A without samples).
    mass : (c,) numpy array
        The lumped mass of each column's vertex.
    tol : float

    Returns
    -------
    exponent : (r,) int32 numpy array
    """
    B = np.asarray(B, np.float64)
    if B.ndim != 2 or not np.isfinite(B).all():
        raise ValueError(f"B must be a finite 2D array, got shape {B.shape}")
    weight = np.linalg.norm(SA, axis=0)
    Y = np.linalg.norm(SA @ (B * np.sqrt(mass)))
    c = tol * Y * np.sqrt(12.0 / (len(B) * max(float(np.sum(mass)), 1e-300)))
    top = np.abs(B).max(axis=1, initial=0.0)
    with np.errstate(divide="ignore"):
        finest = np.ceil(np.log2(top / CODE_MAX))  # codes of at most CODE_MAX
        coarsest = np.ceil(np.log2(top))  # codes 0 and ±1
        target = np.floor(np.log2(c / weight))
    exponent = np.clip(np.nan_to_num(target, nan=0.0, posinf=coarsest, neginf=finest), finest, coarsest)
    return np.where(top > 0, exponent, 0).astype(np.int32)


def quantize_rows(B, exponent):
    """The integer codes of B on the grid 2^exponent per row: ``rint(B / 2^e_j)`` (int32 numpy array)."""
    return np.rint(np.asarray(B, np.float64) / np.exp2(np.asarray(exponent, np.float64))[:, None]).astype(np.int32)


def dequantize_rows(codes, exponent):
    """B on its grid: ``codes · 2^exponent`` per row, float32 (exact for codes of at most 24 bits)."""
    return (np.asarray(codes, np.float64) * np.exp2(np.asarray(exponent, np.float64))[:, None]).astype(np.float32)


def on_grid(B, exponent):
    """B rounded to the grid 2^exponent per row (:func:`grid_exponents`): the factor a page evaluates, float32."""
    return dequantize_rows(quantize_rows(B, exponent), exponent)


def exact_grid(B):
    """The coarsest power-of-two grid per row that holds B exactly, and its codes (None when a code needs more than
    16 bits: B is then shipped as float32).

    Returns
    -------
    codes : (r, c) int32 numpy array, or None
    exponent : (r,) int32 numpy array, or None
    """
    B = np.asarray(B, np.float64)
    mantissa, power = np.frexp(B)
    bits = (mantissa * 2.0**53).astype(np.int64)  # exact: B is a float64 value
    low = np.log2((bits & -bits).astype(np.float64), where=bits != 0, out=np.zeros(B.shape))
    lowest = np.where(B != 0, power - 53 + low, np.inf).min(axis=1, initial=np.inf)
    exponent = np.where(np.isfinite(lowest), lowest, 0).astype(np.int32)
    if np.abs(B / np.exp2(exponent.astype(np.float64))[:, None]).max(initial=0) > CODE_MAX:  # before any int cast
        return None, None
    return quantize_rows(B, exponent), exponent


def rice_pack(codes):
    """Rice codes of every row (LSB first): zigzag z = 2c (c ≥ 0) or −2c − 1, then ⌊z / 2^k_j⌋ ones, a zero and
    the k_j low bits of z, with k_j the row's shortest.

    Parameters
    ----------
    codes : (r, c) integer numpy array
        |codes| ≤ :data:`CODE_MAX`.

    Returns
    -------
    packed : (bytes,) uint8 numpy array
    k : (r,) uint8 numpy array
    """
    c = np.asarray(codes, np.int64)
    z = np.where(c >= 0, 2 * c, -2 * c - 1)
    cost = [(z >> k).sum(axis=1) + (k + 1) * z.shape[1] for k in range(K_MAX + 1)]
    k = np.argmin(np.stack(cost), axis=0).astype(np.uint8)
    kk = np.repeat(k.astype(np.int64), z.shape[1])
    z = z.ravel()
    q = z >> kk
    start = np.concatenate([[0], np.cumsum(q + 1 + kk)])
    bits = np.zeros(int(start[-1]), np.uint8)
    ones = np.repeat(start[:-1], q) + np.arange(int(q.sum())) - np.repeat(np.cumsum(q) - q, q)
    bits[ones] = 1
    for b in range(int(k.max(initial=0))):
        has = kk > b
        bits[(start[:-1] + q + 1 + b)[has]] = (z[has] >> b) & 1
    return np.packbits(bits, bitorder="little"), k


def rice_unpack(packed, k, cols):
    """The codes of :func:`rice_pack` ((len(k), cols) int32 numpy array): the page's decoding, in Python."""
    bits = np.unpackbits(np.asarray(packed, np.uint8), bitorder="little")
    out, pos = np.zeros((len(k), cols), np.int32), 0
    for j, kj in enumerate(np.asarray(k, int)):
        for i in range(cols):
            q = 0
            while bits[pos]:
                q, pos = q + 1, pos + 1
            r = int(bits[pos + 1 : pos + 1 + kj] @ (1 << np.arange(kj)))
            pos += 1 + kj
            z = (q << kj) + r
            out[j, i] = -(z + 1) // 2 if z & 1 else z // 2
    return out


def compact_payload(p, drawn=None):
    """The payload as the standalone page ships it (a new dict; ``p`` is unchanged).

    In 3D only the vertices the page draws (``drawn(p)``, default :func:`drawn_vertices`; the movable page's keeps
    its placement's vertices too, :func:`defop.editor.movable_page.drawn_payload`). ``B``, when its rows lie on
    power-of-two grids with codes of at most 16 bits (as :func:`defop.editor.payload.page_factors` makes it), becomes
    ``B_rice`` and ``B_k`` (:func:`rice_pack`) and ``B_exponent`` (:func:`exact_grid`: its rows' powers of two); the
    edges ``E`` are left out (the page rebuilds them from F); the region outlines keep 7 significant digits;
    triangle indices (``F``, ``surface_F``, ``surface_tets``) become uint16 when there are fewer than 65,536
    vertices. Everything else is as in ``p``.

    Returns
    -------
    dict
    """
    out = (drawn or drawn_vertices)(p) if p.get("d") == 3 else dict(p)
    B = out.get("B")
    if B is not None:
        codes, exponent = exact_grid(B)
        if codes is not None:
            del out["B"]
            packed, k = rice_pack(codes)
            out.update(B_rice=packed, B_k=k, B_exponent=exponent)
    out.pop("E", None)
    if "regions" in out:  # drawn only (the extrapolation rule reads ``reach``): 7 significant digits
        out["regions"] = [[[float(f"{v:.7g}") for v in poly] for poly in polys] for polys in out["regions"]]
    n = int(out["n_vertices"])
    for name in ("F", "surface_F", "surface_tets"):
        if name in out and n <= 0xFFFF and (name != "surface_F" or len(out["surface_tets"]) <= 0xFFFF):
            out[name] = np.asarray(out[name]).astype(np.uint16)
    return out


def drawn_vertices(p, also=None, renumbered=()):
    """A 3D payload restricted to the vertices the page draws: those of the surface's tetrahedra
    (``surface_tets``) or else of the boundary facets ``F``, and the handles (a new dict; ``p`` is unchanged).

    The operator's rows are per vertex ((★): x + δψ(Q) W_F, then Q − P on the handles), so the kept vertices
    are evaluated exactly as before; ``V``, the columns of ``B`` (or of ``A`` = W_F without factors), ``handles``
    and the indices are renumbered, ``n_vertices`` counts the kept ones and ``n_vertices_all`` all of them. The
    boundary facets are left out when the surface is drawn. Unchanged when every vertex is drawn.

    Parameters
    ----------
    p : dict
    also : int numpy array, optional
        Vertices to keep as well (a movable page's placement vertices: :mod:`defop.editor.movable_page`); then
        ``drawn`` (k,) int32 holds the kept vertices (their indices in the operator's mesh, increasing).
    renumbered : sequence of str
        Further keys of vertex indices to renumber (each must index kept vertices).

    Returns
    -------
    dict
    """
    n, surface = int(p["n_vertices"]), "surface_tets" in p
    keep = np.union1d(np.asarray(p["surface_tets"] if surface else p["F"]).ravel(), p["handles"])
    if also is not None:
        keep = np.union1d(keep, also)
    out = dict(p)
    if surface:
        out.pop("F", None)
    if len(keep) == n:
        return out
    renumber = vertex_renumbering(keep, n)
    cols = (3 * keep[:, None] + np.arange(3)).ravel()
    out.update(V=p["V"][keep], handles=renumber[p["handles"]], n_vertices=len(keep), n_vertices_all=n)
    if also is not None:
        out["drawn"] = keep.astype(np.int32)
    out["B" if "B" in p else "A"] = (p["B"] if "B" in p else p["A"])[:, cols]
    for name in ("F", "surface_tets", *renumbered):
        if name in out:
            out[name] = renumber[out[name]]
    return out


def vertex_renumbering(keep, n):
    """(n,) int32 numpy array: the new index of each kept vertex (sorted ``keep``), −1 for the others."""
    renumber = np.full(n, -1, np.int32)
    renumber[keep] = np.arange(len(keep), dtype=np.int32)
    return renumber
