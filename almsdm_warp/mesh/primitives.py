"""Meshes the project makes itself: a triangulated sphere, a tetrahedral ball, tetrahedral boxes.

Sizes go in in millimetres. The ``*_arrays`` functions return raw arrays in metres for numerical
references (the finite-element solve in :mod:`almsdm_warp.evaluation.fem`); the others return a
validated :class:`TissueMesh` built from the same arrays, as a mesh file would be loaded.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from . import topology as topo
from .tissue_mesh import TissueMesh

SLIVER_TOL = 1e-3
"""Tets with volume below this x edge^3 (a regular tet has 0.118 edge^3) are dropped from the ball."""

# Kuhn (Freudenthal) split of the unit cube into 6 tets around the diagonal (0,0,0)-(1,1,1):
# one tet per order of the three unit steps. Every cube uses the same diagonal direction, so the
# faces of neighbouring cubes match (a conforming mesh).
_KUHN_PATHS = ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0))


def _positive(name: str, value) -> float:
    value = float(value)
    if not np.isfinite(value) or value <= 0.0:
        raise InputError(f"{name} must be a positive number of millimetres, got {value!r}")
    return value


def _orient(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Tets with their last two vertices swapped where the volume is negative."""
    tets = tets.copy()
    flip = topo.tet_signed_volumes(vertices, tets) < 0.0
    tets[flip, 2], tets[flip, 3] = tets[flip, 3], tets[flip, 2].copy()
    return tets


# -- sphere surface --------------------------------------------------------------------------------
def icosphere_arrays(radius_mm: float, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """A subdivided icosahedron on a sphere centred at the origin: (vertices [m], triangles)."""
    from .io import import_trimesh

    trimesh = import_trimesh()

    radius_mm = _positive("radius_mm", radius_mm)
    if int(subdivisions) != subdivisions or not 0 <= subdivisions <= 7:
        raise InputError(f"subdivisions must be an integer in 0..7, got {subdivisions!r}")
    sphere = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=radius_mm)
    return np.asarray(sphere.vertices) * 1e-3, np.asarray(sphere.faces, dtype=np.int32)


def icosphere(radius_mm: float, subdivisions: int) -> TissueMesh:
    """A validated surface sphere of `radius_mm`, 10 x 4^s + 2 vertices for `subdivisions` s."""
    vertices_m, triangles = icosphere_arrays(radius_mm, subdivisions)
    return TissueMesh.from_arrays(vertices_m * 1e3, triangles=triangles, scale=1.0)


