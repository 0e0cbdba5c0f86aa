"""Every organ a volume: a closed surface tetrahedralized by fTetWild (pytetwild), finer near the probe.

fTetWild (Hu et al. 2020, "Fast Tetrahedral Meshing in the Wild") meshes the inside of the surface's
envelope: it accepts surfaces with self-intersections (the SOFA liver has them; TetGen and Gmsh refuse
it), and its output surface lies within `epsilon` x the bounding box's diagonal of the input, not on
its vertices. It is an optional dependency (the `volume` extra, docs/volume.md); without it
:func:`tetrahedralize` raises an InputError that says how to install it.
"""

from __future__ import annotations

import itertools
import math
import os
import tempfile

import numpy as np

from ..errors import InputError
from . import topology as topo
from .tissue_mesh import TissueMesh

VOLUME_CHOICES = ("off", "auto")
"""--volume and a scene's [mesh] volume: off, the mesh as read; auto, a closed surface given for a volumetric law
tetrahedralized, finest where it is pressed."""
RESOLVED_EDGE = 0.45
"""Edge / contact radius at which a press is resolved (docs/calibration.md, "Mesh independence", the rule)."""
SPLIT_RATIO = 4.0 / 3.0
"""fTetWild splits an edge longer than this x its target: the sizing field asks for the bound / this."""
GRADING = 0.5
"""How fast the target edge grows with the distance beyond the probe's disc [m per m]."""
BACKGROUND_CELLS = 40
"""Cells along the longest side of the sizing field's background grid."""
TETS_PER_EDGE_CUBE = 8.5
"""Tets fTetWild makes per cube of its target edge (a regular tet's volume is e^3 / 8.49; measured on
icospheres R 15-50 mm: 8.4-15, more where the surface is a larger share): the estimate of a mesh's size."""
MAX_TETS = 250_000
"""The most tets a surface is made into (about the estimate): beyond, fTetWild runs for many minutes and the
model's set-up with it (about 1,600 tets a second here: 52,000 in 33 s); the refusal says what makes it smaller."""

# the six tets of a cube around its diagonal 0-7 (corner c = i + 2j + 4k), the Freudenthal split:
# one per order of the axes, so that neighbouring cubes share their faces' diagonals
_KUHN = np.array([[0, 1 << a, (1 << a) | (1 << b), 7] for a, b in itertools.permutations(range(3), 2)], dtype=np.int64)


def contact_edge(probe_radius: float, depth: float, body_radius: float = math.inf) -> float:
    """The longest edge [m] that resolves a sphere of `probe_radius` [m] pressed `depth` [m] into a body
    of `body_radius` [m] (inf: a plane): RESOLVED_EDGE x the Hertz contact radius sqrt(R_eff d)."""
    r_eff = probe_radius if math.isinf(body_radius) else probe_radius * body_radius / (probe_radius + body_radius)
    return RESOLVED_EDGE * math.sqrt(r_eff * depth)


