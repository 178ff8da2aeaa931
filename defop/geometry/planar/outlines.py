"""Outlines from implicit fields and from images (silhouettes).

Procedural shapes are unions of tapered capsules and ellipses, given as "inside-ness" fields
(positive inside, about a distance near the boundary), sampled on a grid and contoured by contourpy.
All fields are element-wise arithmetic, never BLAS (``@``, ``np.dot``): the outline, and so the
Triangle mesh, is the same on every CPU.
"""

from __future__ import annotations

import math
import os
import re
import struct
import warnings
from pathlib import Path

import numpy as np

from ... import options as opt
from ..fields import capsule, chain, subtract, union  # noqa: F401  (dimension-generic; re-exported here)
from .polygon import points_in_polygon, polygon_area
from .silhouette import FOREGROUNDS as FOREGROUNDS  # re-exported
from .silhouette import foreground as foreground  # re-exported
from .silhouette import silhouette


# ------------------------------------------------------------------------------- level sets
def _level_set_loops(Z, x, y, level):
    """Closed contour loops of Z = level (Z > level is inside), outer loops CCW, holes CW."""
    import contourpy

    gen = contourpy.contour_generator(x, y, Z, line_type=contourpy.LineType.Separate)
    eps = 1e-9 * max(x[-1] - x[0], y[-1] - y[0])  # the contour passes a grid point: near-duplicate points
    loops = []
    for L in gen.lines(level):
        L = np.asarray(L)
        if len(L) > 1 and np.array_equal(L[0], L[-1]):
            L = L[:-1]
        d = L - np.roll(L, 1, axis=0)
        L = L[np.sqrt(d[:, 0] ** 2 + d[:, 1] ** 2) > eps]
        if len(L) >= 3 and abs(polygon_area(L)) > 0:
            loops.append(L)
    return loops


def outline_from_field(Z, x, y, level=0.0, min_area_frac=1e-3):
    """The largest component of {Z > level} as (outer, holes).

    Parameters
    ----------
    Z : (ny,nx) numpy array
    x : (nx,) numpy array
    y : (ny,) numpy array
    level : float
    min_area_frac : float
        Holes and separate regions smaller than this fraction of the outer area are dropped silently.
        Larger separate regions (outside the largest one, or islands in its holes) are dropped with a
        UserWarning: one mesh is one connected region.

    Returns
    -------
    outer : (k,2) numpy array or None
        None when the set is empty.
    holes : list of (l,2) numpy array
    """
    outer, holes, dropped, _ = field_components(Z, x, y, level, min_area_frac)
    if dropped:
        warnings.warn(
            f"the shape has {len(dropped) + 1} separate regions; kept the largest, dropped {len(dropped)} "
            f"(the largest dropped one has {max(dropped):.1%} of its area)",
            UserWarning,
            stacklevel=opt.user_stacklevel(),
        )
    return outer, holes


def field_components(Z, x, y, level=0.0, min_area_frac=1e-3):
    """:func:`outline_from_field` without its warning: what it keeps, and what it drops.

    Returns
    -------
    outer : (k,2) numpy array or None
    holes : list of (l,2) numpy array
    dropped : list of float
        Each separate region dropped (above ``min_area_frac``), as a fraction of the kept outer loop's area.
    lost : float
        The fraction of the area of {Z > level} outside the kept region (0 when nothing was dropped): the signed
        areas of every loop (outer loops counter-clockwise, holes clockwise) minus the kept region's.
    """
    loops = _level_set_loops(Z, x, y, level)
    if not loops:
        return None, [], [], 0.0
    signed = np.array([polygon_area(L) for L in loops])
    areas = np.abs(signed)
    order = np.argsort(-areas, kind="stable")
    outer = loops[order[0]]
    holes, dropped, kept = [], [], [int(order[0])]
    for k in order[1:]:
        L = loops[k]
        if areas[k] < min_area_frac * areas[order[0]]:
            continue
        # a loop inside the outer one is a hole unless it sits inside another hole (an island); islands and
        # loops outside the outer one are separate regions
        if points_in_polygon(L[:1], [outer])[0] and not any(points_in_polygon(L[:1], [h])[0] for h in holes):
            holes.append(L)
            kept.append(int(k))
        else:
            dropped.append(areas[k] / areas[order[0]])
    total = float(signed.sum())
    lost = max(0.0, (total - float(signed[kept].sum())) / total) if dropped and total > 0 else 0.0
    return outer, holes, dropped, lost


def implicit_outline(field, bbox, resolution=400):
    """Outline of {field > 0} sampled on a grid (for procedural shapes).

    Parameters
    ----------
    field : callable
        ``field(P (k,2)) -> (k,)``, positive inside.
    bbox : (2,2) array-like
        ``[[xmin, ymin], [xmax, ymax]]``.
    resolution : int
        Grid points along the longer side.

    Returns
    -------
    outer : (k,2) numpy array
    holes : list of (l,2) numpy array
    """
    (x0, y0), (x1, y1) = np.asarray(bbox, float)
    s = max(x1 - x0, y1 - y0) / resolution
    x = np.arange(x0, x1 + s, s)
    y = np.arange(y0, y1 + s, s)
    X, Y = np.meshgrid(x, y)
    Z = field(np.column_stack([X.ravel(), Y.ravel()])).reshape(X.shape)
    return outline_from_field(Z, x, y, 0.0)


