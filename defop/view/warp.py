"""Piecewise-affine image warping by a deformed triangle mesh (notebook 13).

A picture is warped by its mesh: every output pixel inside a deformed triangle X[F_t] takes the colour of
the source image at the same barycentric coordinates in the rest triangle V[F_t]. Rasterisation and
sampling are vectorised over all (triangle, pixel) pairs; bilinear sampling is scipy's
``map_coordinates``. Coordinates are in pixels: x to the right (column), y down (row), pixel centres at
integers.
"""

from __future__ import annotations

import numpy as np

from .. import options as opt

#: outputs larger than this many pixels are refused (the rasteriser holds a few arrays of this size)
MAX_PIXELS = 10**8


def _check_points(name, X, n=None):
    """(n,2) finite float array, named in the message."""
    X = opt.real_array(name, X)
    if X.ndim != 2 or X.shape[1] != 2 or (n is not None and len(X) != n):
        want = f"({n}, 2)" if n is not None else "(n, 2)"
        raise ValueError(f"{name} must have shape {want}, got {X.shape}")
    if not np.isfinite(X).all():
        first = int(np.argwhere(~np.isfinite(X))[0, 0])
        raise ValueError(f"{name} has NaN or infinite entries (first at vertex {first})")
    return X


def _check_faces(F, n):
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or F.dtype.kind not in "iu":
        raise ValueError(f"F must be an (m, 3) integer array, got shape {F.shape} of dtype {F.dtype}")
    if len(F) and (F.min() < 0 or F.max() >= n):
        raise ValueError(f"F refers to vertex {int(F.max() if F.max() >= n else F.min())}; there are {n} vertices")
    return F.astype(np.int64, copy=False)


def _check_shape(shape):
    if np.ndim(shape) != 1 or len(shape) != 2:
        raise ValueError(f"shape must be (height, width), got {shape!r}")
    h, w = (opt.integer(name, v, minimum=1) for name, v in zip(("height", "width"), shape))
    if h * w > MAX_PIXELS:
        raise ValueError(f"shape {(h, w)} has {h * w:,} pixels, more than MAX_PIXELS = {MAX_PIXELS:,}")
    return h, w