def tet_quality(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Each tet's mean ratio 12 (3|V|)^(2/3) / sum(l^2), signed by its volume: 1 for a regular tet,
    near 0 for a sliver, negative for an inverted one; shape [tet_count]."""
    p = np.asarray(vertices, dtype=np.float64)[np.asarray(tets, dtype=np.int64)]
    volume = topo.tet_signed_volumes(vertices, tets)
    l2 = sum(((p[:, a] - p[:, b]) ** 2).sum(axis=1) for a, b in itertools.combinations(range(4), 2))
    return np.sign(volume) * 12.0 * (3.0 * np.abs(volume)) ** (2.0 / 3.0) / np.maximum(l2, np.finfo(float).tiny)


def check_closed(surface: TissueMesh) -> None:
    """InputError unless `surface` is a surface mesh whose every edge joins exactly two triangles."""
    if surface.is_volume:
        raise InputError(f"{surface.name}: already a tetrahedral mesh ({surface.tet_count} tets); nothing to tetrahedralize")
    edges = np.sort(surface.triangles[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    for bad, what in ((counts > 2, "non-manifold: an edge of 3 or more triangles"), (counts == 1, "open: an edge on its border")):
        if bad.any():
            a, b = unique[np.argmax(bad)]
            raise InputError(f"{surface.name}: cannot tetrahedralize: the surface is {what} ({int(bad.sum())} such edges, "
                             f"first between vertices {a} and {b}); a volume needs a closed surface")


def sizing_field(lo, hi, edge: float, near=None, near_edge: float | None = None, near_radius: float = 0.0,
                 cells: int = BACKGROUND_CELLS):
    """A background tet grid over the box [lo, hi] and its target edge at each grid point [m]:
    near_edge within near_radius of `near` (a point [3] or points [k, 3]: the nearest counts), growing by
    GRADING with the distance beyond, at most `edge`.

    Each point takes the field's value one cell diagonal nearer to `near`, so that the linear
    interpolation inside a grid tet never exceeds the field. Returns (points [p, 3], tets [t, 4], values [p])."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    step = float((hi - lo).max()) / cells
    n = np.maximum(np.ceil((hi - lo) / step).astype(np.int64), 1)
    axes = [lo[k] + step * np.arange(n[k] + 1) for k in range(3)]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    ijk = np.stack(np.meshgrid(*(np.arange(m) for m in n), indexing="ij"), axis=-1).reshape(-1, 3)
    corner = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)])
    flat = lambda q: (q[..., 0] * (n[1] + 1) + q[..., 1]) * (n[2] + 1) + q[..., 2]  # noqa: E731
    cube = flat(ijk[:, None, :] + corner[None, :, :])  # [cells, 8]
    tets = cube[:, _KUHN].reshape(-1, 4)
    flip = topo.tet_signed_volumes(points, tets) < 0
    tets[flip] = tets[flip][:, [0, 1, 3, 2]]
    values = np.full(len(points), float(edge))
    if near is not None and near_edge is not None:
        gap = nearest_distance(points, near) - near_radius - step * math.sqrt(3.0)
        values = np.minimum(values, near_edge + GRADING * np.maximum(gap, 0.0))
    return points, tets.astype(np.int32), values


def nearest_distance(points, near) -> np.ndarray:
    """Each of `points` [p, 3]'s distance to the nearest of `near` (a point [3] or points [k, 3])."""
    from scipy.spatial import cKDTree

    near = np.asarray(near, dtype=np.float64).reshape(-1, 3)
    return cKDTree(near).query(np.asarray(points, dtype=np.float64))[0]


def estimate_tets(surface_mm, triangles, points, values) -> float:
    """About how many tets fTetWild makes of the closed surface (vertices [mm]) for the sizing field
    (sizing_field's grid points [mm] and target edges there [mm]): TETS_PER_EDGE_CUBE x the integral of
    1 / edge^3 over the inside, a cell's volume a grid point inside the surface (VTK's inside test,
    through pyvista: fTetWild's own dependency)."""
    import pyvista as pv

    step = float(np.min([np.diff(np.unique(points[:, k])).min(initial=np.inf) for k in range(3)]))
    faces = np.column_stack([np.full(len(triangles), 3), triangles]).ravel()
    cloud, shell = pv.PolyData(np.asarray(points, dtype=np.float64)), pv.PolyData(np.asarray(surface_mm, dtype=np.float64), faces)
    if hasattr(cloud, "select_interior_points"):  # pyvista >= 0.47
        inside = cloud.select_interior_points(shell, check_surface=False)["selected_points"]
    else:
        inside = cloud.select_enclosed_points(shell, check_surface=False)["SelectedPoints"]
    inside = np.asarray(inside, dtype=bool)
    return float(TETS_PER_EDGE_CUBE * step**3 * (np.asarray(values)[inside] ** -3.0).sum())


def check_size(name: str, estimate: float, max_tets: float, sizing: str) -> None:
    """InputError where the estimated tets exceed `max_tets`; `sizing` says what asked for the edges."""
    if estimate > max_tets:
        raise InputError(f"{name}: the tets would be about {estimate:,.0f} ({sizing}), more than {max_tets:,.0f}: "
                         f"press fewer points or a shorter path, with a larger probe or deeper (coarser edges), "
                         f"or --volume off / --wall membrane")