def cos_sin(angle):
    """cos and sin of an angle, rounded to multiples of 2^-40.

    libm's last bit may differ between builds (glibc has FMA variants of sin/cos); rounding to a coarser
    grid makes such a difference vanish except with a probability of about 2^-12 per value.
    """
    g = 2.0**40
    return round(math.cos(angle) * g) / g, round(math.sin(angle) * g) / g


# --------------------------------------------- primitives: "inside-ness" fields, union by max
# capsule, chain, union and subtract are dimension-generic (defop.geometry.fields); the ellipse turns.
def ellipse(c, rx, ry, angle=0.0):
    """Ellipse field: scaled so that it behaves like a distance near the boundary.

    Returns
    -------
    f : callable, ``f(P (k,2)) -> (k,)``
    """
    c = np.asarray(c, float)
    ca, sa = cos_sin(angle)

    def f(P):
        px, py = P[:, 0] - c[0], P[:, 1] - c[1]
        u, v = px * ca + py * sa, py * ca - px * sa
        return min(rx, ry) * (1 - np.sqrt((u / rx) ** 2 + (v / ry) ** 2))

    return f


# ----------------------------------------------------------------------------------- images
def image_path(path, name="image"):
    """``path`` (str, bytes or os.PathLike) as a :class:`pathlib.Path` of an existing file.

    Raises
    ------
    ValueError
        No such file, a directory, or a path that is not a str, bytes or os.PathLike (naming ``name``).
    """
    if isinstance(path, bytes):
        path = os.fsdecode(path)  # bytes name a file, as they do for open()
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"{name} must be a path (str, bytes or pathlib.Path) or an array, got {type(path).__name__}")
    try:
        path = Path(path)
        exists, is_dir = path.exists(), path.is_dir()
    except (ValueError, OSError) as exc:  # an embedded NUL, a name too long
        raise ValueError(f"{name}: cannot use {str(path)!r:.200} as a file name ({exc})") from None
    if not exists:
        raise ValueError(f"no such image file: {path}")
    if is_dir:
        raise ValueError(f"image file {path} is a directory")
    return path


def read_image(path):
    """The pixels of an image file, as matplotlib's ``imread`` gives them (Pillow does the reading).

    8-bit PNGs become float32 in [0, 1] (the value / 255, palettes and grey + alpha as RGBA); other formats
    keep Pillow's integer pixels, which :func:`load_image` scales.

    Parameters
    ----------
    path : str, bytes or os.PathLike

    Returns
    -------
    (H,W), (H,W,3) or (H,W,4) numpy array

    Raises
    ------
    ValueError
        Naming the file: missing, not an image Pillow reads, truncated or corrupt, or declaring more pixels
        than Pillow's decompression-bomb limit ``PIL.Image.MAX_IMAGE_PIXELS`` (checked from the header,
        before the pixels are decoded).
    """
    from PIL import Image

    path = image_path(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as image:
                return _pixels(image)
    except (Image.DecompressionBombError, Image.DecompressionBombWarning) as exc:
        found = re.search(r"\((\d+) pixels\)", str(exc))  # Pillow: "Image size (3600000000 pixels) exceeds ..."
        size = f"{int(found.group(1)):,} pixels" if found else "too many pixels"
        raise ValueError(
            f"image file {path} declares {size}, more than Pillow's decompression-bomb limit "
            f"PIL.Image.MAX_IMAGE_PIXELS = {Image.MAX_IMAGE_PIXELS:,}; raise it to read a file you "
            f"trust"
        ) from None
    except Image.UnidentifiedImageError:
        raise ValueError(f"image file {path} is not an image Pillow can read") from None
    except PermissionError:
        raise  # an OSError that already names the file
    except MemoryError:
        raise ValueError(f"image file {path} is too large to decode in the memory available") from None
    except (OSError, SyntaxError, EOFError, ValueError, IndexError, TypeError, struct.error) as exc:
        why = str(exc) or type(exc).__name__  # Pillow: "image file is truncated (3 bytes not processed)", ...
        raise ValueError(f"image file {path} is truncated or corrupt: {why}") from None


def _pixels(image):
    from PIL import PngImagePlugin

    image.load()
    if not isinstance(image, PngImagePlugin.PngImageFile):
        return np.asarray(image)
    if image.mode in ("P", "LA"):
        image = image.convert("RGBA")
    if image.mode == "1":
        return np.asarray(image, np.float32)
    top = 2**16 - 1 if image.mode.startswith("I") else 2**8 - 1
    return np.divide(image, top, dtype=np.float32)


def load_image(image):
    """An image as a float array in [0,1]: (H,W), (H,W,3) or (H,W,4).

    Integer images are scaled by their type's maximum (255 for uint8), boolean ones map to 0/1.

    Parameters
    ----------
    image : numpy array, or a path (str, bytes or os.PathLike) read by :func:`read_image`

    Raises
    ------
    ValueError
        A missing, unreadable, truncated or too large file (naming it), a complex or non-numeric dtype, NaN,
        a layout other than (H,W), (H,W,3), (H,W,4), or floats outside [0,1].
    """
    if isinstance(image, (str, bytes, os.PathLike)):
        path = image_path(image)
        try:
            return _unit_image(read_image(path))
        except ValueError as exc:
            if str(path) in str(exc):
                raise
            raise ValueError(f"image file {path}: {exc}") from None  # decoded, but not a picture we can use
    return _unit_image(image)


def _unit_image(image):
    """The array checks and scaling of :func:`load_image`."""
    img = np.asarray(image)
    if img.dtype == bool:
        img = img.astype(float)
    elif np.issubdtype(img.dtype, np.integer):
        top = img.max(initial=0)
        img = img.astype(float) / (1.0 if top <= 1 else 255.0 if top <= 255 else float(np.iinfo(img.dtype).max))
    elif not np.issubdtype(img.dtype, np.floating):
        raise ValueError(f"an image must hold real numbers (bool, integer or float), got dtype {img.dtype}")
    img = np.asarray(img, float)
    layouts = "(H,W) grey, (H,W,3) RGB or (H,W,4) RGBA"
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] in (3, 4))):
        raise ValueError(f"an image must be {layouts}; got shape {img.shape}")
    if min(img.shape[:2]) < 3:
        raise ValueError(f"the image is too small to hold a shape: {img.shape[1]} x {img.shape[0]} pixels")
    if not np.isfinite(img).all():
        raise ValueError("the image has NaN or infinite values")
    if img.min() < 0 or img.max() > 1:
        raise ValueError(f"float image values must lie in [0,1], got [{img.min():.3g}, {img.max():.3g}]")
    return img


