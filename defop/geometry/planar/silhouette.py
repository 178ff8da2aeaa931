"""Which pixels of a picture are the shape: the foreground value of a pixel (:func:`foreground`) and the rule that
splits a picture into shape and background (:func:`silhouette`), one rule for grey, colour and RGBA pictures."""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["FOREGROUNDS", "MIN_CONTRAST", "foreground", "otsu_level", "silhouette"]

FOREGROUNDS = ("auto", "dark", "light", "alpha")
#: the automatic rule needs the split value (alpha, grey or colour distance, in [0,1] or [0, √3]) to vary by this
#: much: below it a picture is one colour with noise (an 8-bit picture's step is 1/255 = 0.004)
MIN_CONTRAST = 0.05


def foreground(img, mode="auto"):
    """How much each pixel is foreground, in [0,1], and a sentence saying what was assumed: what an explicit
    ``threshold=`` of :func:`silhouette` cuts.

    Parameters
    ----------
    img : (H,W), (H,W,3) or (H,W,4) numpy array in [0,1]
    mode : str
        ``"alpha"``: the alpha channel; ``"dark"``: dark shapes on a light background;
        ``"light"``: light shapes on a dark background; ``"auto"``: the alpha channel when it varies,
        otherwise whatever differs from the image border (a light border means a dark shape).
        Grey, RGB and RGBA layouts of the same picture give the same foreground.

    Returns
    -------
    fg : (H,W) numpy array
    assumed : str
    """
    if mode not in FOREGROUNDS:
        raise ValueError(f"foreground must be one of {FOREGROUNDS}, got {mode!r}")
    has_alpha = img.ndim == 3 and img.shape[2] == 4
    if mode == "alpha" or (mode == "auto" and has_alpha and np.ptp(img[..., 3]) > 0):
        if not has_alpha:
            raise ValueError(f"foreground='alpha' needs an (H,W,4) RGBA image, got shape {img.shape}")
        return img[..., 3], "the shape is the opaque part (alpha channel)"
    grey = img if img.ndim == 2 else img[..., :3].mean(axis=2)
    if mode == "auto":
        border = _border(grey)
        mode = "dark" if border.mean() >= 0.5 else "light"
        how = f"judged from the border, mean grey {border.mean():.2f}; pass foreground= to override"
    else:
        how = f"foreground={mode!r}"
    if mode == "dark":
        return 1.0 - grey, f"the shape is dark on a light background ({how})"
    return grey, f"the shape is light on a dark background ({how})"


def _border(a):
    """The pixels on the border of an (H,W,...) array, (2H + 2W, ...) (corners twice)."""
    return np.concatenate([a[0], a[-1], a[:, 0], a[:, -1]])


def otsu_level(value, bins=256):
    """Otsu's threshold: the level that splits the values in two with the largest between-class variance
    w₀ w₁ (μ₀ − μ₁)² (Otsu 1979), on a histogram of ``bins`` bins over [min, max], as
    :func:`skimage.filters.threshold_otsu` (here in numpy, so the core does not need scikit-image).

    Parameters
    ----------
    value : numpy array
        Not all equal.
    bins : int

    Returns
    -------
    level : float
        A bin centre: the values above it are one class.
    """
    counts, edges = np.histogram(value, bins=bins, range=(float(value.min()), float(value.max())))
    centres = (edges[:-1] + edges[1:]) / 2
    counts = counts.astype(float)
    w0, w1 = np.cumsum(counts), np.cumsum(counts[::-1])[::-1]
    with np.errstate(invalid="ignore", divide="ignore"):  # empty classes: 0/0, never the maximum
        m0 = np.cumsum(counts * centres) / w0
        m1 = (np.cumsum((counts * centres)[::-1]) / w1[::-1])[::-1]
    between = np.nan_to_num(w0[:-1] * w1[1:] * (m0[:-1] - m1[1:]) ** 2)
    return float(centres[int(np.argmax(between))])


