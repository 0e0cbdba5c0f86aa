"""Labels that collide with nothing: each goes to the first spot around its point (in display units,
after the layout) that keeps it inside its axes and off the boxes already taken (other labels,
markers, legends), or to the spot that collides least. matplotlib only; no pyplot."""

from __future__ import annotations

import numpy as np

TURNS = (0, 1, -1, 2, -2, 3, -3, 4)
"""Directions tried around the point, in eighths of a turn from the first."""


def box_around(xy, half_w: float, half_h: float | None = None) -> np.ndarray:
    """A display box [x0, y0, x1, y1] centred on xy."""
    half_h = half_w if half_h is None else half_h
    return np.array([xy[0] - half_w, xy[1] - half_h, xy[0] + half_w, xy[1] + half_h])


def overlaps(a, b) -> bool:
    """Whether two display boxes [x0, y0, x1, y1] share more than a line."""
    return min(a[2], b[2]) > max(a[0], b[0]) and min(a[3], b[3]) > max(a[1], b[1])


def extent(bbox) -> np.ndarray:
    """A matplotlib Bbox as [x0, y0, x1, y1]."""
    return np.array([bbox.x0, bbox.y0, bbox.x1, bbox.y1])


def text_box(text, renderer) -> np.ndarray:
    """The display box [x0, y0, x1, y1] of a Text's words (an Annotation's without its arrow)."""
    from matplotlib.text import Annotation, Text

    if isinstance(text, Annotation):
        text.update_positions(renderer)
    return extent(Text.get_window_extent(text, renderer))


def text_half_size(ax, text: str, fontsize: float, renderer, pad: float = 2.0) -> np.ndarray:
    """Half the width and height [px] of `text` at `fontsize`, plus `pad`."""
    probe = ax.text(0, 0, text, fontsize=fontsize, transform=None)
    ext = probe.get_window_extent(renderer)
    probe.remove()
    return np.array([ext.width, ext.height]) / 2 + pad


def place(ax, text: str, xy, renderer, taken: list, *, fontsize: float = 8, radii=(10.0, 22.0, 40.0), start=np.pi / 4,
          extra_cost=None, arrow_from: int = 1, **annotate_kw):
    """Annotate the data point `xy` with `text` at the least colliding spot around it: 100 a spot
    outside the axes, 10 each taken box it overlaps, plus extra_cost(box) (say, 1 a sample on a
    shape to keep clear). Tries radii [pt] (from the point to the nearest side of the text) in
    turn, at angles from `start` [rad]; stops at the first spot of cost 0. Appends the label's box to
    `taken` and returns the annotation (with a thin line to the point from the `arrow_from`-th radius on)."""
    half = text_half_size(ax, text, fontsize, renderer)
    here = ax.transData.transform(xy)
    frame = extent(ax.get_window_extent(renderer))
    px = ax.figure.dpi / 72.0
    boxes = np.asarray(taken, dtype=np.float64).reshape(-1, 4)
    best = None
    for k, r in enumerate(radii):
        for turn in TURNS:
            a = start + turn * np.pi / 4
            u = np.array([np.cos(a), np.sin(a)])
            spot = here + u * (px * r + np.abs(u) @ half)  # the text's near side r from the point
            box = box_around(spot, *half)
            inside = box[0] >= frame[0] and box[1] >= frame[1] and box[2] <= frame[2] and box[3] <= frame[3]
            hits = (np.minimum(box[2], boxes[:, 2]) > np.maximum(box[0], boxes[:, 0])) & (
                np.minimum(box[3], boxes[:, 3]) > np.maximum(box[1], boxes[:, 1]))
            cost = 100 * (not inside) + 10 * int(hits.sum()) + (extra_cost(box) if extra_cost else 0)
            if best is None or cost < best[0]:
                best = (cost, spot, box, k)
            if cost == 0:
                break
        if best[0] == 0:
            break
    _, spot, box, k = best
    taken.append(box)
    arrow = {"arrowprops": {"arrowstyle": "-", "lw": 0.6, "color": "0.3", "shrinkA": 0, "shrinkB": 3}} if k >= arrow_from else {}
    ann = ax.annotate(text, xy, xytext=ax.transData.inverted().transform(spot), textcoords="data", fontsize=fontsize,
                      ha="center", va="center", **arrow, **annotate_kw)
    ann.set_in_layout(False)
    return ann


def marker_boxes(ax, points, half_px: float = 4.0) -> list:
    """Display boxes around data points (the markers a label should not hide)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return [box_around(p, half_px) for p in ax.transData.transform(pts)] if len(pts) else []
