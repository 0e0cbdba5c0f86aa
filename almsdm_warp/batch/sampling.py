"""Where a sweep presses: N points spread evenly over an organ's surface, each snapped to a vertex.

Up to the surface's vertices, farthest-point sampling of the vertices themselves; beyond, of a
dense area-uniform sample of the surface (trimesh's draws for the seed) snapped to the nearest
vertex, or (beyond FPS_MAX points) that sample itself, drawn on a thread a core while the first
chunks press (Sampling)."""

from __future__ import annotations

import time

import numpy as np

from ..errors import InputError

FPS_MAX = 20000
"""Beyond this many points (and the mesh's vertices), points are area-uniform random, not farthest-point."""
TREE_WORK = 1_000_000
TREE_MIN = 64
"""farthest_points updates only the points near each chosen one (a k-d tree) where n x points exceeds
TREE_WORK and n TREE_MIN: fewer choices update every point sooner than a tree of a large organ is built
(a lesion's 3 centres on 500,000 vertices)."""


def farthest_points(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """Indices of `n` of `points` chosen greedily, each farthest from those already chosen (the first
    of equals: np.argmax).

    Each point's squared distance to the chosen set, d2, only falls, and choosing k (d2[k] = D, the
    largest) lowers it only for the points nearer to k than their own d2 <= D: those in the ball of
    radius sqrt(D) around k, found in a k-d tree and updated alone (the same arithmetic a point, so
    the same bits as updating every point: tests/test_sweep.py). As the chosen points fill the
    surface the balls shrink: 10,000 of 30,000 points in 0.8 s, against 6.7 s for the whole array
    each time; 2,000 of 501,762 in 2.6 s against 25 s (docs/performance.md, "Datasets")."""
    p = np.asarray(points, dtype=np.float64)
    n = min(int(n), len(p))
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    diff = p - p[start]
    d2 = np.einsum("ij,ij->i", diff, diff)
    tree = None
    if n > TREE_MIN and n * len(p) > TREE_WORK:
        from scipy.spatial import cKDTree

        tree = cKDTree(p, balanced_tree=False, compact_nodes=False)  # built 3x sooner, queried as fast
    near, every = slice(None), True
    for i in range(1, n):
        chosen[i] = k = int(np.argmax(d2))
        if not every:  # a margin over sqrt(D) for the tree's rounding (a point too many changes nothing)
            near = np.asarray(tree.query_ball_point(p[k], np.sqrt(d2[k]) * (1.0 + 1e-9), return_sorted=False), dtype=np.int64)
        diff = p[near] - p[k]
        d2k = np.einsum("ij,ij->i", diff, diff)
        if every and tree is not None:  # every point while a choice lowers more than an eighth of them
            every = 8 * np.count_nonzero(d2k < d2) > len(p)
        d2[near] = np.minimum(d2[near], d2k)
    return chosen


def area_uniform_points(vertices: np.ndarray, triangles: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """`n` points [n, 3] uniform by area over the triangles, from np.random.default_rng(seed).

    Each point picks a triangle with probability proportional to its area (the areas' cumulative sum
    searched with a uniform number), then a point uniform in it (two uniform numbers u, v; where
    u + v > 1 they are folded back as 1 - u, 1 - v). The draws and the arithmetic are trimesh's
    ``sample.sample_surface``, so the points are its bits for the same seed, without building a mesh
    object or its (n, 2, 3) temporaries."""
    surface = AreaSampler(vertices, triangles, n, seed)
    in_blocks(surface.points, n)
    return surface.out


class AreaSampler:
    """area_uniform_points in parts: the draws at once, in trimesh's order (a triangle by a uniform
    number searched in the areas' cumulative sum, then u, v for each point); then points(b, e) puts
    points b..e into `out`, each from its own draws, so any split gives the same bits."""

    def __init__(self, vertices, triangles, n: int, seed: int = 0, out: np.ndarray | None = None):
        p = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles)
        self.o = p[t[:, 0]]
        self.e1, self.e2 = p[t[:, 1]] - self.o, p[t[:, 2]] - self.o
        # the area as trimesh computes it: |(v1 - v0) x (v2 - v1)| / 2
        c = np.cross(self.e1, p[t[:, 2]] - p[t[:, 1]])
        self.cum = np.cumsum(np.sqrt((c**2).sum(axis=1)) / 2.0)
        rng = np.random.default_rng(seed)
        self.pick, self.uv = rng.random(n), rng.random((n, 2))
        self.out = np.empty((n, 3)) if out is None else out

    def points(self, b: int, e: int) -> None:
        face = np.searchsorted(self.cum, self.pick[b:e] * self.cum[-1])
        w = self.uv[b:e]
        w[w.sum(axis=1) > 1.0] -= 1.0  # folded back into the triangle: 1 - u, 1 - v
        np.abs(w, out=w)
        self.out[b:e] = self.e1[face] * w[:, :1] + self.e2[face] * w[:, 1:] + self.o[face]


class Sampling:
    """sample_points' area-uniform path (beyond FPS_MAX points and the surface's vertices) on a
    thread a core, a block of points at a time in order, each block drawn and snapped to its nearest
    surface vertex: `points` and `vertices` fill in behind the caller, who presses the first chunks
    while later blocks are sampled (wait(end): until points[:end] are there). The same bits as
    sample_points."""

    BLOCK = 1 << 16

    def __init__(self, mesh, n: int, seed: int = 0):
        import os
        from concurrent.futures import ThreadPoolExecutor

        from scipy.spatial import cKDTree

        self._t0 = time.perf_counter()
        self.points, self.vertices = np.empty((n, 3)), np.empty(n, dtype=np.int64)
        self.blocks = [(b, min(b + self.BLOCK, n)) for b in range(0, n, self.BLOCK)]
        self.seconds = None
        """Wall time [s] from the start to the last block, once wait() has seen it."""
        self._pool = ThreadPoolExecutor(min(len(self.blocks), os.cpu_count() or 1), thread_name_prefix="sweep-sampling")

        def prepare():  # the draws and the tree, on the pool too: the caller goes on at once
            self.surface = mesh.surface_vertices
            self.tree = cKDTree(mesh.vertices[self.surface])
            self.area = AreaSampler(mesh.vertices, mesh.triangles, n, seed, out=self.points)

        self._prepared = self._pool.submit(prepare)
        self._futures = [self._pool.submit(self._block, b, e) for b, e in self.blocks]  # run in this order
        self._pool.shutdown(wait=False)

    def _block(self, b: int, e: int) -> float:
        self._prepared.result()
        self.area.points(b, e)
        self.vertices[b:e] = self.surface[self.tree.query(self.points[b:e])[1]]
        return time.perf_counter()

    def wait(self, end: int | None = None) -> None:
        """Return once points[:end] (all: None) are sampled; an error in a block is raised here."""
        end = len(self.vertices) if end is None else end
        last = 0.0
        for (b, _), f in zip(self.blocks, self._futures):
            if b >= end:
                break
            last = max(last, f.result())
        if end >= len(self.vertices) and self.seconds is None:
            self.seconds = last - self._t0


def in_blocks(work, n: int, size: int = 1 << 16) -> None:
    """work(begin, end) over blocks of `size` of range(n), on a thread per core (NumPy and SciPy
    release the GIL in them): each point's result is its own, so any split gives the same bits."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    blocks = [(b, min(b + size, n)) for b in range(0, n, size)]
    if len(blocks) <= 1:
        for b, e in blocks:
            work(b, e)
        return
    with ThreadPoolExecutor(min(len(blocks), os.cpu_count() or 1)) as pool:
        for f in [pool.submit(work, b, e) for b, e in blocks]:
            f.result()


def sample_points(mesh, n: int, seed: int = 0):
    """`n` contact points spread evenly over the surface: (points [n, 3] m, contact vertex [n]).

    Up to the number of surface vertices: farthest-point sampling of the vertices themselves
    (distinct contacts), starting from the highest one. Beyond: of an area-uniform sample of
    the surface (seeded, so a rerun picks the same points; beyond FPS_MAX points that sample
    itself), each snapped to its nearest vertex, as the probe's contact moves to the nearest
    vertex (the paper's model).
    """
    surface = mesh.surface_vertices
    v = mesh.vertices
    if n <= len(surface):
        from ..region.contact import top_vertex

        start = int(np.flatnonzero(surface == top_vertex(mesh))[0])  # its index among the surface vertices
        idx = surface[farthest_points(v[surface], n, start)]
        return v[idx].copy(), idx.astype(np.int64)
    from scipy.spatial import cKDTree

    if n > FPS_MAX:  # farthest-point sampling costs n x 3n: beyond FPS_MAX, area-uniform random points
        sampling = Sampling(mesh, n, seed)
        sampling.wait()
        return sampling.points, sampling.vertices
    dense = area_uniform_points(v, mesh.triangles, 3 * n, seed)
    pts = dense[farthest_points(dense, n, int(np.argmax(dense[:, 2])))]
    tree, near = cKDTree(v[surface]), np.empty(len(pts), dtype=np.int64)

    def snap(b: int, e: int) -> None:
        near[b:e] = tree.query(pts[b:e])[1]

    in_blocks(snap, len(pts))  # the same nearest vertices as one query
    return pts, surface[near].astype(np.int64)


def pressable_points(mesh, n: int, fixed_below=None):
    """sample_points less those a support holds (z below `fixed_below` [m]: a press there reads no force).
    Raises InputError when the support holds every one."""
    points, vertices = sample_points(mesh, n)
    if fixed_below is None:
        return points, vertices
    keep = mesh.vertices[vertices, 2] >= fixed_below
    if not keep.any():
        raise InputError(f"every sampled point is held by the support (z below {fixed_below * 1e3:g} mm)")
    return points[keep], vertices[keep]


def start_sampling(mesh, n: int, fixed_below=None):
    """pressable_points(mesh, n, fixed_below) as (points, vertices, None); or, on its area-uniform
    path and where no support can drop points (so their number is n before they are drawn), a
    Sampling that fills them in behind the caller: (its points, its vertices, it). The same points."""
    if n > FPS_MAX and n > len(mesh.surface_vertices) and fixed_below is None:
        sampling = Sampling(mesh, n)
        return sampling.points, sampling.vertices, sampling
    return (*pressable_points(mesh, n, fixed_below), None)
