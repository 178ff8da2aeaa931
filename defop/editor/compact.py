"""The page's compact encoding of a payload: the factor B in 12 bits per entry, the mesh's indices in 16 bits.

A standalone page carries its numbers as base64 of typed arrays (:func:`defop.editor.payload.encode_payload`).
Most of them are the factor B of W_F ≈ A B ((r, d n_vertices), :mod:`defop.operator.compress`). The page ships
B on a 12-bit grid per row: every entry of row j is an integer code c ∈ [−2047, 2047] times 2^e_j, the smallest
power of two that holds the row's largest entry, so each entry is off by at most half a step, max_c |B_jc| / 2047
(:func:`quantize_rows`). A 12-bit B is exact in float32 and the quantization is idempotent, so the factors the
page evaluates are known in Python bit for bit (:func:`defop.editor.payload.page_factors`). B is zero on the
handle columns (code 0) and multiplies δψ(P) = 0: the handles (Prop. 2) and the rest pose (8b) stay exact.

``decodePayload`` of ``static/defop_editor.js`` undoes :func:`compact_payload`: it unpacks ``B_packed`` with
``B_exponent`` into B and, for the 2D canvas fallback, rebuilds the edges E from F.
"""

from __future__ import annotations

import numpy as np

#: the codes of a 12-bit row: c ∈ [−CODE_MAX, CODE_MAX], stored as c + 2048 in 12 bits
CODE_MAX = 2047


def quantize_rows(B):
    """The 12-bit codes and the power-of-two scale of every row of B.

    Parameters
    ----------
    B : (r, c) numpy array
        Finite.

    Returns
    -------
    codes : (r, c) int16 numpy array
        In [−2047, 2047]; ``codes * 2.0**exponent[:, None]`` is B within half a step per entry.
    exponent : (r,) int32 numpy array
        The smallest e with max |B_j| ≤ 2047 · 2^e (0 for a zero row).
    """
    B = np.asarray(B, np.float64)
    if B.ndim != 2 or not np.isfinite(B).all():
        raise ValueError(f"B must be a finite 2D array, got shape {B.shape}")
    top = np.abs(B).max(axis=1, initial=0.0)
    exponent = np.zeros(len(B), np.int32)
    nonzero = top > 0
    exponent[nonzero] = np.ceil(np.log2(top[nonzero] / CODE_MAX)).astype(np.int32)
    exponent[nonzero & (top > CODE_MAX * np.exp2(exponent.astype(float)))] += 1  # log2's rounding
    codes = np.rint(B / np.exp2(exponent.astype(float))[:, None])
    return np.clip(codes, -CODE_MAX, CODE_MAX).astype(np.int16), exponent


def dequantize_rows(codes, exponent):
    """B on the 12-bit grid: ``codes · 2^exponent`` per row, float32 (exact)."""
    return (np.asarray(codes, np.float64) * np.exp2(np.asarray(exponent, np.float64))[:, None]).astype(np.float32)


def on_grid(B):
    """B rounded to its 12-bit grid (:func:`quantize_rows`): the factor a page evaluates, float32."""
    return dequantize_rows(*quantize_rows(B))


def pack12(codes):
    """Codes in [−2047, 2047] as bytes, two per three bytes (little end first); an odd count is padded with 0.

    Returns
    -------
    packed : (3 ⌈k/2⌉,) uint8 numpy array
    """
    u = np.asarray(codes, np.int32).ravel() + 2048
    if u.size % 2:
        u = np.append(u, 2048)
    lo, hi = u[0::2], u[1::2]
    out = np.empty((len(lo), 3), np.uint8)
    out[:, 0] = lo & 0xFF
    out[:, 1] = (lo >> 8) | ((hi & 0xF) << 4)
    out[:, 2] = hi >> 4
    return out.ravel()


def unpack12(packed, count):
    """The first ``count`` codes of :func:`pack12`'s bytes (int16 numpy array): the page's unpacking in numpy."""
    b = np.asarray(packed, np.int32).reshape(-1, 3)
    lo = b[:, 0] | ((b[:, 1] & 0xF) << 8)
    hi = (b[:, 1] >> 4) | (b[:, 2] << 4)
    return (np.column_stack([lo, hi]).ravel()[:count] - 2048).astype(np.int16)


def compact_payload(p):
    """The payload as the standalone page ships it (a new dict; ``p`` is unchanged).

    In 3D only the vertices the page draws (:func:`drawn_vertices`). ``B``, when it lies on its 12-bit grid (as
    :func:`defop.editor.payload.page_factors` makes it), becomes ``B_packed`` (:func:`pack12`) and ``B_exponent``
    (its rows' powers of two); the edges ``E`` are left out (the page rebuilds them from F); the region outlines
    keep 7 significant digits; triangle indices (``F``, ``surface_F``, ``surface_tets``) become uint16 when there
    are fewer than 65,536 vertices. Everything else is as in ``p``.

    Returns
    -------
    dict
    """
    out = drawn_vertices(p) if p.get("d") == 3 else dict(p)
    B = out.get("B")
    if B is not None:
        codes, exponent = quantize_rows(B)
        if np.array_equal(dequantize_rows(codes, exponent), B):
            del out["B"]
            out.update(B_packed=pack12(codes), B_exponent=exponent)
    out.pop("E", None)
    if "regions" in out:  # drawn only (the extrapolation rule reads ``reach``): 7 significant digits
        out["regions"] = [[[float(f"{v:.7g}") for v in poly] for poly in polys] for polys in out["regions"]]
    n = int(out["n_vertices"])
    for name in ("F", "surface_F", "surface_tets"):
        if name in out and n <= 0xFFFF and (name != "surface_F" or len(out["surface_tets"]) <= 0xFFFF):
            out[name] = np.asarray(out[name]).astype(np.uint16)
    return out


def drawn_vertices(p):
    """A 3D payload restricted to the vertices the page draws: those of the surface's tetrahedra
    (``surface_tets``) or else of the boundary facets ``F``, and the handles (a new dict; ``p`` is unchanged).

    The operator's rows are per vertex ((★): x + δψ(Q) W_F, then Q − P on the handles), so the kept vertices
    are evaluated exactly as before; ``V``, the columns of ``B`` (or of ``A`` = W_F without factors), ``handles``
    and the indices are renumbered, ``n_vertices`` counts the kept ones and ``n_vertices_all`` all of them. The
    boundary facets are left out when the surface is drawn. Unchanged when every vertex is drawn.

    Returns
    -------
    dict
    """
    n, surface = int(p["n_vertices"]), "surface_tets" in p
    keep = np.union1d(np.asarray(p["surface_tets"] if surface else p["F"]).ravel(), p["handles"])
    out = dict(p)
    if surface:
        out.pop("F", None)
    if len(keep) == n:
        return out
    renumber = np.full(n, -1, np.int32)
    renumber[keep] = np.arange(len(keep), dtype=np.int32)
    cols = (3 * keep[:, None] + np.arange(3)).ravel()
    out.update(V=p["V"][keep], handles=renumber[p["handles"]], n_vertices=len(keep), n_vertices_all=n)
    out["B" if "B" in p else "A"] = (p["B"] if "B" in p else p["A"])[:, cols]
    for name in ("F", "surface_tets"):
        if name in out:
            out[name] = renumber[out[name]]
    return out
