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
    probe_centre: np.ndarray
    """The sphere's centre [m], or the point probe's tip (probe_radius 0)."""
    outward: np.ndarray
    """Unit outward normal at the contact at rest (the probe's axis)."""
    in_contact: bool
    force_N: float
    time_s: float
    probe_radius: float = 0.0
    """The sphere's radius [m]; 0: the paper's point probe."""

    @classmethod
    def of(cls, pal, time_s: float) -> "Snapshot":
        from ..sim.model import PROBE_OFF, PROBE_SPHERE

        q = pal.positions()
        contact = pal.probe_mode != PROBE_OFF
        outward = -pal.inward_normal()
        if pal.probe_mode == PROBE_SPHERE:
            centre = pal.probe_target
        elif contact:
            centre = q[pal.vertex]
        else:  # lifted: drawn touching the contact at rest
            centre = pal.rest_position() + outward * pal.probe_radius
        ring = pal.region.vertex_ring.numpy().copy() if pal.region is not None else None
        force = float(np.linalg.norm(pal.feedback_force)) if contact else 0.0
        return cls(q, ring, int(pal.vertex), np.asarray(centre, dtype=np.float64), outward, contact, force, float(time_s),
                   float(pal.probe_radius))


def sphere_faces(centre_mm, radius_mm: float, rings: int = 12) -> np.ndarray:
    """Quads of a latitude-longitude sphere of `radius_mm` around `centre_mm` (every corner on it):
    [rings * 2 rings, 4, 3] mm."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, 2 * rings + 1)
    t, f = np.meshgrid(theta, phi, indexing="ij")
    p = np.stack([np.sin(t) * np.cos(f), np.sin(t) * np.sin(f), np.cos(t)], axis=-1) * radius_mm + np.asarray(centre_mm)
    return np.stack([p[:-1, :-1], p[:-1, 1:], p[1:, 1:], p[1:, :-1]], axis=2).reshape(-1, 4, 3)


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
    colors[:, :3] *= _brightness(_face_normals(p[tri]), snap.outward)[:, None]  # so the dent reads as a dent
    ax.computed_zorder = False  # draw in the order given: surface, outline, probe
    ax.add_collection3d(Poly3DCollection(p[tri], facecolors=colors, edgecolors="none", linewidths=0, zorder=1))
    if snap.vertex_ring is not None:
        outline = region_outline(mesh.triangles, snap.vertex_ring)
        drawn = np.zeros(len(p), dtype=bool)
        drawn[tri.ravel()] = True
        outline = outline[drawn[outline].all(axis=1)]  # the part in view
        if len(outline):
            ax.add_collection3d(Line3DCollection(p[outline], colors="black", linewidths=1.4, zorder=2))
    probe = _draw_probe(ax, snap, shaft_mm)
    _frame(ax, np.vstack([p[np.unique(tri)], probe]), snap.outward, elev, title)


def _face_normals(corners: np.ndarray) -> np.ndarray:
    """Unit normals of the triangles corners [k, 3, 3]."""
    fn = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    return fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)


def _brightness(normals: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Lambert brightness of faces with unit `normals` [k, 3] under a light over the viewer's shoulder."""
    light = outward + np.array([0.3, -0.3, 0.5])
    return 0.45 + 0.55 * np.abs(normals @ (light / np.linalg.norm(light)))


def _draw_probe(ax, snap, shaft_mm) -> np.ndarray:
    """The sphere to scale (or the point probe's tip) and its shaft along the outward normal; returns
    the points [mm] the view must hold."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    centre, radius = snap.probe_centre * 1e3, snap.probe_radius * 1e3
    top = centre + snap.outward * radius
    shaft = top + snap.outward * shaft_mm
    if radius > 0:
        quads = sphere_faces(centre, radius)
        shade = _brightness((quads.mean(axis=1) - centre) / radius, snap.outward)
        colors = np.column_stack([np.outer(shade, [0.6, 0.68, 0.8]), np.full(len(quads), 0.15)])  # the dent shows through
        ax.add_collection3d(Poly3DCollection(quads, facecolors=colors, edgecolors=(0.15, 0.25, 0.45, 0.45), linewidths=0.4,
                                             zorder=3, gid="probe sphere"))
    else:
        ax.scatter(*centre, color="black", s=30, depthshade=False, zorder=4)
    ax.plot(*np.stack([top, shaft]).T, color="dimgray", linewidth=3, solid_capstyle="round", zorder=4)
    return np.vstack([centre - radius, centre + radius, shaft])


def _frame(ax, points, outward, elev, title) -> None:
    """True proportions around `points` [mm], the view from the contact's side, every axis labelled in mm."""
    from matplotlib.ticker import MaxNLocator

    lo, hi = points.min(axis=0), points.max(axis=0)
    span = np.maximum(hi - lo, 0.05 * (hi - lo).max())  # true proportions, no flat axis
    lo = (lo + hi) / 2 - span / 2
    ax.set_xlim(lo[0], lo[0] + span[0])
    ax.set_ylim(lo[1], lo[1] + span[1])
    ax.set_zlim(lo[2], lo[2] + span[2])
    ax.set_box_aspect(tuple(span / span.max()), zoom=0.85)  # room for the labels inside the axes
    ax.view_init(*_view(outward, elev))
    ax.set_title(title, fontsize=9)
    for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
        axis.set_major_locator(MaxNLocator(4))
        axis.set_label_text(f"{name} [mm]", fontsize=8)
        axis.labelpad = 2
    ax.tick_params(labelsize=6, pad=0)