# -- tetrahedral ball ------------------------------------------------------------------------------
def _fibonacci_sphere(count: int, rng: np.random.Generator) -> np.ndarray:
    """`count` nearly evenly spread unit vectors (golden-angle spiral), randomly rotated."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (1.0 + 5.0**0.5) * k
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    points = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return points @ q.T


def _ball_points(radius: float, edge: float, rng: np.random.Generator) -> np.ndarray:
    """Points on concentric shells `edge` apart (each spread at about `edge`) plus the centre."""
    shells = max(1, int(round(radius / edge)))
    points = [np.zeros((1, 3))]
    for k in range(1, shells + 1):
        r = radius * k / shells
        # a triangulated sphere has about two triangles of area sqrt(3)/4 edge^2 per vertex
        count = max(4, int(round(4.0 * np.pi * r * r / (0.5 * 3.0**0.5 * edge * edge))))
        shell = _fibonacci_sphere(count, rng) * r
        if k < shells:  # jitter the inner shells: no four points cospherical with a fifth
            shell += rng.uniform(-0.05, 0.05, size=shell.shape) * edge
        points.append(shell)
    return np.concatenate(points)


def _peel_slivers(points: np.ndarray, tets: np.ndarray, min_volume: float) -> np.ndarray:
    """Remove tets of volume < min_volume that have a face on the boundary, until none has."""
    while True:
        faces = np.sort(tets[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3), axis=1)
        _, inverse, counts = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
        on_hull = (counts[inverse.ravel()] == 1).reshape(-1, 4).any(axis=1)
        drop = on_hull & (topo.tet_signed_volumes(points, tets) < min_volume)
        if not drop.any():
            return tets
        tets = tets[~drop]


def _grade_toward_top(points: np.ndarray, radius: float, refine: float) -> np.ndarray:
    """Pull points toward the top pole (0, 0, R) so that edges there are `refine` times shorter.

    Along each ray from the pole a distance s becomes s (a + (1 - a) s / 2R), a = 1 / refine:
    spacing x a at the pole, x (2 - a) at the far side. Points of the outer shell are put back
    on the sphere, so the surface stays exactly spherical.
    """
    pole = np.array([0.0, 0.0, radius])
    offset = points - pole
    s = np.linalg.norm(offset, axis=1, keepdims=True)
    a = 1.0 / refine
    moved = pole + offset * (a + (1.0 - a) * s / (2.0 * radius))
    outer = np.isclose(np.linalg.norm(points, axis=1), radius)
    moved[outer] *= radius / np.linalg.norm(moved[outer], axis=1, keepdims=True)
    return moved


def tet_ball_arrays(
    radius_mm: float, edge_mm: float, seed: int = 0, refine_top: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """A tetrahedral ball centred at the origin, edges about `edge_mm`: (vertices [m], tets).

    `refine_top` > 1 grades the mesh: edges that many times shorter at the top pole (0, 0, R), where
    a probe presses, and up to twice as long at the bottom (see _grade_toward_top).

    The Delaunay tetrahedralisation of points on concentric spherical shells; the outer shell lies
    exactly on the sphere, so the surface is a closed sphere-like polyhedron. Tets are positively
    oriented; slivers (volume < SLIVER_TOL x edge^3) on the hull are peeled off, layer by layer,
    which keeps the surface closed; those inside stay (their volume is positive).
    """
    from scipy.spatial import Delaunay

    radius = _positive("radius_mm", radius_mm)
    edge = _positive("edge_mm", edge_mm)
    if radius / edge > 200:
        raise InputError(f"radius_mm / edge_mm is {radius / edge:.0f}; more than 200 shells is too many")
    if not 1.0 <= float(refine_top) <= 10.0:
        raise InputError(f"refine_top must be in 1..10, got {refine_top!r}")
    points = _ball_points(radius, edge, np.random.default_rng(seed))
    if refine_top > 1.0:
        points = _grade_toward_top(points, radius, float(refine_top))
    tets = Delaunay(points).simplices.astype(np.int64)
    tets = _orient(points, tets)
    tets = _peel_slivers(points, tets, SLIVER_TOL * edge**3)
    used = np.unique(tets)
    index = np.full(len(points), -1, dtype=np.int64)
    index[used] = np.arange(len(used))
    return points[used] * 1e-3, index[tets].astype(np.int32)


def tet_ball(radius_mm: float, edge_mm: float, seed: int = 0, refine_top: float = 1.0) -> TissueMesh:
    """A validated tetrahedral ball of `radius_mm` with edges about `edge_mm` (see tet_ball_arrays)."""
    vertices_m, tets = tet_ball_arrays(radius_mm, edge_mm, seed, refine_top)
    return TissueMesh.from_arrays(vertices_m * 1e3, tetrahedra=tets, scale=1.0)


# -- tetrahedral boxes -----------------------------------------------------------------------------
def tet_grid_arrays(xs_mm, ys_mm, zs_mm) -> tuple[np.ndarray, np.ndarray]:
    """The tensor grid of three increasing coordinate lists [mm], 6 tets a cell: (vertices [m], tets).

    Graded lists (fine near a contact, coarse far away) make large blocks cheap.
    """
    axes = []
    for name, values in (("xs_mm", xs_mm), ("ys_mm", ys_mm), ("zs_mm", zs_mm)):
        values = np.asarray(values, dtype=np.float64).ravel()
        if len(values) < 2 or not np.isfinite(values).all() or (np.diff(values) <= 0).any():
            raise InputError(f"{name} must hold at least 2 finite, strictly increasing coordinates")
        axes.append(values)
    nx, ny, nz = (len(a) for a in axes)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    node = np.arange(nx * ny * nz).reshape(nx, ny, nz)
    cells = np.stack(np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij"), -1)
    cells = cells.reshape(-1, 3)
    tets = []
    for path in _KUHN_PATHS:
        corner = cells.copy()
        ids = [node[corner[:, 0], corner[:, 1], corner[:, 2]]]
        for axis in path:
            corner[:, axis] += 1
            ids.append(node[corner[:, 0], corner[:, 1], corner[:, 2]])
        tets.append(np.stack(ids, axis=1))
    tets = _orient(grid, np.concatenate(tets))
    return grid * 1e-3, tets.astype(np.int32)


def tet_box_arrays(size_mm, n) -> tuple[np.ndarray, np.ndarray]:
    """A box [0, sx] x [0, sy] x [0, sz] mm with n (or (nx, ny, nz)) cells a side: (vertices [m], tets)."""
    size = np.broadcast_to(np.asarray(size_mm, dtype=np.float64), (3,))
    cells = np.broadcast_to(np.asarray(n), (3,))
    for s in size:
        _positive("size_mm", s)
    if any(int(c) != c or c < 1 for c in cells):
        raise InputError(f"n must be a positive integer (or three), got {n!r}")
    return tet_grid_arrays(*(np.linspace(0.0, s, int(c) + 1) for s, c in zip(size, cells)))


def tet_box(size_mm, n) -> TissueMesh:
    """A validated tetrahedral box of `size_mm` (one size or three) with `n` cells a side (or three)."""
    vertices_m, tets = tet_box_arrays(size_mm, n)
    return TissueMesh.from_arrays(vertices_m * 1e3, tetrahedra=tets, scale=1.0)
