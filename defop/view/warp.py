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

#: outputs larger than this many pixels are refused: the output itself is a float64 array of this size per channel
MAX_PIXELS = 10**8
#: output pixels rasterised and sampled at once: :func:`warp_image`'s memory beyond its input and output is a few
#: hundred bytes per tile pixel, whatever the output's size (measured at MAX_PIXELS, one uint8 channel: 82 MB
#: above the 909 MB of the interpreter, the input and the float64 output; 27 CPU s)
TILE_PIXELS = 2**18
#: (triangle, pixel) pairs tested at once within a tile (about 15 float arrays of this length)
CANDIDATE_BLOCK = 2**19
#: image dtypes scipy's ``map_coordinates`` samples exactly as their float64 cast (other dtypes are cast first)
_NATIVE = tuple(np.dtype(t) for t in ("u1", "u2", "i1", "i2", "i4", "f4", "f8"))


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


def _tiles(shape):
    """Boxes (r0, r1, c0, c1) of at most :data:`TILE_PIXELS` pixels covering an image of ``shape``, row-major."""
    h, w = shape
    cols = min(w, TILE_PIXELS)
    rows = max(1, TILE_PIXELS // cols)
    for r0 in range(0, h, rows):
        for c0 in range(0, w, cols):
            yield r0, min(r0 + rows, h), c0, min(c0 + cols, w)


def _boxes(T, box):
    """Per triangle, its first pixel (x, y) and pixel counts (nx, ny) of its bounding box clipped to ``box``."""
    r0, r1, c0, c1 = box
    # clip before the integer cast: a vertex at 1e20 pixels overflowed int64 and the triangle drew nothing
    lo = np.ceil(np.clip(T.min(axis=1), [c0 - 1.0, r0 - 1.0], [c1, r1])).astype(np.int64)
    hi = np.floor(np.clip(T.max(axis=1), [c0 - 1.0, r0 - 1.0], [c1, r1])).astype(np.int64)
    lo = np.maximum(lo, [c0, r0])
    hi = np.minimum(hi, [c1 - 1, r1 - 1])
    return lo, np.maximum(hi[:, 0] - lo[:, 0] + 1, 0), np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)


def _blocks(counts):
    """Consecutive index ranges [a, b) whose counts sum to at most :data:`CANDIDATE_BLOCK` (or one index)."""
    cum = np.concatenate([[0], np.cumsum(counts)])
    a = 0
    while a < len(counts):
        b = max(a + 1, int(np.searchsorted(cum, cum[a] + CANDIDATE_BLOCK, side="right")) - 1)
        yield a, b
        a = b


def _cover(T, det, box):
    """Which triangle covers each pixel centre of ``box`` (the last one where they overlap), and where in it.

    Parameters
    ----------
    T : (m,3,2) numpy array
        The deformed triangles, in pixels.
    det : (m,) numpy array
        Twice their signed areas.
    box : tuple of int
        (r0, r1, c0, c1), rows and columns of the tile.

    Returns
    -------
    face : (r1-r0,c1-c0) int numpy array
        −1 where no triangle covers the pixel.
    bary : (r1-r0,c1-c0,3) numpy array
    """
    r0, r1, c0, c1 = box
    face = np.full((r1 - r0, c1 - c0), -1, dtype=np.int64)
    bary = np.zeros((r1 - r0, c1 - c0, 3))
    ok = np.flatnonzero(np.abs(det) > 1e-12)
    lo, nx, ny = _boxes(T[ok], box)
    counts = nx * ny
    hit = np.flatnonzero(counts)
    ok, lo, nx, counts = ok[hit], lo[hit], nx[hit], counts[hit]
    inv_det = 1.0 / det[ok]
    e1, e2 = T[ok, 1] - T[ok, 0], T[ok, 2] - T[ok, 0]
    for a, b in _blocks(counts):  # in triangle order: the last triangle over a pixel wins, as without tiles
        c = counts[a:b]
        i = np.repeat(np.arange(a, b), c)
        local = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
        px, py = lo[i, 0] + local % nx[i], lo[i, 1] + local // nx[i]
        # barycentric coordinates by Cramer's rule: [e1 e2] (l1, l2) = p − a
        dx, dy = px - T[ok[i], 0, 0], py - T[ok[i], 0, 1]
        l1 = (dx * e2[i, 1] - dy * e2[i, 0]) * inv_det[i]
        l2 = (dy * e1[i, 0] - dx * e1[i, 1]) * inv_det[i]
        l0 = 1.0 - l1 - l2
        inside = (l0 >= -1e-9) & (l1 >= -1e-9) & (l2 >= -1e-9)
        face[py[inside] - r0, px[inside] - c0] = ok[i[inside]]
        bary[py[inside] - r0, px[inside] - c0] = np.column_stack([l0[inside], l1[inside], l2[inside]])
    return face, bary