def _blur(Z, sigma):
    """Near-Gaussian blur by a binomial kernel (variance n/4 = sigma²), separable.

    The weights C(n,k)/2^n are exact dyadic numbers, so blurring a 0/1 mask is exact arithmetic: no
    ``exp`` (numpy's is CPU-dispatched, libm's has FMA variants), the same field on every CPU.
    """
    from scipy.ndimage import correlate1d

    n = max(2, 2 * round(2 * sigma * sigma))  # even: a centred kernel
    w = np.array([math.comb(n, k) for k in range(n + 1)], float) / 2.0**n
    return correlate1d(correlate1d(Z, w, axis=0, mode="reflect"), w, axis=1, mode="reflect")


def image_outline(image, threshold=None, smooth=1.0, foreground_mode="auto"):
    """Silhouette of an image as polygons (largest connected component, with its holes).

    Parameters
    ----------
    image : (H,W) or (H,W,3|4) numpy array, or a path to an image file
        See :func:`load_image`.
    threshold : float or None
        None (default): the automatic rule of :func:`silhouette`, the same for every picture. A number in (0,1):
        pixels whose foreground value (see :func:`foreground`) exceeds it are inside.
    smooth : float
        Blur radius (pixels, the standard deviation of a binomial kernel) before extracting the contour,
        to remove pixel stairs.
    foreground_mode : str
        See :func:`foreground`.

    Returns
    -------
    outer : (k,2) numpy array
        In pixel units, y up, origin at the bottom-left.
    holes : list of (l,2) numpy array

    Warns
    -----
    UserWarning
        When separate regions are dropped (one mesh is one connected region): how many, and the share of the
        foreground's area lost, naming ``threshold=``.

    Raises
    ------
    ValueError
        A bad image, or one with no foreground or only foreground (the message says which
        foreground was assumed).
    """
    mask, assumed = silhouette(load_image(image), threshold, foreground_mode)
    Z = np.pad(mask.astype(float), 2)
    if smooth:
        Z = _blur(Z, smooth)
    Z = Z[::-1]  # y up
    h, w = Z.shape
    outer, holes, dropped, lost = field_components(Z, np.arange(w) - 2.0, np.arange(h) - 2.0, 0.5)
    if outer is None:
        raise ValueError(f"the image has no foreground region large enough to mesh; assumed {assumed}")
    if dropped:
        warnings.warn(
            f"the picture's foreground has {len(dropped) + 1} separate regions; kept the largest, dropped "
            f"{len(dropped)} (the largest dropped one has {max(dropped):.1%} of its area): {lost:.1%} of the "
            f"foreground's area is lost. If they are one shape, join them in the picture or pass threshold= (a "
            f"number in (0,1): a pixel is inside when its foreground value exceeds it, so a lower one takes more "
            f"pixels); assumed {assumed}",
            UserWarning,
            stacklevel=opt.user_stacklevel(),
        )
    return outer, holes
