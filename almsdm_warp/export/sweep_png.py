"""A picture of a sweep: the organ seen from two opposite sides, coloured by the stiffness under the
probe where it was pressed and grey where it was not (matplotlib, Agg, no pyplot, no display).

Each view is an orthographic projection along one axis of the mesh (the one its bounding box is
thinnest along, so the map shows the most surface), drawn as a 2D map with both axes in mm at true
proportions. A face is coloured only where all three of its corners were pressed (the mean of the
three): nothing is extrapolated from the nearest pressed point. Every pressed point visible in a view
is a dot of its own colour; the stiffest and the softest point are marked and annotated in every
view, drawn hollow and "(behind)" in a view where the surface hides them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

NOT_PRESSED_GREY = 0.78
"""Grey level of a face with a corner that was never pressed."""
AXIS_NAMES = "xyz"


@dataclass(frozen=True)
class View:
    """An orthographic view along a mesh axis: the camera on the `sign` side of axis `axis`."""

    axis: int
    sign: int

    @property
    def camera(self) -> np.ndarray:
        """Unit vector from the organ toward the camera."""
        c = np.zeros(3)
        c[self.axis] = self.sign
        return c

    @property
    def plane(self) -> tuple[int, int]:
        """The mesh axes drawn across and up: (x, y) under a z view, (x, z) otherwise with z up."""
        return (0, 1) if self.axis == 2 else ((1, 2) if self.axis == 0 else (0, 2))

    @property
    def mirrored(self) -> bool:
        """Whether the across axis runs right to left (as seen from this side, not through the organ)."""
        a, b = self.plane
        return float(np.cross(np.eye(3)[a], np.eye(3)[b]) @ self.camera) < 0

    @property
    def name(self) -> str:
        side = {2: ("top", "bottom"), 1: ("back", "front"), 0: ("right", "left")}[self.axis][self.sign < 0]
        return f"{side}: seen from {'+' if self.sign > 0 else '-'}{AXIS_NAMES[self.axis]}"


def opposite_views(vertices_mm: np.ndarray) -> tuple[View, View]:
    """The two views along the axis the organ is thinnest along (the widest map), + side first."""
    axis = int(np.argmin(np.ptp(vertices_mm, axis=0)))
    return View(axis, 1), View(axis, -1)


def vertex_values(vertex_count: int, vertex: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Each vertex's value: the mean of the finite values pressed at it; NaN where it was never pressed
    (or only to a non-finite value)."""
    vertex, values = np.asarray(vertex, dtype=np.int64), np.asarray(values, dtype=np.float64)
    ok = np.isfinite(values)
    total = np.bincount(vertex[ok], weights=values[ok], minlength=vertex_count)
    count = np.bincount(vertex[ok], minlength=vertex_count)
    out = np.full(vertex_count, np.nan)
    np.divide(total, count, out=out, where=count > 0)
    return out


def face_values(triangles: np.ndarray, per_vertex: np.ndarray) -> np.ndarray:
    """Each face's value: the mean of its corners' where all three were pressed, else NaN."""
    return per_vertex[np.asarray(triangles)].mean(axis=1)  # a NaN corner makes the mean NaN


def extremes(columns: dict) -> dict:
    """Row of the stiffest and of the softest point of the table (finite stiffness only):
    {"stiffest": row, "softest": row}; empty when no point has a finite stiffness."""
    stiff = np.asarray(columns["stiffness_N_per_mm"], dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(stiff))
    if not len(ok):
        return {}
    return {"stiffest": int(ok[np.argmax(stiff[ok])]), "softest": int(ok[np.argmin(stiff[ok])])}