def _triangles(X, F):
    """The deformed triangles T (m,3,2) and twice their signed areas (m,)."""
    T = X[F]
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    return T, e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]


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
    T, det = _triangles(X, F)
    face = np.empty(shape, dtype=np.int64)
    bary = np.empty((*shape, 3))
    for r0, r1, c0, c1 in _tiles(shape):
        face[r0:r1, c0:c1], bary[r0:r1, c0:c1] = _cover(T, det, (r0, r1, c0, c1))
    return face, bary


def warp_image(image, V, X, F, shape=None, background=1.0):
    """Warp a picture by the map V → X, affine on each triangle.

    The output is rasterised and sampled tile by tile (:data:`TILE_PIXELS`), so the memory beyond the input and
    the output stays bounded up to :data:`MAX_PIXELS`; integer and float32 images are sampled without a float64
    copy. Bit for bit the result of one tile.

    Parameters
    ----------
    image : (H,W) or (H,W,c) numpy array
        The source picture, real numbers (floats or integers).
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
    out : float numpy array
        The warped picture, (height,width) or (height,width,c).
    """
    from scipy.ndimage import map_coordinates

    image = opt.real_array("image", image, cast=False)
    if image.ndim not in (2, 3) or 0 in image.shape:
        raise ValueError(f"image must be a non-empty (H, W) or (H, W, c) array, got shape {image.shape}")
    V = _check_points("V", V)
    X = _check_points("X", X, len(V))
    F = _check_faces(F, len(X))
    shape = _check_shape(image.shape[:2] if shape is None else shape)
    T, det = _triangles(X, F)
    chans = image[..., None] if image.ndim == 2 else image
    if chans.dtype not in _NATIVE:  # sampled as its float64 cast would be: cast once
        chans = chans.astype(float)
    out = np.full((*shape, chans.shape[2]), float(background))
    for r0, r1, c0, c1 in _tiles(shape):
        face, bary = _cover(T, det, (r0, r1, c0, c1))
        inside = face >= 0
        b, corners = bary[inside], V[F[face[inside]]]  # (k,3), (k,3,2)
        src = b[:, 0, None] * corners[:, 0] + b[:, 1, None] * corners[:, 1] + b[:, 2, None] * corners[:, 2]
        for c in range(chans.shape[2]):
            out[r0:r1, c0:c1, c][inside] = map_coordinates(
                chans[..., c], [src[:, 1], src[:, 0]], order=1, mode="nearest", output=np.float64
            )
    return out[..., 0] if image.ndim == 2 else out


def _check_mask(mask):
    """An (H,W) boolean mask with at least one True pixel (0/1 numbers are accepted as booleans)."""
    arr = np.asarray(mask)
    if arr.ndim != 2:
        hint = "; for a picture, pass the silhouette, e.g. image.mean(axis=2) < 0.5" if arr.ndim == 3 else ""
        raise ValueError(f"mask must be an (H, W) array of booleans, got shape {arr.shape}{hint}")
    if arr.dtype != bool:
        if arr.dtype.kind not in "iuf" or not np.isin(arr, (0, 1)).all():
            raise ValueError(
                f"mask must be an (H, W) array of booleans (or 0/1), got dtype {arr.dtype} with "
                f"values other than 0 and 1"
            )
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
