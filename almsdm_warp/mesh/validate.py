"""Validate and repair a mesh once, on the host, with vectorized NumPy, when it enters.

Fatal problems raise :class:`InputError` with one line that names the file, the element and the
value; repairs (merged, dropped, reoriented) and findings (open surface, non-manifold edges,
components) become one-line ``notes`` of the TissueMesh built from them.
Element and vertex numbers in messages are those of the input, so that they can be found in the file.
"""

from __future__ import annotations

import itertools
import math
import numbers

import numpy as np

from . import topology as topo
from ..errors import InputError

MERGE_TOL = 1e-9
"""Vertices closer than this x the bounding-box diagonal are one vertex."""
DEGENERATE_TOL = 1e-12
"""Triangles with area <= this x diag^2, tets with |volume| <= this x diag^3, are degenerate."""
MAX_COORDINATE_M = 1.0e3
"""Coordinates beyond +-1 km (after the scale) are an error: no organ is that large, and the
device's float32 would leave millimetre springs unresolved there (a wrong scale, usually)."""
MAX_FILE_COORDINATE = 1.0e100
"""Coordinates beyond this in the file's own units are an error whatever the scale (cubes of
them, for tet volumes, would overflow float64)."""
MIN_EDGE_M = 1.0e-8
"""Edges shorter than this [m] are an error: the force kernels treat springs under 1e-9 m as
collapsed (no direction, no force), so such a spring would silently do nothing."""
SLIVER_QUALITY = 0.02
"""Tets of quality (topology.tet_quality: 1 regular, 0 flat) under this are slivers: a note counts them and
names the worst. They are kept (only zero-volume tets are dropped), but they stiffen a volumetric law's
step: the neo-Hookean law's critical step shrinks with its worst tet."""
MIN_EDGE_RELATIVE = 2.0**-20
"""Edges shorter than this x the largest |coordinate| are an error: float32 on the device
(24-bit mantissa) keeps no more than a few bits of their length."""

_KINDS = {3: ("triangle", "triangles"), 4: ("tetrahedron", "tetrahedra")}


def repair_arrays(vertices, triangles=None, tetrahedra=None, *, scale: float = 1.0, path=None):
    """Validate and repair raw arrays into the fields of a TissueMesh (vertices in metres).

    vertices: [n, 3] coordinates in file units; file units x `scale` = millimetres.
    triangles: [m, 3] and tetrahedra: [t, 4] vertex indices (0-based); either may be None.
    When there are tetrahedra, the surface is recomputed from them and `triangles` is ignored.
    Returns (fields, keep, where): the TissueMesh keyword arguments, the input index of each kept
    vertex and the name messages use (for :func:`check_edge_lengths` on the mesh built from them).
    """
    where = str(path) if path is not None else "<arrays>"
    notes: list[str] = []
    scale = check_scale(scale, where)
    v = _as_vertices(vertices, where)
    tri = _as_elements(triangles, 3, where)
    tet = _as_elements(tetrahedra, 4, where)
    n = len(v)
    if n == 0 or (len(tri) == 0 and len(tet) == 0):
        raise InputError(
            f"{where}: the mesh is empty ({n} vertices, {len(tri)} triangles, {len(tet)} tetrahedra)"
        )
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"{where}: vertex {i} has a non-finite coordinate {_fmt_xyz(v[i])}")
    _check_range(tri, n, where)
    _check_range(tet, n, where)
    _check_extent(v, topo.used_vertices(tet if len(tet) else tri, n), scale, where)

    volume = len(tet) > 0
    if volume and len(tri):
        what = _plural(len(tri), "triangle", "triangles")
        notes.append(f"ignored the file's {len(tri)} {what}: the surface is recomputed from the tetrahedra")
    elements = tet if volume else tri
    ids = np.arange(len(elements))  # input element numbers, carried through the filters

    used = topo.used_vertices(elements, n)
    lo, hi = v[used].min(axis=0), v[used].max(axis=0)
    diag = float(np.linalg.norm(hi - lo))

    inside = np.flatnonzero(np.abs(v).max(axis=1) <= min(MAX_COORDINATE_M / (scale * 1e-3), MAX_FILE_COORDINATE))
    remap = _merge_duplicates(v, inside, diag, notes)
    elements = remap[elements]
    elements, ids, degenerate = _drop_degenerate(v, elements, ids, diag, where, notes)
    elements, ids = _drop_duplicates(elements, ids, notes)

    if volume:
        elements, inverted = _reorient_tets(v, elements, ids, notes)
        _report_tet_findings(v, elements, ids, notes, degenerate, inverted)
        surface = topo.tet_surface(elements)
    else:
        surface = elements

    # keep the referenced vertices, in input order; `keep` maps new index -> input index
    keep = topo.used_vertices(elements, n)
    unreferenced = _unreferenced(remap, keep)
    if len(unreferenced):
        notes.append(
            f"dropped {len(unreferenced)} unreferenced {_plural(len(unreferenced), 'vertex', 'vertices')}"
            f" (first: vertex {unreferenced[0]})"
        )
    new_index = np.full(n, -1, dtype=np.int64)
    new_index[keep] = np.arange(len(keep))
    elements = new_index[elements]
    surface = new_index[surface]
    v_kept = v[keep]

    _report_surface_edges(surface, keep, notes, volume)
    if not volume:
        surface = _orient_closed_surface(v_kept, surface, notes)
        elements = surface
    _report_components(elements, len(keep), notes)

    fields = dict(
        vertices=v_kept * (scale * 1e-3),
        triangles=surface.astype(np.int32),
        tetrahedra=elements.astype(np.int32) if volume else np.zeros((0, 4), dtype=np.int32),
        path=path if path is None else str(path),
        notes=tuple(notes),
    )
    return fields, keep, where


