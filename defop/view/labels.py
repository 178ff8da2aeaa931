"""Labels that do not overlap: placement with leader lines, and the check every figure passes (matplotlib).

:func:`place_labels` puts one text label beside each point of a scatter plot, at the first of a ring of candidate
offsets (right, above, below, left, then farther out) where it overlaps no other label, no marker and stays inside
the axes; a label moved away from its point gets a thin leader line to it. :func:`text_overlaps` lists the pairs
of texts of a figure whose drawn boxes overlap (tests/test_figure_text.py runs it on every figure of the lessons).
"""

from __future__ import annotations

import itertools

import numpy as np
from matplotlib.text import Text

__all__ = ["check_no_overlap", "place_labels", "text_extent", "text_overlaps", "visible_texts"]

# candidate directions, in the order tried: right, upper right, lower right, up, down, left, upper left, lower left
_DIRECTIONS = ((1, 0), (1, 1), (1, -1), (0, 1), (0, -1), (-1, 0), (-1, 1), (-1, -1))
_RADII = (5, 12, 22, 34, 48, 64)  # points


def _renderer(fig):
    fig.canvas.draw()
    return fig.canvas.get_renderer()


def _overlap(a, b, pad=0.0):
    """Overlap area of two display boxes (x0, y0, x1, y1), each grown by ``pad`` pixels."""
    w = min(a[2], b[2]) - max(a[0], b[0]) + 2 * pad
    h = min(a[3], b[3]) - max(a[1], b[1]) + 2 * pad
    return max(w, 0.0) * max(h, 0.0)


def _box(extent):
    return (extent.x0, extent.y0, extent.x1, extent.y1)


def _best_label(ax, renderer, xy, text, taken, frame, scale, place):
    """The cheapest of the candidate placements of one label (overlap with ``taken``, a large cost outside
    ``frame``; the first free one wins): its annotation (the others are removed) and its display box."""
    best = None
    for r, (dx, dy) in itertools.product(_RADII, _DIRECTIONS):
        norm = np.hypot(dx, dy)
        leader = dict(arrowstyle="-", color=place["color"], lw=0.6, shrinkA=1, shrinkB=3) if r > _RADII[0] else None
        ann = ax.annotate(
            text,
            xy,
            xytext=(r * dx / norm, r * dy / norm),
            textcoords="offset points",
            ha="left" if dx > 0 else "right" if dx < 0 else "center",
            va="bottom" if dy > 0 else "top" if dy < 0 else "center",
            fontsize=place["fontsize"],
            arrowprops=leader,
            **place["text_kw"],
        )
        box = _box(text_extent(ann, renderer))
        inside = box[0] >= frame[0] and box[1] >= frame[1] and box[2] <= frame[2] and box[3] <= frame[3]
        cost = sum(_overlap(box, t, pad=1.0 * scale) for t in taken) + (0.0 if inside else 1e6)
        if best is None or cost < best[0]:
            if best is not None:
                best[1].remove()
            best = (cost, ann, box)
        else:
            ann.remove()
        if cost == 0:
            break
    return best[1], best[2]


def place_labels(ax, x, y, texts, fontsize=7, marker_px=6.0, avoid=(), color="0.35", **text_kw):
    """Label each point (x[i], y[i]) with texts[i], with no label over another label, a marker or the axes' edge.

    Parameters
    ----------
    ax : matplotlib Axes
        Its limits and scales must be final (labels are placed in display coordinates).
    x, y : (k,) array_like
        Data coordinates of the points.
    texts : sequence of str
    fontsize : float
    marker_px : float
        Half the size, in pixels, of the box kept free around every point.
    avoid : sequence of matplotlib artists
        Further artists to keep clear of (e.g. the legend).
    color : colour
        Of the leader lines.

    Returns
    -------
    annotations : list of matplotlib.text.Annotation
        One per point, in the order given.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if not (x.shape == y.shape == (len(texts),)):
        raise ValueError(f"x, y and texts must have one entry per point, got {x.shape}, {y.shape} and {len(texts)}")
    fig = ax.figure
    renderer = _renderer(fig)
    frame = _box(ax.get_window_extent(renderer))
    points = ax.transData.transform(np.column_stack([x, y])) if len(x) else np.zeros((0, 2))
    taken = [(px - marker_px, py - marker_px, px + marker_px, py + marker_px) for px, py in points]
    taken += [_box(a.get_window_extent(renderer)) for a in avoid]
    out = []
    place = dict(fontsize=fontsize, color=color, text_kw=text_kw)
    for i in np.argsort(-points[:, 1], kind="stable") if len(x) else []:  # top to bottom
        ann, box = _best_label(ax, renderer, (x[i], y[i]), texts[i], taken, frame, fig.dpi / 72.0, place)
        taken.append(box)
        out.append((i, ann))
    return [ann for _, ann in sorted(out, key=lambda t: t[0])]


def text_extent(text, renderer):
    """Display box of a text alone (an annotation's leader line left out)."""
    if hasattr(text, "update_positions"):
        text.update_positions(renderer)
    return Text.get_window_extent(text, renderer)


def visible_texts(fig):
    """Every text a draw of the figure puts on the canvas (titles, labels, tick labels in view, annotations, legend
    entries), with its display box: the texts are recorded as they draw, so hidden axes and ticks out of view are
    left out."""
    drawn = []
    draw = Text.draw

    def recording(text, renderer):
        if text.get_visible() and text.get_text().strip() and text.get_alpha() != 0:
            drawn.append(text)
        return draw(text, renderer)

    Text.draw = recording
    try:
        renderer = _renderer(fig)
    finally:
        Text.draw = draw
    texts = []
    for t in dict.fromkeys(drawn):
        box = text_extent(t, renderer)
        if box.width > 0 and box.height > 0:
            texts.append((t, box))
    return texts


def text_overlaps(fig, tolerance=1.0):
    """Pairs of texts of ``fig`` whose drawn boxes overlap by more than ``tolerance`` square pixels.

    Returns
    -------
    overlaps : list of (str, str, float)
        The two texts and their overlap area in square pixels; empty when no two texts overlap.
    """
    texts = visible_texts(fig)
    found = []
    for (a, ba), (b, bb) in itertools.combinations(texts, 2):
        area = _overlap(_box(ba), _box(bb))
        if area > tolerance:
            found.append((a.get_text(), b.get_text(), area))
    return found


def check_no_overlap(fig, tolerance=1.0):
    """Raise ValueError naming the texts of ``fig`` that overlap (the notebooks call it on every figure they save).

    Returns
    -------
    fig : matplotlib Figure
        Unchanged, when no two texts overlap.
    """
    found = text_overlaps(fig, tolerance)
    if found:
        pairs = "; ".join(f"{a!r} over {b!r} ({area:.0f} px²)" for a, b, area in found[:8])
        raise ValueError(f"{len(found)} pairs of texts overlap in the figure: {pairs}")
    return fig