def _close_up(mesh, snap: Snapshot):
    """The close-up's faces (a corner within 1.2x the region's radius of the contact, at least 1.5 sphere
    radii, at most 5 sphere radii or 30% of the organ: a region of the whole organ is no close-up) and
    that radius [m]."""
    rest = mesh.vertices
    if snap.vertex_ring is not None:
        inside = np.flatnonzero(snap.vertex_ring >= 0)
        radius = 1.2 * np.linalg.norm(rest[inside] - rest[snap.contact_vertex], axis=1).max()
    else:
        radius = 0.15 * np.ptp(rest, axis=0).max()
    radius = max(min(radius, max(5 * snap.probe_radius, 0.3 * np.ptp(rest, axis=0).max())), 1.5 * snap.probe_radius, 1e-6)
    near = np.linalg.norm(rest - rest[snap.contact_vertex], axis=1) <= radius
    return np.flatnonzero(np.any(near[mesh.triangles], axis=1)), radius


def preview_figure(mesh, snap: Snapshot, *, title: str = ""):
    """The figure of `snap` of `mesh` (matplotlib Figure, not yet saved): the whole organ and a close-up."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rest = mesh.vertices
    disp = np.linalg.norm(snap.positions - rest, axis=1) * 1e3
    vmax = max(float(disp.max()), 1.0)  # at least 1 mm: float32 rounding at rest stays pale
    cmap = matplotlib.colormaps["magma_r"]
    norm = matplotlib.colors.Normalize(0.0, vmax)
    fig = Figure(figsize=(11, 5.0), dpi=90)
    FigureCanvasAgg(fig)
    everything = np.arange(mesh.triangle_count)
    close, radius = _close_up(mesh, snap)
    ax1 = fig.add_subplot(1, 2, 1, projection="3d")
    _draw(ax1, mesh, snap, everything, rest, cmap, norm, "whole organ", shaft_mm=25.0, elev=35.0)
    ax2 = fig.add_subplot(1, 2, 2, projection="3d")
    probe = f"a {snap.probe_radius * 1e3:g} mm sphere, to scale" if snap.probe_radius > 0 else "the point probe"
    if snap.vertex_ring is None:
        close_title = f"around {probe}"
    elif np.linalg.norm(rest[snap.vertex_ring >= 0] - rest[snap.contact_vertex], axis=1).max() <= radius:
        close_title = f"region (outlined) and {probe}"
    else:
        close_title = f"{radius * 1e3:.0f} mm around the contact (the region reaches farther) and {probe}"
    _draw(ax2, mesh, snap, close, rest, cmap, norm, close_title, shaft_mm=min(0.5 * radius * 1e3, 25.0), elev=20.0)
    fig.subplots_adjust(left=0.0, right=0.88, bottom=0.03, top=0.88, wspace=0.1)
    sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
    fig.colorbar(sm, cax=fig.add_axes((0.91, 0.2, 0.015, 0.6)), label="displacement [mm]")
    state = f"probe force {snap.force_N:.3f} N" if snap.in_contact else "probe lifted"
    fig.suptitle(f"{title}  t = {snap.time_s:.3f} s, {state}".strip(), fontsize=10)
    return fig


def render_png(path, mesh, snap: Snapshot, *, title: str = "") -> Path:
    """Draw `snap` of `mesh` to the PNG `path` (a temporary file, then a rename)."""
    p = check_png_path(path)
    fig = preview_figure(mesh, snap, title=title)
    with atomic_path(p, ".tmp.png") as tmp:
        fig.savefig(tmp, format="png")
    return p