def _unreferenced(remap: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The vertices neither merged into another (remap: each vertex's representative) nor used (`keep`),
    sorted: np.setdiff1d's answer, by a mask."""
    referenced = np.zeros(len(remap), dtype=bool)
    referenced[keep] = True
    return np.flatnonzero((remap == np.arange(len(remap))) & ~referenced)


# -- input checks ---------------------------------------------------------------------------------
def check_scale(scale, where: str) -> float:
    """The mesh scale (millimetres per file unit) as a positive finite float, else InputError."""
    if isinstance(scale, bool) or not isinstance(scale, numbers.Real):
        raise InputError(f"{where}: scale must be a positive number, got {scale!r}")
    s = float(scale)
    if not math.isfinite(s) or s <= 0.0:
        raise InputError(f"{where}: scale must be a positive finite number (file units x scale = mm), got {s!r}")
    return s


def _as_vertices(vertices, where: str) -> np.ndarray:
    try:
        v = np.asarray(vertices if vertices is not None else np.zeros((0, 3)))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: vertices are not an array of numbers: {exc}") from exc
    if v.size == 0:
        return np.zeros((0, 3), dtype=np.float64)
    if v.dtype.kind not in "iuf":
        raise InputError(f"{where}: vertex coordinates must be numbers, got dtype {v.dtype}")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"{where}: vertices must have shape (n, 3), got {v.shape}")
    return v.astype(np.float64)


def _as_elements(elements, k: int, where: str) -> np.ndarray:
    one, many = _KINDS[k]
    if elements is None:
        return np.zeros((0, k), dtype=np.int64)
    try:
        e = np.asarray(elements)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{where}: {many} are not an array of indices: {exc}") from exc
    if e.size == 0:
        return np.zeros((0, k), dtype=np.int64)
    if e.ndim != 2 or e.shape[1] != k:
        raise InputError(f"{where}: {many} must have shape (m, {k}), got {e.shape}")
    if e.dtype.kind in "iu":
        if e.dtype.kind == "u" and e.size and e.max() > np.iinfo(np.int64).max:
            row = int(np.argmax((e > np.iinfo(np.int64).max).any(axis=1)))
            raise InputError(f"{where}: {one} {row} has an index too large for int64")
        return e.astype(np.int64)
    if e.dtype.kind == "f":
        bad = ~(np.isfinite(e) & (e == np.round(e)))
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise InputError(f"{where}: {one} {row} has a non-integer vertex index {float(e[row, col])!r}")
        return e.astype(np.int64)
    raise InputError(f"{where}: {many} must hold integer vertex indices, got dtype {e.dtype}")


def _check_range(elements: np.ndarray, n: int, where: str) -> None:
    bad = (elements < 0) | (elements >= n)
    if not bad.any():
        return
    one, many = _KINDS[elements.shape[1]]
    rows = np.flatnonzero(bad.any(axis=1))
    row = rows[0]
    value = elements[row][bad[row]][0]
    more = f" ({len(rows) - 1} more {many} out of range)" if len(rows) > 1 else ""
    raise InputError(
        f"{where}: {one} {row} references vertex {value}, but the mesh has {n} vertices (0..{n - 1}){more}"
    )


def _check_extent(v: np.ndarray, used: np.ndarray, scale: float, where: str) -> None:
    """Every vertex that an element uses within +-MAX_COORDINATE_M once scaled to metres and
    within +-MAX_FILE_COORDINATE in the file's units (checked before any float64 arithmetic on
    them: squares of 1e154 overflow); and the mesh not smaller than MIN_EDGE_M."""
    limit = min(MAX_COORDINATE_M / (scale * 1e-3), MAX_FILE_COORDINATE)  # in file units
    far = np.abs(v[used]).max(axis=1) > limit
    if far.any():
        i = int(used[np.argmax(far)])
        metres = float(np.abs(v[i]).max()) * scale * 1e-3
        if metres > MAX_COORDINATE_M:
            raise InputError(
                f"{where}: vertex {i} at {_fmt_xyz(v[i])} (file units, x {scale:g} mm each) is {metres:.3g} m from the "
                f"origin, beyond the {MAX_COORDINATE_M:g} m the simulator handles; check the scale (millimetres per file unit)"
            )
        raise InputError(f"{where}: vertex {i} at {_fmt_xyz(v[i])} is beyond +-{MAX_FILE_COORDINATE:g} file units")
    size = float(np.ptp(v[used], axis=0).max()) * scale * 1e-3
    if size < MIN_EDGE_M:
        raise InputError(
            f"{where}: the mesh is {size:.3g} m across (file units x {scale:g} mm), smaller than the {MIN_EDGE_M:g} m "
            f"springs the simulator resolves; check the scale (millimetres per file unit)"
        )


def check_edge_lengths(mesh, keep: np.ndarray, where: str) -> None:
    """Every spring of `mesh` (a TissueMesh) long enough for the force kernels and for float32 on the
    device; `keep` maps its vertices to the input's, for the message."""
    if mesh.edge_count == 0:
        return
    length = mesh.edge_rest_length
    span = float(np.abs(mesh.vertices).max())
    floor = max(MIN_EDGE_M, MIN_EDGE_RELATIVE * span)
    j = int(np.argmin(length))
    if length[j] < floor:
        a, b = (int(keep[x]) for x in mesh.edges[j])
        why = (f"{MIN_EDGE_M:g} m, below which a spring has no direction" if floor == MIN_EDGE_M
               else f"{floor:.3g} m, what float32 resolves at coordinates up to {span:.3g} m")
        raise InputError(
            f"{where}: the edge between vertices {a} and {b} is {length[j]:.3g} m long at rest, shorter than "
            f"{why}; check the scale (millimetres per file unit) or merge those vertices"
        )


# -- repairs --------------------------------------------------------------------------------------
def _merge_duplicates(v: np.ndarray, used: np.ndarray, diag: float, notes: list[str]) -> np.ndarray:
    """Map each vertex to the lowest-numbered vertex within MERGE_TOL x diag of it (or of a chain).

    `used`: the vertices that take part, those within the extent the simulator handles (every
    vertex an element references is); the others are unreferenced, dropped anyway, and may hold
    anything (coordinates of 1e300 overflow the tree's distances)."""
    n = len(v)
    identity = np.arange(n)
    if len(used) < 2 or not _may_have_duplicates(v[used], MERGE_TOL * diag):
        return identity
    from scipy.spatial import cKDTree

    pairs = used[cKDTree(v[used]).query_pairs(MERGE_TOL * diag, output_type="ndarray")]
    if len(pairs) == 0:
        return identity
    count, label = topo.connected_components(pairs, n)
    first = np.full(count, n, dtype=np.int64)
    np.minimum.at(first, label, identity)
    remap = first[label]
    moved = np.flatnonzero(remap != identity)
    i = moved[0]
    dist = float(np.linalg.norm(v[i] - v[remap[i]]))
    notes.append(
        f"merged {len(moved)} duplicate {_plural(len(moved), 'vertex', 'vertices')} "
        f"(first: vertex {i} onto vertex {remap[i]}, {dist:.3g} apart)"
    )
    return remap


MERGE_CELL = 1.0e3
"""The pre-check's cells (_may_have_duplicates) are this x the merge distance on a side."""


def _may_have_duplicates(points: np.ndarray, reach: float) -> bool:
    """False only when no two of `points` are within `reach` of each other, found by sorting, with no k-d
    tree: the usual mesh has no duplicates, and scipy.spatial's import (0.4-0.7 s) is then left to whatever
    needs it later. In a grid of MERGE_CELL x reach a side, two points that close share a cell, or lie
    across a face, both within reach of it; those near a face (about 1% of them) share a cell in one of
    the grids shifted by half a cell along the axes they straddle. True: the k-d tree decides."""
    if reach <= 0.0:
        return True
    q = (points - points.min(axis=0)) / (MERGE_CELL * reach)
    if q.max() >= 2.0**20 or _share_a_cell(q):  # the keys hold 21 bits an axis
        return True
    frac = q - np.floor(q)
    slack = 2.0 / MERGE_CELL  # reach in cells, doubled against the rounding of q
    near = q[((frac < slack) | (frac > 1.0 - slack)).any(axis=1)]
    shifts = [s for s in itertools.product((0.0, 0.5), repeat=3) if any(s)]
    return len(near) > 1 and any(_share_a_cell(near + np.array(s)) for s in shifts)


def _share_a_cell(q: np.ndarray) -> bool:
    """True when two rows of q (coordinates in cells, under 2**21) fall in one unit cell."""
    i = np.floor(q).astype(np.int64)
    key = (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]
    return len(np.unique(key)) < len(key)


def _drop_degenerate(v, elements, ids, diag, where, notes):
    k = elements.shape[1]
    one, many = _KINDS[k]
    s = np.sort(elements, axis=1)
    repeated = (s[:, 1:] == s[:, :-1]).any(axis=1)
    if k == 3:
        size, what = topo.triangle_areas(v, elements), "area"
        small = size <= DEGENERATE_TOL * diag**2
    else:
        size, what = np.abs(topo.tet_signed_volumes(v, elements)), "volume"
        small = size <= DEGENERATE_TOL * diag**3
    bad = repeated | small
    if bad.any():
        j = int(np.argmax(bad))
        label = "degenerate" if k == 3 else "zero-volume"
        notes.append(
            f"dropped {int(bad.sum())} {label} {one if bad.sum() == 1 else many} (first: {one} {ids[j]}, "
            f"vertices {tuple(int(x) for x in elements[j])}, {what} {size[j]:.3g})"
        )
    if bad.all():
        raise InputError(
            f"{where}: no {many} left: all {len(elements)} are degenerate ({what} ~0 or a repeated vertex)"
        )
    return elements[~bad], ids[~bad], int(bad.sum())


def _drop_duplicates(elements, ids, notes):
    one, many = _KINDS[elements.shape[1]]
    key = np.sort(elements, axis=1)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    dup = first[inverse] != np.arange(len(elements))
    if not dup.any():
        return elements, ids
    j = int(np.argmax(dup))
    notes.append(
        f"dropped {int(dup.sum())} duplicate {one if dup.sum() == 1 else many} "
        f"(first: {one} {ids[j]}, same vertices as {one} {ids[first[inverse[j]]]})"
    )
    return elements[~dup], ids[~dup]


def _reorient_tets(v, tets, ids, notes):
    vol = topo.tet_signed_volumes(v, tets)
    inverted = vol < 0.0
    if inverted.any():
        j = int(np.argmax(inverted))
        notes.append(
            f"reoriented {int(inverted.sum())} of {len(tets)} inverted tetrahedra by swapping two corners "
            f"(first: tetrahedron {ids[j]}, signed volume {vol[j]:.3g})"
        )
        tets = tets.copy()
        tets[inverted] = tets[inverted][:, [0, 1, 3, 2]]
    return tets, int(inverted.sum())


def _report_tet_findings(v, tets, ids, notes, degenerate: int = 0, inverted: int = 0):
    """Notes on the (oriented) tets: their quality in one line, faces shared by more than two."""
    line = quality_line(v, tets, ids, degenerate, inverted)
    if line:
        notes.append(line)
    _report_shared_faces(tets, notes)


def quality_line(v, tets, ids, degenerate: int = 0, inverted: int = 0) -> str:
    """One line on a tet mesh's quality (topology.tet_quality: 1 a regular tet, 0 a flat one) where it has
    a fault, else "": the slivers (under SLIVER_QUALITY), the degenerate tets dropped and the inverted
    ones reoriented, counted, the median quality and the worst tet, named."""
    q = topo.tet_quality(v, tets)
    slivers = int(np.count_nonzero(q < SLIVER_QUALITY))
    if not (slivers or degenerate or inverted):
        return ""
    j = int(np.argmin(q))
    head = (f"{slivers} sliver {_plural(slivers, 'tetrahedron', 'tetrahedra')} of {len(tets)} (quality under {SLIVER_QUALITY:g}, "
            f"1 a regular tet)" if slivers else f"tet quality: no slivers among {len(tets)} (quality under {SLIVER_QUALITY:g}, 1 a regular tet)")
    return (f"{head}, {degenerate} degenerate dropped, {inverted} inverted reoriented; median quality {np.median(q):.3g}; "
            f"worst: tetrahedron {ids[j]}, vertices {tuple(int(x) for x in tets[j])}, quality {q[j]:.3g}"
            + ("; slivers stiffen a volumetric law's step and dent under a press: remesh them" if slivers else ""))


def _orient_closed_surface(v, tri, notes):
    """Make a closed surface's winding consistent and outward (per body); leave an open one as it is."""
    edge_use = _edge_counts(tri)[1]
    boundary = int((edge_use == 1).sum())
    if boundary or (edge_use > 2).any():
        notes.append(
            f"open surface: {boundary} boundary edges; winding kept as in the file"
            if not (edge_use > 2).any()
            else f"not a closed manifold surface ({boundary} boundary edges); winding kept as in the file"
        )
        return tri
    flip, orientable = topo.orientation_flips(v, tri)
    if not orientable:
        notes.append("closed surface that cannot be oriented (a one-sided surface, like a Klein bottle); "
                      "winding kept as in the file")
        return tri
    fixed = tri.copy()
    fixed[flip] = fixed[flip][:, ::-1]
    flipped = np.flatnonzero((fixed != tri).any(axis=1))
    if len(flipped) == len(tri):
        notes.append(f"reversed the winding of all {len(tri)} triangles: the closed surface was wound inward")
    elif len(flipped):
        notes.append(
            f"flipped {len(flipped)} of {len(tri)} triangles to make the closed surface's winding "
            f"consistent and outward (first: output triangle {flipped[0]})"
        )
    return fixed


# -- findings -------------------------------------------------------------------------------------
def _edge_counts(tri: np.ndarray):
    """(unique sorted edges [e, 2], number of triangles using each [e])."""
    return topo.unique_pairs(np.sort(tri[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1))


def _report_surface_edges(surface, keep, notes, volume):
    edges, count = _edge_counts(surface)
    nonmanifold = count > 2
    if nonmanifold.any():
        j = int(np.argmax(nonmanifold))
        a, b = keep[edges[j]]
        where = "surface edges of the tetrahedra" if volume else "edges"
        count_nm = int(nonmanifold.sum())
        where = where if count_nm > 1 else where.replace("edges", "edge")
        notes.append(
            f"{count_nm} non-manifold {where} (shared by more than 2 triangles; "
            f"first: edge between vertices {a} and {b}, {count[j]} triangles)"
        )


def _report_shared_faces(tets, notes):
    faces = np.sort(tets[:, topo.TET_FACES_OUT].reshape(-1, 3), axis=1)
    _, count = np.unique(faces, axis=0, return_counts=True)
    over = count > 2
    if over.any():
        notes.append(f"{int(over.sum())} faces shared by more than 2 tetrahedra (the tet mesh overlaps itself)")


def _report_components(elements, n, notes):
    if elements.shape[1] == 4:
        edges = topo.unique_edges(np.zeros((0, 3), dtype=np.int64), elements)
    else:
        edges = topo.unique_edges(elements)
    count, label = topo.connected_components(edges, n)
    if count > 1:
        sizes = np.sort(np.bincount(label))[::-1]
        shown = ", ".join(str(s) for s in sizes[:5]) + (", ..." if count > 5 else "")
        notes.append(f"{count} connected components (vertices in each: {shown})")


# -- formatting -----------------------------------------------------------------------------------
def _fmt_xyz(p) -> str:
    return "(" + ", ".join(repr(float(x)) for x in p) + ")"


def _plural(count: int, one: str, many: str) -> str:
    return one if count == 1 else many