def _candidates(T, shape):
    """All (triangle, pixel) pairs with the pixel centre in the triangle's bounding box, clipped to the image."""
    h, w = shape
    # clip before the integer cast: a vertex at 1e20 pixels overflowed int64 and the triangle drew nothing
    lo = np.ceil(np.clip(T.min(axis=1), -1.0, [w, h])).astype(np.int64)
    hi = np.floor(np.clip(T.max(axis=1), -1.0, [w, h])).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w - 1, h - 1])
    nx, ny = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    counts = nx * ny
    tri = np.repeat(np.arange(len(T)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    px = lo[tri, 0] + local % nx[tri]
    py = lo[tri, 1] + local // nx[tri]
    return tri, px, py


def rasterize(X, F, shape):
    """Which deformed triangle covers each pixel centre, and with which barycentric coordinates.

    Parameters
    ----------
    X : (n,2) numpy array
        Deformed vertices in pixels (x = column, y = row).
    F : (m,3) int numpy array
    shape : tuple of int
        (height, width) of the output.

    Returns
    -------
    face : (height,width) int numpy array
        The covering triangle, −1 outside the mesh (where triangles overlap, the last one wins).
    bary : (height,width,3) numpy array
        Barycentric coordinates in that triangle (0 outside).
    """
    X = _check_points("X", X)
    F = _check_faces(F, len(X))
    shape = _check_shape(shape)
    T = X[F]  # (m,3,2)
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    ok = np.flatnonzero(np.abs(det) > 1e-12)
    tri, px, py = _candidates(T[ok], shape)
    tri = ok[tri]
    # barycentric coordinates by Cramer's rule: [e1 e2] (l1, l2) = p − a
    inv_det = 1.0 / np.where(np.abs(det) > 1e-12, det, 1.0)
    dx, dy = px - T[tri, 0, 0], py - T[tri, 0, 1]
    l1 = (dx * e2[tri, 1] - dy * e2[tri, 0]) * inv_det[tri]
    l2 = (dy * e1[tri, 0] - dx * e1[tri, 1]) * inv_det[tri]
    l0 = 1.0 - l1 - l2
    inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
    tri, px, py = tri[inside], px[inside], py[inside]
    lam = np.column_stack([l0[inside], l1[inside], l2[inside]])
    face = np.full(shape, -1, dtype=np.int64)
    bary = np.zeros((*shape, 3))
    face[py, px] = tri
    bary[py, px] = lam
    return face, bary


def warp_image(image, V, X, F, shape=None, background=1.0):
    """Warp a picture by the map V → X, affine on each triangle.

    Parameters
    ----------
    image : (H,W) or (H,W,c) numpy array
        The source picture, floats.
    V : (n,2) numpy array
        Rest vertices in the source's pixels (x = column, y = row).
    X : (n,2) numpy array
        Deformed vertices in the output's pixels.
    F : (m,3) int numpy array
    shape : tuple of int, optional
        (height, width) of the output (default: the source's).
    background : float
        Value outside the deformed mesh.

    Returns
    -------
    out : numpy array
        The warped picture, (height,width) or (height,width,c).
    """
    from scipy.ndimage import map_coordinates

    image = opt.real_array("image", image)
    if image.ndim not in (2, 3) or 0 in image.shape:
        raise ValueError(f"image must be a non-empty (H, W) or (H, W, c) array, got shape {image.shape}")
    V = _check_points("V", V)
    X = _check_points("X", X, len(V))
    shape = _check_shape(image.shape[:2] if shape is None else shape)
    face, bary = rasterize(X, F, shape)
    inside = face >= 0
    b, corners = bary[inside], V[np.asarray(F)[face[inside]]]  # (k,3), (k,3,2)
    src = b[:, 0, None] * corners[:, 0] + b[:, 1, None] * corners[:, 1] + b[:, 2, None] * corners[:, 2]
    chans = image[..., None] if image.ndim == 2 else image
    out = np.full((*shape, chans.shape[2]), float(background))
    for c in range(chans.shape[2]):
        out[inside, c] = map_coordinates(chans[..., c], [src[:, 1], src[:, 0]], order=1, mode="nearest")
    return out[..., 0] if image.ndim == 2 else out


def _check_mask(mask):
    """An (H,W) boolean mask with at least one True pixel (0/1 numbers are accepted as booleans)."""
    arr = np.asarray(mask)
    if arr.ndim != 2:
        hint = "; for a picture, pass the silhouette, e.g. image.mean(axis=2) < 0.5" if arr.ndim == 3 else ""
        raise ValueError(f"mask must be an (H, W) array of booleans, got shape {arr.shape}{hint}")
    if arr.dtype != bool:
        if arr.dtype.kind not in "iuf" or not np.isin(arr, (0, 1)).all():
            raise ValueError(f"mask must be an (H, W) array of booleans (or 0/1), got dtype {arr.dtype} with "
                             f"values other than 0 and 1")
        arr = arr.astype(bool)
    if not arr.any():
        raise ValueError(f"mask has no True pixel: the shape is empty ({arr.shape[0]} x {arr.shape[1]} all False)")
    return arr


def image_to_mesh_frame(mask, mesh=None, size=1.0):
    """The similarity that takes pixels to the units of a mesh made by ``dop.shapes.from_image(mask)``.

    ``from_image`` puts the silhouette's bounding box at the origin, y up, scaled to a unit diagonal. This
    recovers that frame by matching the mesh's bounding box to the mask's (pixel edges), within a fraction of
    a pixel.

    Parameters
    ----------
    mask : (H,W) bool numpy array
        True on the shape.
    mesh : defop.geometry.mesh.Mesh, optional
        Without it, the frame ``from_image(mask, size=size)`` is expected to use (to place handles before
        meshing).
    size : float
        The ``size`` passed to ``from_image``.

    Returns
    -------
    to_mesh : callable
        (k,2) pixels (x = column, y = row) → (k,2) mesh coordinates.
    to_pixels : callable
        The inverse.

    Raises
    ------
    ValueError
        ``mask`` not a 2D array of booleans (or 0/1), or with no True pixel; ``size`` not a positive number.
    """
    mask = _check_mask(mask)
    rows, cols = np.nonzero(mask)
    H = mask.shape[0]
    lo = np.array([cols.min() - 0.5, (H - 1) - rows.max() - 0.5])  # bottom-left pixel edge, y up
    size_px = np.array([cols.max() - cols.min() + 1.0, rows.max() - rows.min() + 1.0])
    if mesh is None:
        size = opt.positive("size", size)
        scale, mesh_lo = size / np.linalg.norm(size_px), np.zeros(2)
    else:
        scale, mesh_lo = np.linalg.norm(np.ptp(mesh.V, axis=0)) / np.linalg.norm(size_px), mesh.V.min(axis=0)

    def to_mesh(p):
        p = np.asarray(p, dtype=float)
        up = np.column_stack([p[:, 0], (H - 1) - p[:, 1]])
        return (up - lo) * scale + mesh_lo

    def to_pixels(x):
        up = (np.asarray(x, dtype=float) - mesh_lo) / scale + lo
        return np.column_stack([up[:, 0], (H - 1) - up[:, 1]])

    return to_mesh, to_pixels