def hidden(points: np.ndarray, own: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, camera) -> np.ndarray:
    """Whether each surface point (at the vertex `own` [n]) is hidden in the orthographic view toward
    `camera`: a triangle that does not touch its vertex covers it nearer the camera. [n] bool."""
    camera = np.asarray(camera, dtype=np.float64)
    across = np.linalg.svd(camera[None, :])[2][1:]  # two unit vectors perpendicular to the camera
    tri = np.asarray(triangles, dtype=np.int64)
    i, t, bary = _covering(points @ across.T, (vertices @ across.T)[tri])
    keep = ~np.any(tri[t] == np.asarray(own)[i, None], axis=1)
    depth = np.einsum("ij,ij->i", bary, (vertices @ camera)[tri[t]])
    front = depth > points[i] @ camera + 1e-6 * np.ptp(vertices)
    out = np.zeros(len(points), dtype=bool)
    out[i[keep & front]] = True
    return out


def covered(points2d: np.ndarray, corners2d: np.ndarray) -> np.ndarray:
    """Whether each 2D point lies in one of the 2D triangles corners2d [m, 3, 2]. [n] bool."""
    out = np.zeros(len(points2d), dtype=bool)
    out[_covering(points2d, corners2d)[0]] = True
    return out


def _covering(points2d: np.ndarray, corners2d: np.ndarray):
    """The pairs (point i, triangle t) where triangle t covers point i, and the point's barycentric
    coordinates in it: (i [k], t [k], bary [k, 3]). Candidates by the triangles' centres (a k-d tree)."""
    from scipy.spatial import cKDTree

    if not len(corners2d) or not len(points2d):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    centre = corners2d.mean(axis=1)
    reach = float(np.linalg.norm(corners2d - centre[:, None], axis=2).max())
    near = cKDTree(centre).query_ball_point(points2d, reach * (1 + 1e-9) + 1e-12)
    i = np.repeat(np.arange(len(points2d)), [len(n) for n in near])
    t = np.fromiter((k for n in near for k in n), dtype=np.int64, count=len(i))
    bary = _barycentric(points2d[i], corners2d[t])
    inside = np.all(bary >= -1e-9, axis=1)
    return i[inside], t[inside], bary[inside]