def _separation(img, mode):
    """The one value per pixel the automatic rule splits, whether the split's high side is the shape (else the side
    touching the border less is), and what was assumed."""
    has_alpha = img.ndim == 3 and img.shape[2] == 4
    if mode == "alpha" or (mode == "auto" and has_alpha and np.ptp(img[..., 3]) >= 0.5):
        fg, assumed = foreground(img, "alpha")
        return fg, True, assumed
    if mode != "auto":
        fg, assumed = foreground(img, mode)
        return fg, True, assumed
    colour = img[..., :3] if img.ndim == 3 else img[..., None]
    background = np.median(_border(colour), axis=0)
    d = colour - background
    value = np.sqrt(sum(d[..., k] * d[..., k] for k in range(d.shape[-1])))  # element-wise: the same on every CPU
    what = "grey" if colour.shape[-1] == 1 else "colour"
    return value, False, f"the shape is what differs in {what} from the picture's border (foreground='auto')"


def silhouette(img, threshold=None, mode="auto"):
    """Which pixels are the shape.

    With ``threshold=None`` (the automatic rule, one for every picture): one value per pixel is split in two by
    Otsu's threshold (:func:`otsu_level`, the level halfway between the two sides' means, so an
    antialiased edge is cut where the shape covers half a pixel). The value is the alpha channel when it spans at
    least half its range (or with ``mode="alpha"``), the foreground of ``mode="dark"``/``"light"``, and otherwise
    the distance in colour (grey, or RGB) from the median colour of the picture's border; the shape is then the
    side that touches the picture's border less. So a shape of any colour on a background of any other colour
    keeps its area, dark on light or light on dark.

    With a number: the pixels whose :func:`foreground` value exceeds it.

    Parameters
    ----------
    img : (H,W), (H,W,3) or (H,W,4) numpy array in [0,1]
        See :func:`load_image`.
    threshold : float or None
        Strictly between 0 and 1, or None for the automatic rule.
    mode : str
        See :func:`foreground`.

    Returns
    -------
    mask : (H,W) bool numpy array
    assumed : str
        What was taken as the shape, for messages.

    Raises
    ------
    ValueError
        A bad ``threshold`` or ``mode``; a picture of one colour, or whose values span less than
        :data:`MIN_CONTRAST` (nothing to separate); with a number, no pixel or every pixel above it (the message
        names ``threshold=``).
    """
    if mode not in FOREGROUNDS:
        raise ValueError(f"foreground must be one of {FOREGROUNDS}, got {mode!r}")
    if threshold is not None:
        real = isinstance(threshold, numbers.Real) and not isinstance(threshold, (bool, np.bool_))
        if not (real and np.isfinite(threshold) and 0 < threshold < 1):
            raise ValueError(f"threshold must lie strictly between 0 and 1 (or None, automatic), got {threshold!r}")
        fg, assumed = foreground(img, mode)
        mask = fg > threshold
        if not mask.any():
            raise ValueError(
                f"the image has no foreground (no pixel above threshold={threshold}; lower it, or pass "
                f"threshold=None for the automatic rule); assumed {assumed}"
            )
        if mask.all():
            raise ValueError(
                f"the image is all foreground (every pixel above threshold={threshold}; raise it, or pass "
                f"threshold=None for the automatic rule); the silhouette needs a background around it; "
                f"assumed {assumed}"
            )
        return mask, assumed
    value, high_is_shape, assumed = _separation(img, mode)
    spread = float(np.ptp(value))
    if spread < MIN_CONTRAST:
        within = "" if spread == 0 else f" within {spread:.2g}, less than MIN_CONTRAST = {MIN_CONTRAST}"
        raise ValueError(
            f"the image has no foreground (every pixel is the same {'value' if high_is_shape else 'colour'}"
            f"{within}: no shape stands out from a background"
            + ("; pass threshold= to cut a faint one" if spread else "")
            + f"); assumed {assumed}"
        )
    level = otsu_level(value)
    mask = value > level
    if not high_is_shape and np.count_nonzero(_border(mask)) > np.count_nonzero(~_border(mask)):
        mask = ~mask  # the shape is the side that touches the border less
    return mask, f"{assumed}, split at Otsu's level {level:.3g}"