def _pytetwild():
    try:
        import pytetwild
    except ImportError as exc:
        raise InputError("tetrahedralizing a surface needs fTetWild: pip install 'almsdm_warp[volume]' "
                         f"(pytetwild and pyvista; docs/volume.md) ({exc})") from exc
    return pytetwild


def tetrahedralize(surface: TissueMesh, *, edge: float | None = None, near=None, near_edge: float | None = None,
                   near_radius: float | None = None, epsilon: float = 1e-3, threads: int = 1,
                   iterations: int = 20, max_tets: float | None = None) -> TissueMesh:
    """The volume inside a closed surface, as a TissueMesh of positively oriented tets.

    edge: target edge away from the probe [m] (default: the bounding box's diagonal / 20).
    near: a point [m] (the probe's contact), or points [k, 3] (a sweep's, a path's), where the edges are to be near_edge [m] or shorter
      (`contact_edge` gives the resolved one) within near_radius [m] (default 4 x near_edge), growing
      by GRADING beyond; without them the target edge is `edge` everywhere.
    epsilon: how far the new surface may lie from the input, as a fraction of the diagonal.
    threads: fTetWild's threads (1, the default, gives the same mesh on every run).
    iterations: fTetWild's optimization passes at most (its default 80 took twice as long on an
      icosphere for the same minimum mean ratio; docs/volume.md).
    max_tets: refuse (InputError) a field that would make more tets than this (estimate_tets), before fTetWild runs
      (default MAX_TETS, read when called).
    Raises InputError for an open or non-manifold surface, or when fTetWild is not installed.
    """
    check_closed(surface)
    tetwild = _pytetwild()
    x = surface.vertices * 1e3  # fTetWild in millimetres: its tolerances suit numbers of order one
    lo, hi = x.min(axis=0), x.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    edge_mm = diag / 20.0 if edge is None else edge * 1e3
    background, sizing = {}, f"target edge {edge_mm:.3g} mm"
    graded = near is not None and near_edge is not None
    radius = (4.0 * near_edge if near_radius is None else near_radius) if graded else 0.0
    pad = 0.05 * (hi - lo) + edge_mm
    v, t, s = sizing_field(lo - pad, hi + pad, edge_mm, np.asarray(near) * 1e3 if graded else None,
                           near_edge * 1e3 / SPLIT_RATIO if graded else None, radius * 1e3)
    if graded:
        background = {"bg_vertices": v, "bg_tets": t, "bg_values": s}
        count = len(np.asarray(near).reshape(-1, 3))
        sizing += f", {near_edge * 1e3:.3g} mm within {radius * 1e3:.3g} mm of {'the probe' if count == 1 else f'{count} points'}"
    check_size(surface.name, estimate_tets(x, surface.triangles, v, s), MAX_TETS if max_tets is None else max_tets, sizing)
    cwd = os.getcwd()
    with tempfile.TemporaryDirectory() as scratch:  # fTetWild writes __tracked_surface.stl into the cwd
        try:
            os.chdir(scratch)
            points, tets = tetwild.tetrahedralize(x, surface.triangles, edge_length_abs=edge_mm, epsilon=epsilon,
                                                  num_threads=threads, num_opt_iter=iterations, quiet=True, **background)
        except RuntimeError as exc:
            raise InputError(f"{surface.name}: fTetWild could not tetrahedralize the surface: {exc}") from exc
        finally:
            os.chdir(cwd)
    tets = np.asarray(tets, dtype=np.int64)
    if not len(tets):
        raise InputError(f"{surface.name}: fTetWild found no volume inside the surface (is it flat, or inside out?)")
    flip = topo.tet_signed_volumes(points, tets) < 0  # fTetWild's corner order is the other hand
    tets[flip] = tets[flip][:, [0, 1, 3, 2]]
    mesh = TissueMesh.from_arrays(points, None, tets, scale=1.0, path=surface.path)
    mesh.notes = (f"tetrahedralized by fTetWild: {mesh.tet_count} tets, {sizing}", *mesh.notes)
    return mesh
