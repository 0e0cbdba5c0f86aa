"""A batch's substeps without the eigenvalues of its whole free set: the whole mesh's critical step
bounds every region's from below, a small piece of the batch's free set bounds theirs from above;
where both give the same substeps, those are the batch's (BatchPalpation.plan_substeps)."""

from __future__ import annotations

import numpy as np

from ..checks import substeps_for
from ..mesh.topology import csr_entries

MARGIN = 1e-4
"""Relative slack on either bound: the estimates (eigsh to 1e-6, assembled in another order) agree to about 1e-7."""
PIECE_RINGS = (4, 8, 16)
"""Rings of the pieces tried, grown from the batch's stiffest free vertex, each until its substeps agree."""


def stiffness_proxy(model) -> np.ndarray:
    """Each vertex's Gershgorin row sum of M^-1/2 K M^-1/2 for the springs law [1/s^2], [n]: where the
    stiffest mode lives (its largest entries), computed once a model."""
    e = model.mesh.edges.astype(np.int64)
    m, ke = model.particle_mass_host, model.spring_ke_host
    r = model.anchor_ke_host.astype(np.float64).copy()
    for a, b in ((0, 1), (1, 0)):
        np.add.at(r, e[:, a], ke * (1.0 + np.sqrt(m[e[:, a]] / m[e[:, b]])))
    return r / m


def grow(model, seed: int, free: np.ndarray, rings: int) -> np.ndarray:
    """The vertices of `free` (sorted) within `rings` mesh rings of `seed` through `free` only, sorted."""
    offsets, neighbour, _ = model.mesh.adjacency
    inside = frontier = np.array([seed], dtype=np.int64)
    for _ in range(rings):
        near = np.unique(neighbour[csr_entries(offsets, frontier)])
        at = np.minimum(np.searchsorted(free, near), len(free) - 1)
        near = near[free[at] == near]
        frontier = np.setdiff1d(near, inside, assume_unique=True)
        if len(frontier) == 0:
            break
        inside = np.union1d(inside, frontier)
    return inside


def certified_critical_dt(model, free: np.ndarray, frame_dt: float, bound: float, cache: dict) -> float | None:
    """`bound` (the whole mesh's critical step [s]) where it gives the frame the substeps that the
    critical step of the free vertices `free` (sorted, unique) would: certain where one substep is
    stable under it; for the springs law also where a piece of `free` around its stiffest vertex (a
    principal submatrix: a critical step no shorter than all of `free`'s) needs as many. Else None
    (then only `free`'s own estimate decides). `cache`: the pieces' steps, by piece, kept by the caller."""
    n = substeps_for(frame_dt, (1 - MARGIN) * bound)
    if n == 1:
        return bound
    if model.law != "springs" or len(free) == 0:
        return None
    if "proxy" not in cache:
        cache["proxy"] = stiffness_proxy(model)
    seed = int(free[np.argmax(cache["proxy"][free])])
    size = 0
    for rings in PIECE_RINGS:
        piece = grow(model, seed, free, rings)
        if len(piece) == size:  # the piece holds every free vertex it can reach
            break
        size, key = len(piece), ("piece", piece.tobytes())
        if key not in cache:
            cache[key] = model.critical_dt(piece)
        if substeps_for(frame_dt, (1 + MARGIN) * cache[key]) == n:
            return bound
    return None
