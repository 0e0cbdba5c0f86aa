"""Vertex normals of the organ's surface as it deforms, by the paper's three strategies (section 1.3).

Only the region moves, so only the normals it can change need recomputing: those of its vertices.
(A vertex outside the region shares no triangle with a free vertex: the free vertices' one-ring
faces reach at most the fixed outer ring, which is in the region. On a tet mesh the surface
triangles' edges are tet edges, so the same holds for the surface.) The local strategies update
just those; "global" updates everything, every frame. A volume mesh keeps normals on its surface
vertices and zero inside.

    normals = SurfaceNormals(mesh, device="cpu", strategy="precomputed")
    normals.update_region(state.particle_q, region)   # each displayed frame
    n = normals.numpy()                                 # unit normals, [vertex_count, 3]

:func:`benchmark_strategies` times the three per frame (``scripts/bench_normals.py`` prints them).
"""

from __future__ import annotations

import statistics
import time

import numpy as np
import warp as wp

from ..mesh.device_mesh import as_device_mesh
from ..kernels.region import normals as nk

STRATEGIES = ("global", "search", "precomputed")
"""global: all faces and vertices; search: the moved vertices, faces found by scanning every
triangle; precomputed: the moved vertices, faces from the vertex-to-face incidence built once."""


def check_strategy(strategy: str) -> str:
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown normals strategy {strategy!r} (known: {', '.join(STRATEGIES)})")
    return strategy


class SurfaceNormals:
    """Area-weighted unit vertex normals of a mesh's surface on one device, kept up to date.

    `vertex_normal` (shape [vertex_count], vec3) starts at the rest shape's normals; each update
    rewrites the normals a strategy covers from the positions it is given.
    """

    def __init__(self, mesh, device=None, strategy: str = "precomputed"):
        self.dmesh = dm = as_device_mesh(mesh, device)
        self.device = dm.device
        self.strategy = check_strategy(strategy)
        n = dm.vertex_count
        self.vertex_normal = wp.zeros(n, dtype=wp.vec3, device=self.device)
        """Unit normal of each vertex (zero off the surface), shape [vertex_count], vec3."""
        self._face_normal = wp.zeros(max(dm.triangles.shape[0], 1), dtype=wp.vec3, device=self.device)
        self.all_vertices = wp.array(np.arange(n, dtype=np.int32), dtype=wp.int32, device=self.device)
        """0..vertex_count-1: the vertex list of a global model."""
        nk.eval_vertex_normals_global(dm, dm.rest_position, self._face_normal, self.vertex_normal)
        self._region_key = None
        self._left_behind = None  # (vertex ids, count) of the region before a relocation

    def update(self, q, vertices=None, count: int | None = None) -> None:
        """Recompute normals from positions `q` [m] (shape [vertex_count], vec3, on this device).

        vertices: device int32 array of the vertex ids that moved or touch a moved face (the first
        `count`), or None for all. "global" recomputes every vertex whatever is given.
        """
        dm = self.dmesh
        if self.strategy == "global":
            nk.eval_vertex_normals_global(dm, q, self._face_normal, self.vertex_normal)
            return
        if vertices is None:
            vertices, count = self.all_vertices, dm.vertex_count
        elif count is None:
            count = vertices.shape[0]
        if self.strategy == "search":
            nk.eval_vertex_normals_search(dm, q, vertices, count, self.vertex_normal)
        else:
            nk.eval_vertex_normals_incident(dm, q, vertices, count, self.vertex_normal)

    def update_region(self, q, region=None) -> None:
        """Recompute the normals that a step of `region` can change (None: a global model, all).

        After the region moves (a new seed or size), the vertices of the old one are recomputed
        once more: the relocation put them back at rest.
        """
        if region is None:
            self.update(q)
            return
        count = region.vertex_count
        key = (region.seed, count)
        if key != self._region_key:
            if self._left_behind is not None:
                self.update(q, *self._left_behind)
            # a copy: building the next region overwrites region_vertex in place
            self._left_behind = (wp.clone(region.region_vertex[:count]), count) if count else None
            self._region_key = key
        self.update(q, region.region_vertex, count)

    def numpy(self) -> np.ndarray:
        """Host copy of the normals, [vertex_count, 3], float32."""
        return self.vertex_normal.numpy().copy()


