"""A hollow organ's wall as a layer of tets: the surface extruded inward by its thickness.

Beside the membrane on a foundation (tissue/material.py: springs in the surface, anchors for what is
inside), a surface mesh of a material with a thickness t can be made a wall of tetrahedra that the
volumetric laws (neo-Hookean, corotational) press: each vertex x_i is offset along its inward unit
normal -n_i (area-weighted, sim.model.vertex_normals) to x_i - (k / L) t n_i, k = 0..L, in L layers of
height t / L no longer than the edge asked for; each triangle between two layers is a prism, split into
three tets by the sorted-vertex-index rule: with the triangle's vertex ids sorted, v0 < v1 < v2, and '
the next layer inward,

    (v0, v1, v2, v0'), (v1, v2, v0', v1'), (v2, v0', v1', v2')

which cuts each side quad (vi, vj, vj', vi'), i < j, along vj-vi': a choice made by the two ids alone, so
neighbouring prisms share their side faces' diagonals and the tets conform. Layer 0 is the surface
itself, with its vertex ids: a contact vertex of the surface is the same vertex of the wall.

The wall's inner surface is free: nothing inside holds it (the contents, which the membrane model's
foundation stands for, are not modelled; a support, --support or --fixed-below-mm, holds what is below
its plane as for any tet mesh). The inward offset folds where the wall is thicker than the surface's
radius of curvature (the normals meet inside it): `extrude_wall` refuses that before it makes a tet,
and refuses any tet that is not positive afterwards (a sharp fold the curvature estimate misses).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..mesh import topology as topo

WALL_CHOICES = ("membrane", "tets")
"""--wall and a scene's [tissue] wall: a surface with a thickness as a membrane on a foundation (springs), or
as a layer of tets (this module) for a volumetric law."""
FOLD = 0.9
"""The thickest wall allowed, as a fraction of the smallest convex radius of curvature (at 1 the inner layer
collapses to a point at a sphere's centre; beyond, it turns inside out)."""

# the three tets of a prism (v0, v1, v2) -> (v0', v1', v2'), corners as indices into [v0, v1, v2, v0', v1', v2']
_PRISM = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [2, 3, 4, 5]])


def vertex_curvature(vertices, triangles, normals) -> np.ndarray:
    """Each vertex's largest convex normal curvature [1/m] along its edges: 2 n_i . (x_i - x_j) / |x_i - x_j|^2
    (the circle through x_j tangent at x_i; 1/R on a sphere of radius R, <= 0 where flat or concave)."""
    e = topo.unique_edges(triangles)
    d = vertices[e[:, 0]] - vertices[e[:, 1]]
    l2 = np.maximum(np.einsum("ij,ij->i", d, d), np.finfo(float).tiny)
    kappa = np.zeros(len(vertices))
    for a, sign in ((0, 1.0), (1, -1.0)):
        np.maximum.at(kappa, e[:, a], sign * 2.0 * np.einsum("ij,ij->i", normals[e[:, a]], d) / l2)
    return kappa


def layer_count(thickness: float, edge: float) -> int:
    """Layers through a wall of `thickness` [m] whose height is at most `edge` [m] (at least one)."""
    return max(1, math.ceil(thickness / edge - 1e-9))


def prism_tets(triangles, vertex_count: int, layers: int) -> np.ndarray:
    """The tets [3 x triangles x layers, 4] of the prisms between layer k (ids k n + i) and k + 1, each split by
    the sorted-vertex-index rule (module docstring); corner order as split (orientation not yet fixed)."""
    tri = np.sort(np.asarray(triangles, dtype=np.int64), axis=1)
    out = []
    for k in range(layers):
        six = np.concatenate([tri + k * vertex_count, tri + (k + 1) * vertex_count], axis=1)
        out.append(six[:, _PRISM].reshape(-1, 4))
    return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)