def _barycentric(p: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of the 2D points p [k, 2] in the triangles corners [k, 3, 2] (NaN: degenerate)."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    e1, e2, d = b - a, c - a, p - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / det
        v = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / det
        return np.column_stack([1 - u - v, u, v])


def _shade(vertices: np.ndarray, triangles: np.ndarray, camera: np.ndarray) -> np.ndarray:
    """Lambert factor of each face lit from the camera, so the surface reads as a surface."""
    p = vertices[triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return 0.4 + 0.6 * np.abs(n @ camera)


def _draw_surface(ax, vertices, triangles, face_value, view: View, cmap, norm) -> None:
    """The faces, far to near (painter's order), coloured where pressed and grey elsewhere, shaded."""
    from matplotlib.collections import PolyCollection

    colors = np.tile([NOT_PRESSED_GREY, NOT_PRESSED_GREY, NOT_PRESSED_GREY, 1.0], (len(triangles), 1))
    pressed = np.isfinite(face_value)
    colors[pressed] = cmap(norm(face_value[pressed]))
    colors[:, :3] *= _shade(vertices, triangles, view.camera)[:, None]
    order = np.argsort(vertices[triangles].mean(axis=1) @ view.camera)  # the farthest first
    flat = vertices[:, list(view.plane)]
    ax.add_collection(PolyCollection(flat[triangles[order]], facecolors=colors[order], edgecolors="face",
                                     linewidths=0.3, zorder=1))  # edges in the face's colour: no seams


def _draw_view(ax, mesh_mm, columns, view: View, cmap, norm, lesion) -> None:
    """One view: the surface, the pressed points it shows, the lesion, the axes in mm."""
    vertices, triangles, per_vertex = mesh_mm
    _draw_surface(ax, vertices, triangles, face_values(triangles, per_vertex), view, cmap, norm)
    vertex = np.asarray(columns["vertex"], dtype=np.int64)
    stiff = np.asarray(columns["stiffness_N_per_mm"], dtype=np.float64)
    shown = ~hidden(vertices[vertex], vertex, vertices, triangles, view.camera) & np.isfinite(stiff)
    dots = vertices[vertex[shown]][:, list(view.plane)]
    size = _dot_size(dots, vertices[:, list(view.plane)])
    ax.scatter(*dots.T, c=stiff[shown], cmap=cmap, norm=norm, s=size, edgecolors="black",
               linewidths=0.35 if size >= 8 else 0.0, zorder=3)
    if lesion is not None:
        _draw_lesion(ax, lesion, list(view.plane))
    _frame(ax, vertices, view)


def _dot_size(dots: np.ndarray, flat: np.ndarray, map_pt: float = 330.0) -> float:
    """Marker area [pt^2] of the pressed points: 14 where they lie apart; where they crowd (the dots'
    mean spacing on a map about `map_pt` points wide under 12 pt) smaller and without an edge, so that
    the colours, not the edges, fill the map."""
    if not len(dots):
        return 14.0
    span = np.ptp(flat, axis=0)
    spacing_pt = np.sqrt(max(span[0] * span[1], 1e-12) / len(dots)) * map_pt / max(span.max(), 1e-12)
    return float(np.clip((0.45 * spacing_pt) ** 2, 1.0, 14.0))


def _draw_lesion(ax, lesion, plane) -> None:
    """The lesion's sphere as the circle it projects to (red, dashed: it lies inside, seen through)."""
    from matplotlib.patches import Circle

    centre_mm, radius_mm = np.asarray(lesion.center, dtype=np.float64) * 1e3, lesion.radius * 1e3
    ax.add_patch(Circle(centre_mm[plane], radius_mm, fill=False, ls="--", lw=1.2, ec="red", zorder=4))


def _frame(ax, vertices, view: View) -> None:
    """Axes in mm at true proportions, the across axis mirrored where the view is from behind."""
    a, b = view.plane
    pad = 0.1 * np.ptp(vertices, axis=0).max()
    lo, hi = vertices.min(axis=0) - pad, vertices.max(axis=0) + pad
    ax.set_xlim((hi[a], lo[a]) if view.mirrored else (lo[a], hi[a]))
    ax.set_ylim(lo[b], hi[b])
    ax.set_aspect("equal")
    ax.set_xlabel(f"{AXIS_NAMES[a]} [mm]" + (" (mirrored: seen from behind)" if view.mirrored else ""))
    ax.set_ylabel(f"{AXIS_NAMES[b]} [mm]")
    ax.set_title(view.name, fontsize=10)
    ax.grid(alpha=0.25, lw=0.5)


def _mark_extremes(ax, mesh_mm, columns, view: View, found: dict, colour, renderer) -> None:
    """The stiffest (star) and softest (triangle) point: filled where seen, hollow and '(behind)' where
    the surface hides them; each labelled with its stiffness in a spot off the organ (after the layout)."""
    from .labels import marker_boxes, place

    vertices, triangles, _ = mesh_mm
    plane = list(view.plane)
    silhouette = vertices[:, plane][triangles]
    vertex = np.asarray(columns["vertex"], dtype=np.int64)
    stiff = np.asarray(columns["stiffness_N_per_mm"], dtype=np.float64)
    spots = {k: vertices[vertex[r]] for k, r in found.items()}
    taken = marker_boxes(ax, [p[plane] for p in spots.values()], 9.0)
    centre = ax.transData.transform((vertices.max(axis=0) + vertices.min(axis=0))[plane] / 2)

    def on_organ(box):  # label samples that fall on the organ
        gx, gy = np.meshgrid(np.linspace(box[0], box[2], 7), np.linspace(box[1], box[3], 3))
        return int(covered(ax.transData.inverted().transform(np.column_stack([gx.ravel(), gy.ravel()])), silhouette).sum())

    for key, row in found.items():
        p = spots[key]
        behind = bool(hidden(p[None], vertex[row:row + 1], vertices, triangles, view.camera)[0])
        ax.scatter(*p[plane], s=190, marker="*" if key == "stiffest" else "v", zorder=5, linewidths=1.3,
                   edgecolors="black", facecolors="none" if behind else colour(stiff[row]),
                   linestyles="--" if behind else "-")
        out = ax.transData.transform(p[plane]) - centre  # away from the organ's centre first
        place(ax, f"{key} {stiff[row]:.3g} N/mm" + (" (behind)" if behind else ""), p[plane], renderer, taken,
              radii=(20.0, 40.0, 64.0), start=float(np.arctan2(out[1], out[0])), extra_cost=on_organ, arrow_from=0,
              zorder=6, bbox={"boxstyle": "round,pad=0.2", "fc": "white", "ec": "0.5", "lw": 0.5, "alpha": 0.9})


def _caption(columns, found: dict, pressed_vertices: int, vertex_count: int, lesion) -> str:
    lines = [f"{len(columns['vertex'])} presses at {pressed_vertices} of {vertex_count} vertices (dots); "
             "a face is coloured where all three corners were pressed, grey where not (never extrapolated)"
             + ("; red dashed circle: the lesion, seen through the surface" if lesion is not None else "")]
    for key in ("stiffest", "softest"):
        if key in found:
            r = found[key]
            xyz = ", ".join(f"{round(float(columns[c][r]), 1) + 0.0:.1f}" for c in ("x_mm", "y_mm", "z_mm"))
            lines.append(f"{key}: {columns['stiffness_N_per_mm'][r]:.4g} N/mm at vertex {int(columns['vertex'][r])} ({xyz}) mm")
    return "\n".join(lines)


def sweep_figure(mesh, columns: dict, title: str = "", lesion=None):
    """The figure of a sweep (matplotlib Figure, not yet saved). columns: a sweep table's (vertex,
    x_mm, y_mm, z_mm, stiffness_N_per_mm); lesion: a tissue.lesion.Lesion to outline, or None."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    vertices = np.asarray(mesh.vertices, dtype=np.float64) * 1e3
    mesh_mm = (vertices, np.asarray(mesh.triangles, dtype=np.int64),
               vertex_values(len(vertices), columns["vertex"], columns["stiffness_N_per_mm"]))
    stiff = np.asarray(columns["stiffness_N_per_mm"], dtype=np.float64)
    finite = stiff[np.isfinite(stiff)]
    lo, hi = (float(finite.min()), float(finite.max())) if len(finite) else (0.0, 1.0)
    norm = matplotlib.colors.Normalize(vmin=lo, vmax=hi if hi > lo else lo + 1e-9)
    cmap = matplotlib.colormaps["viridis"]
    found = extremes(columns)
    fig = Figure(figsize=(12.5, 6.4), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    views = opposite_views(vertices)
    for ax, view in zip(axes, views):
        _draw_view(ax, mesh_mm, columns, view, cmap, norm, lesion)
    fig.colorbar(matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap), ax=axes, shrink=0.8, label="stiffness under the probe [N/mm]")
    fig.suptitle(title)
    fig.text(0.01, 0.005, _caption(columns, found, int(np.isfinite(mesh_mm[2]).sum()), len(vertices), lesion), fontsize=8, va="bottom")
    fig.get_layout_engine().set(rect=(0, 0.07, 1, 0.93))
    fig.draw_without_rendering()  # the layout, so that the labels can be placed in display units
    fig.set_layout_engine("none")  # and kept: the labels stay inside their axes
    renderer = fig.canvas.get_renderer()
    for ax, view in zip(axes, views):
        _mark_extremes(ax, mesh_mm, columns, view, found, lambda v: cmap(norm(v)), renderer)
    return fig


def plot_sweep(mesh, columns: dict, path, title: str = "", lesion=None) -> Path:
    """Write sweep_figure(...) to the PNG `path` (a temporary file, then a rename)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError as exc:
        raise InputError("--png needs matplotlib: pip install matplotlib") from exc
    from .output import atomic_write

    fig = sweep_figure(mesh, columns, title, lesion)
    return atomic_write(Path(path), lambda tmp: fig.savefig(tmp, format="png"))