def _replay_times(update, device, frames: int, blocks: int) -> list:
    """Seconds per call of `update` captured in a graph and replayed `frames` times, per block."""
    with wp.ScopedCapture(device=device, force_module_load=False) as cap:
        update()
    graph = cap.graph
    for _ in range(10):
        wp.capture_launch(graph)
    per_frame = []
    for _ in range(blocks):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        for _ in range(frames):
            wp.capture_launch(graph)
        wp.synchronize_device(device)
        per_frame.append((time.perf_counter() - t0) / frames)
    return per_frame


def time_strategy(palpation, strategy: str, budget_s: float = 0.2, blocks: int = 9) -> float:
    """Median seconds of one normals update with `strategy` for a touched `palpation`: the vertices
    its step can move (its region, or every vertex for a global model), from its current state;
    graph-replayed blocks that take about `budget_s` in all (a benchmark, not a test)."""
    normals = SurfaceNormals(palpation.model.dmesh, palpation.device, strategy)
    q = palpation.state.particle_q

    def update():
        normals.update_region(q, palpation.region)

    update()  # compiles, loads and settles the region key outside the capture
    wp.synchronize_device(palpation.device)
    t0 = time.perf_counter()
    update()
    wp.synchronize_device(palpation.device)
    first = max(time.perf_counter() - t0, 1e-7)
    frames = int(min(max(budget_s / blocks / first, 1), 5000))
    return statistics.median(_replay_times(update, palpation.device, frames, blocks))


def _moved_vertices(mesh, rings, device):
    """(vertex id array, count, region or None) of the vertices a step can move, with their one ring."""
    from ..region.region import Region

    dm = as_device_mesh(mesh, device)
    if isinstance(rings, str):
        return None, dm.vertex_count, None
    m = dm.mesh
    top = int(m.surface_vertices[np.argmax(m.vertices[m.surface_vertices, 2])])
    region = Region(dm).build(top, int(rings))
    return region.region_vertex, region.vertex_count, region


def benchmark_strategies(mesh, rings, device=None, *, frames: int = 200, blocks: int = 15) -> dict:
    """Cost of one frame's normal update for each strategy, on `device` (a benchmark, not a test).

    mesh: TissueMesh or DeviceMesh. rings: an int (the region around the highest surface vertex)
    or "global" (every vertex moves: the global models). Each strategy's update is captured in a
    Warp graph and replayed `frames` times per block; returns, per strategy, the median and best
    microseconds per frame over `blocks` blocks (`frame_us_median`, `frame_us_best`), and the
    median cost of one uncaptured update (`launch_us_median`: Python and launch overhead
    included), with the numbers of vertices updated and triangles read.
    """
    dm = as_device_mesh(mesh, device)
    dev = dm.device
    vertices, count, region = _moved_vertices(dm, rings, dev)
    rng = np.random.default_rng(0)
    # a deformed shape: the rest shape jittered by up to 1 mm (the cost does not depend on it)
    q = wp.array(dm.mesh.vertices + rng.uniform(-1e-3, 1e-3, dm.mesh.vertices.shape), dtype=wp.vec3, device=dev)
    surface = set(dm.mesh.surface_vertices.tolist())
    ids = np.arange(dm.vertex_count) if vertices is None else vertices.numpy()[:count]
    result = {
        "mesh": dm.mesh.name,
        "rings": rings,
        "device": str(dev),
        "vertices_updated": int(count),
        "surface_vertices_updated": int(sum(1 for v in ids if int(v) in surface)),
        "vertex_count": int(dm.vertex_count),
        "triangle_count": int(dm.triangles.shape[0]),
        "strategies": {},
    }

    for strategy in STRATEGIES:
        normals = SurfaceNormals(dm, dev, strategy)

        def update(normals=normals):
            normals.update(q, vertices, count if vertices is not None else None)

        update()  # compiles and loads the module outside the capture
        wp.synchronize_device(dev)
        launch = []
        for _ in range(max(blocks, 5)):
            t0 = time.perf_counter()
            update()
            wp.synchronize_device(dev)
            launch.append(time.perf_counter() - t0)
        per_frame = _replay_times(update, dev, frames, blocks)
        result["strategies"][strategy] = {
            "frame_us_median": statistics.median(per_frame) * 1e6,
            "frame_us_best": min(per_frame) * 1e6,
            "launch_us_median": statistics.median(launch) * 1e6,
        }
    return result