def extrude_wall(surface, thickness: float, edge: float | None = None, max_tets: float | None = None):
    """The wall of `surface` (a TissueMesh of triangles, metres) `thickness` [m] thick as a TissueMesh of
    positive tets, in layers at most `edge` [m] high (default: the surface's mean edge). InputError where the
    thickness is not > 0, the surface has tets, or the wall would fold (thicker than FOLD x the smallest convex
    radius of curvature, or a tet not positive): one line naming the vertex or tet; and where it would take more
    than `max_tets` tets (default mesh.volume.MAX_TETS)."""
    from ..mesh.tissue_mesh import TissueMesh
    from ..mesh.volume import MAX_TETS, check_size
    from ..sim.model import vertex_normals

    if surface.is_volume:
        raise InputError(f"{surface.name}: already a tetrahedral mesh ({surface.tet_count} tets): a wall is made of a surface")
    if not (thickness > 0 and math.isfinite(thickness)):
        raise InputError(f"{surface.name}: a wall of tets needs a thickness > 0 (--thickness-mm, [tissue] thickness_mm), got {thickness!r} m")
    x = np.asarray(surface.vertices, dtype=np.float64)
    tri = np.asarray(surface.triangles, dtype=np.int64)
    n = vertex_normals(x, tri)
    kappa = vertex_curvature(x, tri, n)
    worst = int(np.argmax(kappa))
    if kappa[worst] * thickness >= FOLD:
        raise InputError(f"{surface.name}: a wall {thickness * 1e3:g} mm thick folds at vertex {worst}, where the surface curves "
                         f"with a radius of {1e3 / kappa[worst]:.3g} mm (the inward offset allows at most {FOLD:g} x that): "
                         f"give a thinner wall, a smoother surface, or --wall membrane")
    edge = float(surface.edge_rest_length.mean()) if edge is None else float(edge)
    layers = layer_count(thickness, edge)
    check_size(surface.name, 3 * len(tri) * layers, MAX_TETS if max_tets is None else max_tets,
               f"{layers} layers of {thickness / layers * 1e3:.3g} mm under {len(tri)} triangles")
    points = np.concatenate([x - (k * thickness / layers) * n for k in range(layers + 1)])
    tets = prism_tets(tri, len(x), layers)
    volume = topo.tet_signed_volumes(points, tets)
    expected = _split_sign(tri)  # each prism's tets' sign when it is not folded
    bad = np.flatnonzero(np.repeat(np.tile(expected, layers), 3) * volume <= 0.0)
    if len(bad):
        k = int(bad[0])
        raise InputError(f"{surface.name}: a wall {thickness * 1e3:g} mm thick inverts tet {k} (of the triangle "
                         f"{int(k // 3 % len(tri))}, layer {int(k // (3 * len(tri)))}): the inward offset folds there; "
                         f"give a thinner wall, a smoother surface, or --wall membrane")
    flip = volume < 0
    tets[flip] = tets[flip][:, [0, 1, 3, 2]]
    mesh = TissueMesh.from_arrays(points * 1e3, tetrahedra=tets, path=surface.path)
    mesh.notes = (f"the wall extruded inward {thickness * 1e3:g} mm in {layers} layer(s) of tets: {mesh.tet_count} tets, "
                  f"its inner surface free", *mesh.notes)
    return mesh


def _split_sign(triangles) -> np.ndarray:
    """Per triangle, the sign of its prism's tets' volumes when the wall does not fold: the sorted corner order
    (v0, v1, v2) turns against the triangle's outward winding (an odd permutation) or with it, and the prism
    goes inward, against the outward normal: -1 for an even permutation, +1 for an odd one."""
    tri = np.asarray(triangles, dtype=np.int64)
    sorted_triangles = np.sort(tri, axis=1)
    # an even permutation (a cyclic shift) keeps the first corner's successor
    first = np.argmax(tri == sorted_triangles[:, :1], axis=1)
    even = tri[np.arange(len(tri)), (first + 1) % 3] == sorted_triangles[:, 1]
    return np.where(even, -1.0, 1.0)
