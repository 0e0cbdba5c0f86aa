"""A picture of one frame for people without a USD viewer: matplotlib, headless (Agg), no pyplot.

The organ's surface coloured by displacement (mm), the region's outline (the surface edges
between faces inside the region and faces outside), the probe as a shaft and tip; the whole organ
on the left, a close-up of the region on the right. matplotlib is imported only here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .output import atomic_path, check_writable

PNG_SUFFIXES = (".png",)


def check_png_path(path) -> Path:
    p = Path(path)
    if p.suffix.lower() not in PNG_SUFFIXES:
        raise InputError(f"{p}: a preview is a PNG file (allowed suffix: .png), got {p.suffix!r}")
    return check_writable(p)


@dataclass
class Snapshot:
    """What a preview draws, copied to the host at one step (SI units)."""

    positions: np.ndarray
    """Every vertex [m], [vertex_count, 3]."""
    vertex_ring: np.ndarray | None
    """Ring of every vertex (-1 outside), or None for a global model."""
    contact_vertex: int
    probe_tip: np.ndarray
    """[m]."""
    outward: np.ndarray
    """Unit outward normal at the contact at rest (the probe's axis)."""
    in_contact: bool
    force_N: float
    time_s: float

    @classmethod
    def of(cls, pal, time_s: float) -> "Snapshot":
        from ..sim.model import PROBE_OFF

        q = pal.positions()
        contact = pal.probe_mode != PROBE_OFF
        tip = q[pal.vertex] if contact else pal.rest_position()
        ring = pal.region.vertex_ring.numpy().copy() if pal.region is not None else None
        force = float(np.linalg.norm(pal.feedback_force)) if contact else 0.0
        return cls(q, ring, int(pal.vertex), np.asarray(tip, dtype=np.float64), -pal.inward_normal(), contact, force, float(time_s))


def region_outline(triangles: np.ndarray, vertex_ring: np.ndarray) -> np.ndarray:
    """Surface edges between a face inside the region (all corners in it) and one outside, [k, 2]."""
    tri = np.asarray(triangles, dtype=np.int64)
    inside = np.all(np.asarray(vertex_ring)[tri] >= 0, axis=1)
    edges = np.sort(tri[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    side = np.repeat(inside, 3)
    key = edges[:, 0] * (tri.max() + 1) + edges[:, 1]
    in_keys = np.unique(key[side])
    out_keys = np.unique(key[~side])
    both = np.intersect1d(in_keys, out_keys)
    first = {k: i for i, k in enumerate(key)}
    return edges[[first[k] for k in both]] if len(both) else np.zeros((0, 2), dtype=np.int64)


def _view(outward, elev):
    # look at the contact from the side of its normal, from `elev` degrees above the horizon
    azim = np.degrees(np.arctan2(outward[1], outward[0])) if np.hypot(outward[0], outward[1]) > 0.3 else -60.0
    return elev, azim


def _draw(ax, mesh, snap, faces, rest, cmap, norm, title, *, shaft_mm, elev):
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    p = snap.positions * 1e3
    disp = np.linalg.norm(snap.positions - rest, axis=1) * 1e3
    tri = mesh.triangles[faces]
    colors = cmap(norm(disp[tri].mean(axis=1)))
    # Lambert shading from a light over the viewer's shoulder, so the dent reads as a dent
    fn = np.cross(p[tri[:, 1]] - p[tri[:, 0]], p[tri[:, 2]] - p[tri[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)
    light = snap.outward + np.array([0.3, -0.3, 0.5])
    colors[:, :3] *= (0.45 + 0.55 * np.abs(fn @ (light / np.linalg.norm(light))))[:, None]
    ax.computed_zorder = False  # draw in the order given: surface, outline, probe
    ax.add_collection3d(Poly3DCollection(p[tri], facecolors=colors, edgecolors="none", linewidths=0, zorder=1))
    if snap.vertex_ring is not None:
        outline = region_outline(mesh.triangles, snap.vertex_ring)
        if len(outline):
            ax.add_collection3d(Line3DCollection(p[outline], colors="black", linewidths=1.4, zorder=2))
    tip = snap.probe_tip * 1e3
    shaft = tip + snap.outward * shaft_mm
    ax.plot(*np.stack([tip, shaft]).T, color="dimgray", linewidth=4, solid_capstyle="round", zorder=3)
    ax.scatter(*tip, color="black", s=30, depthshade=False, zorder=4)
    box = p[np.unique(tri)]
    lo, hi = box.min(axis=0), box.max(axis=0)
    lo, hi = np.minimum(lo, shaft), np.maximum(hi, shaft)
    span = np.maximum(hi - lo, 0.05 * (hi - lo).max())  # true proportions, no flat axis
    lo = (lo + hi) / 2 - span / 2
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(tuple(span / span.max()), zoom=1.1)
    ax.view_init(*_view(snap.outward, elev))
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x [mm]", fontsize=7)
    ax.set_ylabel("y [mm]", fontsize=7)
    ax.set_zlabel("z [mm]", fontsize=7)
    ax.tick_params(labelsize=6)
    from matplotlib.ticker import MaxNLocator

    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))


def render_png(path, mesh, snap: Snapshot, *, title: str = "") -> Path:
    """Draw `snap` of `mesh` to the PNG `path` (a temporary file, then a rename)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    p = check_png_path(path)
    rest = mesh.vertices
    disp = np.linalg.norm(snap.positions - rest, axis=1) * 1e3
    vmax = max(float(disp.max()), 1.0)  # at least 1 mm: float32 rounding at rest stays pale
    cmap = matplotlib.colormaps["magma_r"]
    norm = matplotlib.colors.Normalize(0.0, vmax)
    fig = Figure(figsize=(10.5, 4.8), dpi=90)
    FigureCanvasAgg(fig)
    everything = np.arange(mesh.triangle_count)
    # the close-up: faces with a corner within 1.2x the region's radius of the contact, seen lower
    if snap.vertex_ring is not None:
        inside = np.flatnonzero(snap.vertex_ring >= 0)
        radius = np.linalg.norm(rest[inside] - rest[snap.contact_vertex], axis=1).max()
    else:
        radius = 0.15 * np.ptp(rest, axis=0).max()
    near = np.linalg.norm(rest - rest[snap.contact_vertex], axis=1) <= 1.2 * max(radius, 1e-6)
    close = np.flatnonzero(np.any(near[mesh.triangles], axis=1))
    ax1 = fig.add_subplot(1, 2, 1, projection="3d")
    _draw(ax1, mesh, snap, everything, rest, cmap, norm, "whole organ", shaft_mm=25.0, elev=35.0)
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    close_title = "region (outlined) and probe" if snap.vertex_ring is not None else "around the probe"
    _draw(ax2, mesh, snap, close, rest, cmap, norm, close_title, shaft_mm=0.6 * radius * 1e3, elev=20.0)
    sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, ax=[ax1, ax2], shrink=0.7, pad=0.09, label="displacement [mm]")
    state = f"probe force {snap.force_N:.3f} N" if snap.in_contact else "probe lifted"
    fig.suptitle(f"{title}  t = {snap.time_s:.3f} s, {state}".strip(), fontsize=10)
    with atomic_path(p, ".tmp.png") as tmp:
        fig.savefig(tmp, format="png")
    return p
