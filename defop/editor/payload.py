"""What the page needs to evaluate a DefOp: the operator, the mesh, the regions and a picture, as one payload.

:func:`defop_to_payload` packs Ψ's kind and centres or monomial plan, the float32 factors, the mesh and the
handles; ``static/defop_editor.js`` evaluates D(·, Q) = x + δψ(Q) A B (Eq. 3 in the form (★) of
:mod:`defop.operator.defop`) with the formulas of :mod:`defop.operator.handle_bases`, in 2D and 3D (scalar ``d``;
the 3D page ``static/defop_solid.js`` uses the same evaluator). Shared by the Jupyter widget (:mod:`.browser`)
and the standalone pages (:mod:`.export`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..geometry.planar.outlines import load_image
from ..operator.core import EXTRAPOLATION_FACTOR
from ..operator.defop import training_reach
from .compact import grid_exponents, on_grid
from .logic import reach_polygons

JS_PATH = Path(__file__).with_name("static") / "defop_editor.js"


def script_after_editor(path):
    """The text of a page script that imports from ``defop_editor.js``, without that import line: it runs after the
    editor's script in the same module scope (the 3D page's ``defop_solid.js``, the movable page's
    ``defop_movable.js``).

    Parameters
    ----------
    path : pathlib.Path

    Returns
    -------
    str

    Raises
    ------
    RuntimeError
        The file has no import line from ``./defop_editor.js``.
    """
    text = Path(path).read_text(encoding="utf-8")
    text, n = re.subn(r'^import \{[^}]*\}\s*from "\./defop_editor\.js";\n', "", text, count=1, flags=re.M)
    if n != 1:
        raise RuntimeError(f"{Path(path).name}: no import line from ./defop_editor.js")
    return text


_DTYPES = {"f8": np.float64, "f4": np.float32, "i4": np.int32, "u2": np.uint16, "u1": np.uint8}
# WebGL guarantees far smaller textures, but every current GPU (and Chromium's SwiftShader) takes 4096 per side;
# the page checks MAX_TEXTURE_SIZE again and draws the untextured mesh when the picture does not fit
MAX_IMAGE_SIDE = 4096
MAX_IMAGE_BYTES = 16 * 2**20  # the encoded PNG, sent once to the page (a widget message, or inlined in a page)


def mesh_edges(F):
    """Unique edges of a triangle mesh.

    Parameters
    ----------
    F : (m,3) int numpy array

    Returns
    -------
    E : (e,2) int numpy array
    """
    E = np.sort(np.asarray(F)[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(E, axis=0)


def _polynomial_plan(monomials):
    """Each monomial of degree ≥ 1 as (parent monomial index, z coordinate): ψ_j = ψ_parent · z_factor."""
    index = {m: i for i, m in enumerate(monomials)}
    parent = [index[m[:-1]] if len(m) > 1 else 0 for m in monomials[1:]]
    factor = [m[-1] for m in monomials[1:]]
    return np.array(parent, np.int32), np.array(factor, np.int32)


def region_balls(P, regions=None, samples=None):
    """The sampling region of every moving handle in 3D as balls ``[cx, cy, cz, radius]`` (the page's test).

    Parameters
    ----------
    P : (n,3) numpy array
        Rest positions of the moving handles.
    regions : list of dict, optional
        One region per moving handle, as in :class:`defop.scene.shapes.Shape`; a ``ball`` gives its radius.
        Other kinds (and no regions) fall back to the ball through the farthest training sample.
    samples : (m,n,3) numpy array or None
        The training configurations (for the fallback); without them a handle has no region (empty list).

    Returns
    -------
    balls : list of list of (4,) numpy array
    """
    P = np.asarray(P, float)
    reach = training_reach(P, samples)  # the operator's one definition of the reach
    out = []
    for i, p in enumerate(P):
        region = regions[i] if regions is not None else None
        kind = region.get("kind") if isinstance(region, dict) else getattr(region, "kind", None)
        if kind == "ball":
            radius = region["radius"] if isinstance(region, dict) else region.radius
        elif reach is not None:
            radius = reach[i]
        else:
            out.append([])
            continue
        out.append([np.append(p, float(radius))])
    return out


def check_compress(compress):
    """``compress`` (a page's choice of factors), or ValueError when it is not a bool."""
    if not isinstance(compress, bool):
        raise ValueError(f"compress must be True (the compressed factors) or False (the full W_F), got {compress!r}")
    return compress


def page_factors(op, compress=True):
    """The factors (A, B) of W_F ≈ A B a page carries for ``op``: the one quantisation of every page.

    With ``compress``: ``op``'s own factors, or else those its ``compress`` would set at its defaults (float32;
    :meth:`DefOp.factorise <defop.operator.defop.DefOp.factorise>`, :meth:`MovableOp.factorise
    <defop.operator.movable.MovableOp.factorise>`), with B rounded to its grid (:func:`defop.editor.compact.on_grid`,
    steps by :func:`defop.editor.compact.grid_exponents` over the rows of ``op.compression_samples()``: the grid's
    expected error on those displacements is :data:`defop.editor.compact.GRID_TOL` of theirs; zero on the handle
    columns still), the factors the page evaluates bit for bit. ``op`` is unchanged. Without: ``op.factors`` (None:
    the full W_F).

    Parameters
    ----------
    op : defop.operator.DefOp or defop.operator.movable.MovableOp
    compress : bool

    Returns
    -------
    factors : tuple of ((|Ψ|−1, r), (r, d n_vertices)) float32 numpy arrays, or None

    Raises
    ------
    ValueError
        ``compress`` not a bool.
    """
    if not check_compress(compress):
        return op.factors
    A, B = op.factors if op.factors is not None else op.factorise()
    A = np.asarray(A, np.float32)
    S = op.compression_samples()
    SA = A.astype(np.float64) if S is None else S @ A
    mass = np.repeat(op.mesh.mass_matrix.diagonal(), op.d)
    return A, on_grid(B, grid_exponents(B, SA, mass))


def defop_to_payload(op, regions=None, factors=None):
    """Everything the page needs to evaluate and draw a DefOp: the one place that reads its internals.

    Parameters
    ----------
    op : defop.operator.DefOp
        Uses the compressed factors ``(A, B)`` of W_F when present, otherwise W_F (W[1:] with the handle
        columns zeroed) as a single factor: the page evaluates (★) of :mod:`defop.operator.defop`.
    regions : list of list of (k,2) numpy array, optional
        Sampling-region polygons per moving handle (:func:`defop.editor.logic.region_polygons`), or in 3D
        balls ``[cx, cy, cz, r]`` (:func:`region_balls`); default: discs (balls) through the farthest
        training sample.
    factors : tuple of two numpy arrays, optional
        (A, B) to ship instead of ``op.factors`` (:func:`page_factors`).

    Returns
    -------
    payload : dict
        Scalars (``d``, ``kind``, ``kernel`` for ``"tps"``, ``size``, ``n_moving``, ``n_vertices``, ``scale``,
        ``rank``, ``regions``) and numpy arrays (``P``, ``centers`` or ``parent``/``factor``, ``A``, ``B``,
        ``V``, ``F``, ``E``, ``handles``, ``moving``), each flattened row-major by :func:`encode_payload`, and the
        extrapolation rule (``extrapolation_factor``, ``reach``: :func:`extrapolation_payload`). In 2D
        ``F`` are the triangles; in 3D the outward boundary triangles of the tetrahedra
        (:attr:`defop.geometry.mesh.Mesh.boundary_facets`), the surface the page shades, and ``E`` its edges.
    """
    basis = op.handle_basis
    if regions is None:
        regions = region_balls(op.P, None, op.train_samples) if op.d == 3 else reach_polygons(op.P, op.train_samples)
    F = op.mesh.F if op.d == 2 else op.mesh.boundary_facets
    p = {
        "d": int(op.d),
        "kind": basis.kind,
        "size": int(basis.size),
        "n_moving": int(basis.n_handles),
        "n_vertices": int(op.n_vertices),
        "scale": float(basis.scale),
        "regions": [[np.asarray(poly, float).ravel().tolist() for poly in polys] for polys in regions],
        "P": np.asarray(basis.P, np.float64),
        "V": np.asarray(op.mesh.V, np.float64),
        "F": np.asarray(F, np.int32),
        "E": mesh_edges(F).astype(np.int32),
        "handles": np.asarray(op.handles, np.int32),
        "moving": np.asarray(op.moving, np.uint8),
    }
    if basis.kind == "tps":
        p["kernel"] = basis.kernel  # φ: "r2logr" (d = 2) or "r3" (d = 3), defop.operator.handle_bases.KERNELS
        p["centers"] = np.asarray(basis.z(basis.centers), np.float64)  # z_k = (Q_k − P)/scale, (m, d n)
    else:
        p["parent"], p["factor"] = _polynomial_plan(basis.monomials)
    # (★) of defop.operator.defop: D(·, Q) = x + δψ(Q) W_F, the moving handles' columns set to Q − P exactly
    factors = op.factors if factors is None else factors
    if factors is not None:
        p["A"], p["B"] = (np.asarray(f, np.float32) for f in factors)
        p["rank"] = int(p["A"].shape[1])
    else:
        p["A"] = np.asarray(op.WF, np.float32)  # W[1:] with the handle columns zeroed
    p.update(extrapolation_payload(op.P, op.train_samples))
    return p


def extrapolation_payload(P, samples):
    """The page's extrapolation rule, the operators' own (:func:`defop.operator.core.beyond_reach`): a moving
    handle extrapolates beyond ``extrapolation_factor`` (:data:`defop.operator.core.EXTRAPOLATION_FACTOR`) times its
    ``reach``, the distance from rest to its farthest training sample (:func:`training_reach`).

    Parameters
    ----------
    P : (n,d) numpy array
        Rest positions of the moving handles.
    samples : (m,n,d) numpy array or None
        The training configurations.

    Returns
    -------
    payload : dict
        ``extrapolation_factor`` (float) and, with at least 2 samples, ``reach`` ((n,) float64 numpy array); without
        it neither Python nor the page warns.
    """
    out = {"extrapolation_factor": float(EXTRAPOLATION_FACTOR)}
    reach = training_reach(P, samples)
    if reach is not None:
        out["reach"] = np.asarray(reach, np.float64)
    return out


def surface_payload(surface, n_vertices):
    """The user's surface for the 3D page: the page draws it where the tetrahedra carry it (``makeSurface`` of
    ``static/defop_solid.js``, as :meth:`defop.geometry.volumetric.surface.EmbeddedSurface.deform`).

    Parameters
    ----------
    surface : defop.geometry.volumetric.surface.EmbeddedSurface
        Embedded in the operator's tetrahedra.
    n_vertices : int
        The operator's vertices (the surface's tetrahedra must index them).

    Returns
    -------
    payload : dict
        ``surface_F`` ((l,3) int32: the surface's triangles), ``surface_tets`` ((k,4) int32: the tetrahedron's
        vertices of each surface vertex) and ``surface_bary`` ((k,3) float32: its barycentric coordinates b_1, b_2,
        b_3; the page takes b_0 = 1 − b_1 − b_2 − b_3 in float64, so the weights sum to 1 and a one-hot b stays
        exact).

    Raises
    ------
    ValueError
        The surface is embedded in other tetrahedra (an index beyond ``n_vertices``) or is not finite.
    """
    tets = np.asarray(surface.tets)[np.asarray(surface.elements)]
    bary = np.asarray(surface.bary, float)
    if tets.ndim != 2 or tets.shape[1] != 4 or tets.min(initial=0) < 0 or tets.max(initial=0) >= n_vertices:
        raise ValueError(f"shape.surface is embedded in other tetrahedra than the operator's {n_vertices} vertices")
    if bary.shape != tets.shape or not np.isfinite(bary).all():
        raise ValueError(f"shape.surface: bary must be a finite {tets.shape} array, got {bary.shape}")
    return {
        "surface_F": np.asarray(surface.F, np.int32),
        "surface_tets": tets.astype(np.int32),
        "surface_bary": bary[:, 1:].astype(np.float32),
    }


#: the keys of :func:`defop_to_payload` every branch of a multi-valued operator shares (the mesh and its handles)
_SHARED = ("d", "n_vertices", "regions", "P", "V", "F", "E", "handles", "moving", "reach", "extrapolation_factor")


def branched_to_payload(bop, regions=None):
    """The page's payload of a multi-valued operator (:class:`defop.operator.branched.BranchedOperator`, 2D).

    Branch 0's :func:`defop_to_payload` (the mesh, regions and, unprefixed, its operator), then for every branch
    b its operator's own keys as ``branch{b}.name`` (Ψ, factors) and the coefficients of its closed forms
    ``branch{b}.energy_w``, ``.score_w`` (E_b, s_b = ψ_b(Q) · w, float64), its domain g_b (:func:`domain_payload`)
    and ``box`` (the samples' box, enlarged by one spacing): the domain test of :mod:`defop.operator.branched`,
    ported as ``makeBranched`` in ``static/defop_editor.js``.

    Parameters
    ----------
    bop : defop.operator.branched.BranchedOperator
    regions : list of list of (k,2) numpy array, optional
        As for :func:`defop_to_payload`; default: discs through the farthest training sample of any branch.

    Returns
    -------
    payload : dict
        That of branch 0 plus ``n_branches``, ``branch_labels`` and the prefixed keys.
    """
    own = [b.op.train_samples for b in bop.branches if b.op.train_samples is not None]
    samples = np.concatenate(own) if own else None  # every branch's: each branch covers only its domain
    if regions is None:
        regions = reach_polygons(bop.P, samples)
    p = defop_to_payload(bop.branches[0].op, regions)
    p.update(extrapolation_payload(bop.P, samples))
    p.update(n_branches=len(bop), branch_labels=[int(b.label) for b in bop.branches])
    for b in bop.branches:
        own = defop_to_payload(b.op, p["regions"])
        for name, value in own.items():
            if name not in _SHARED:
                p[f"branch{b.label}.{name}"] = value
        for name in ("energy_w", "score_w"):
            p[f"branch{b.label}.{name}"] = np.asarray(getattr(b, name), np.float64)
        p.update({f"branch{b.label}.{k}": v for k, v in domain_payload(b.domain).items()})
    p["box"] = np.asarray(bop.box, np.float64)
    return p


def domain_payload(domain):
    """The keys of a branch's domain g_b (:class:`defop.operator.domains.Domain`): ``domain_w`` and, for its own
    TPS, ``domain_own`` 1, ``domain_size``, ``domain_scale``, ``domain_kernel`` and ``domain_centers`` (z, (m, dn))."""
    out = {"domain_w": np.asarray(domain.w, np.float64), "domain_own": int(domain.own)}
    if domain.own:
        basis = domain.basis
        out.update(
            domain_size=int(basis.size),
            domain_scale=float(basis.scale),
            domain_kernel=basis.kernel,
            domain_centers=np.asarray(basis.z(basis.centers), np.float64),
        )
    return out


def pixel_coordinates(mesh, image_frame):
    """The rest vertices in the picture's pixels, from a mesh → pixel map or the coordinates themselves.

    Parameters
    ----------
    mesh : defop.geometry.mesh.Mesh
    image_frame : callable or (n_vertices,2) numpy array
        ``to_pixels((k,2) mesh coordinates) -> (k,2) pixels``, e.g. the second result of
        :func:`defop.view.warp.image_to_mesh_frame` ``(mask, mesh)``; or the rest vertices already in pixels.
        Pixels as in :mod:`defop.view.warp`: x = column, y = row (down), pixel centres at integers.

    Returns
    -------
    V_px : (n_vertices,2) numpy array
    """
    V_px = image_frame(mesh.V) if callable(image_frame) else image_frame
    V_px = np.asarray(V_px, dtype=float)
    if V_px.shape != mesh.V.shape:
        raise ValueError(f"image_frame must give one pixel position per vertex, shape {mesh.V.shape}; got {V_px.shape}")
    bad = ~np.isfinite(V_px).all(axis=1)
    if bad.any():
        raise ValueError(f"image_frame gave a NaN or infinite pixel position (vertex {int(np.flatnonzero(bad)[0])})")
    return V_px


def _png(img):
    """PNG bytes of a float image in [0,1] ((H,W), (H,W,3) or (H,W,4)), 8 bits per channel."""
    import io

    from PIL import Image  # pillow: matplotlib's own image library

    out = io.BytesIO()
    Image.fromarray(np.round(img * 255).astype(np.uint8)).save(out, format="png", optimize=False)
    return out.getvalue()


def image_payload(image, V_px):
    """A picture as the page's texture: PNG bytes and one texture coordinate per vertex.

    Parameters
    ----------
    image : (H,W), (H,W,3) or (H,W,4) numpy array, or path
        Grey, RGB or RGBA; bool, integer or float in [0,1] (validated by
        :func:`defop.geometry.planar.outlines.load_image`).
    V_px : (n_vertices,2) numpy array
        The rest vertices in the picture's pixels (:func:`pixel_coordinates`): x = column, y = row.

    Returns
    -------
    payload : dict
        ``image_png`` ((bytes,) uint8 numpy array), ``uv`` ((n_vertices,2) float32 numpy array: texture
        coordinates, ``(V_px + ½) / (W, H)``, the origin at the top-left corner of the first pixel, v down) and
        ``image_size`` ([W, H]).

    Raises
    ------
    ValueError
        A bad picture (dtype, layout, NaN, empty, values outside [0,1]), a side above :data:`MAX_IMAGE_SIDE`,
        a PNG above :data:`MAX_IMAGE_BYTES`, or a vertex more than a pixel outside the picture (a wrong frame).
    """
    img = load_image(image)
    H, W = img.shape[:2]
    if max(H, W) > MAX_IMAGE_SIDE:
        raise ValueError(
            f"the picture is {W} x {H} pixels; the page takes at most {MAX_IMAGE_SIDE} per side "
            f"(downscale it, e.g. skimage.transform.rescale, and its pixel frame with it)"
        )
    V_px = np.asarray(V_px, dtype=float)
    if V_px.ndim != 2 or V_px.shape[1] != 2 or not np.isfinite(V_px).all():
        raise ValueError(f"V_px must be a finite (n_vertices, 2) array, got shape {V_px.shape}")
    lo, hi = np.array([-0.5, -0.5]), np.array([W - 0.5, H - 0.5])  # the picture's outer pixel edges
    gap = np.maximum(lo - V_px, 0).max(axis=1) + np.maximum(V_px - hi, 0).max(axis=1)
    if gap.max() > 1.0:
        i = int(np.argmax(gap))
        raise ValueError(
            f"vertex {i} maps to pixel ({V_px[i, 0]:.1f}, {V_px[i, 1]:.1f}), {gap[i]:.1f} px outside "
            f"the {W} x {H} picture: image_frame must map the mesh to this picture's pixels "
            f"(x = column, y = row down)"
        )
    png = _png(img)
    if len(png) > MAX_IMAGE_BYTES:
        raise ValueError(
            f"the picture is {len(png) / 2**20:.1f} MiB as PNG; the page takes at most "
            f"{MAX_IMAGE_BYTES / 2**20:.0f} MiB (downscale it)"
        )
    uv = ((V_px + 0.5) / [W, H]).astype(np.float32)
    return {"image_png": np.frombuffer(png, np.uint8), "uv": uv, "image_size": [int(W), int(H)]}


def encode_payload(payload):
    """Split a payload into JSON metadata and one byte buffer (arrays at 8-byte-aligned offsets).

    Returns
    -------
    meta : dict
        ``{"scalars": {...}, "arrays": {name: {"dtype", "shape", "offset", "length"}}}``
    data : bytes
    """
    codes = {np.dtype(v): k for k, v in _DTYPES.items()}
    scalars, arrays, chunks, offset = {}, {}, [], 0
    for name, value in payload.items():
        if not isinstance(value, np.ndarray):
            scalars[name] = value
            continue
        a = np.ascontiguousarray(value)
        raw = a.tobytes()
        arrays[name] = {"dtype": codes[a.dtype], "shape": list(a.shape), "offset": offset, "length": int(a.size)}
        pad = -len(raw) % 8
        chunks.append(raw + b"\0" * pad)
        offset += len(raw) + pad
    return {"scalars": scalars, "arrays": arrays}, b"".join(chunks)


def image_for(mesh, image, image_frame):
    if image is None or image_frame is None:
        raise ValueError("image and image_frame go together: the picture and where the mesh lies in its pixels")
    return image_payload(image, pixel_coordinates(mesh, image_frame))
