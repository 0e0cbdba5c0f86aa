"""Several items of one mesh pressed in one batch: each palpation reads its own item's parameters.

A dataset (batch/dataset.py) presses the same points of a mesh once per lesion: the items differ in
their springs', anchors' and dampers' constants (or a tet law's per-tet moduli), not in the mesh, the
points, the regions or the press. StackedModel holds K such models as one model of K copies of the
mesh: item k's vertex v is k x n + v, its spring s is k x e + s, its law entry j is k x m + j, its
parameters the item's own Model's (the same float32 values), its topology the mesh's with those
offsets. ItemBatch is a BatchPalpation over a stack: each palpation's region is built (or gathered
from a table of regions, built once) on the shared mesh, then offset to its item's copy
(kernels/region/batch_rings.py, offset_regions), and the batch's kernels, unchanged, read that
item's constants. A palpation of item k gives the same bits as the same press in a batch of item
k's model alone (tests/test_dataset.py).
"""

from __future__ import annotations

import numpy as np
import warp as wp

from ..kernels.arrays import TissueArrays, struct_from
from ..kernels.region import batch_rings as br
from ..mesh.device_mesh import as_device_mesh
from ..solvers.stepper import check_results, force_bound
from .batch_palpation import BatchPalpation, BatchResult, host_copy, union_critical_dt

INDEX_LIMIT = 2**31 - 1
"""Stacked vertex, spring and entry ids are int32 on the device: K copies of a mesh must number fewer."""


STACK_ELEMENTS = 2**27
"""Vertices, CSR entries and tet corners of all a stack's copies together at most (about 2-4 GB of
arrays): a stack of a 500,000-vertex organ holds about 20 items, one of the shipped stomach thousands."""


def stack_limit(mesh) -> int:
    """The most items of `mesh` a StackedModel holds: its vertex, CSR entry and tet corner ids stay
    int32, and its arrays within STACK_ELEMENTS."""
    sizes = (mesh.vertex_count, 2 * len(mesh.edges), 4 * mesh.tet_count)
    return max(1, min(INDEX_LIMIT // (max(sizes) + 1), STACK_ELEMENTS // (sum(sizes) + 1)))


def _concat(arrays, device) -> wp.array:
    # the device arrays `arrays` (one dtype) end to end, as one array on `device` (the same values)
    host = np.concatenate([a.numpy() for a in arrays])
    return wp.array(host, dtype=arrays[0].dtype, device=device)


def _offset_copies(values: np.ndarray, count: int, stride: int, dtype, device) -> wp.array:
    # `count` copies of the index array `values`, copy k offset by k x stride
    copies = np.concatenate([values + k * stride for k in range(count)])
    return wp.array(copies.astype(np.int32), dtype=dtype, device=device)


def _csr_copies(offsets: np.ndarray, count: int, device) -> wp.array:
    # the CSR offsets of `count` copies of a table whose offsets are `offsets` [n + 1]
    total = int(offsets[-1])
    out = np.concatenate([offsets[:-1] + k * total for k in range(count)] + [[count * total]])
    return wp.array(out.astype(np.int32), dtype=wp.int32, device=device)


class StackedModel:
    """K Models of one mesh (the same topology, rest shape, support and tissue law; each its own
    constants) as the one Model of K copies of the mesh that a batch's kernels read, on `device`.

    The geometry and the support are the first model's (`mesh`, `dmesh`: a region is built on the
    one mesh); the per-vertex, per-spring and per-entry arrays are the items' in order (item k's
    vertex v at k x vertex_stride + v, spring s at k x edge_stride + s). force_bounds: each item's
    force_bound, where the caller has them (else made when first asked for)."""

    def __init__(self, models: list, device=None, force_bounds: list | None = None):
        if not models:
            raise ValueError("a stack needs at least one model")
        base = self.base = models[0]
        for k, m in enumerate(models[1:], start=1):
            if m.mesh is not base.mesh or m.law != base.law or not np.array_equal(m.support_mask, base.support_mask):
                raise ValueError(f"model {k} of the stack has another mesh, tissue law or support than model 0")
        if len(models) > stack_limit(base.mesh):
            raise ValueError(f"{len(models)} models of {base.particle_count} vertices are more than a stack holds ({stack_limit(base.mesh)})")
        self.models = list(models)
        """The items' models, in stack order."""
        self.device = d = wp.get_device(device if device is not None else base.device)
        self.dmesh = base.dmesh if base.device == d else as_device_mesh(base.mesh, d)
        self.mesh, self.law, self.law_entry, self.tissue = base.mesh, base.law, base.law_entry, base.tissue
        self.fixed_below, self.support_mask, self.support_count = base.fixed_below, base.support_mask, base.support_count
        self.vertex_normal_rest = base.vertex_normal_rest
        K = self.item_count = len(models)
        n, e = self.vertex_stride, self.edge_stride = base.particle_count, base.spring_count
        self.particle_count, self.spring_count = K * n, K * e
        for name in ("particle_q_rest", "particle_mass", "anchor_ke", "anchor_kd", "spring_ke", "spring_kd", "spring_rest_length",
                     "adj_spring"):
            setattr(self, name, _concat([getattr(m, name) for m in models], d))
        offsets, vertex, edge = base.mesh.adjacency
        self.adj_offsets = _csr_copies(np.asarray(offsets), K, d)
        self.adj_vertex = _offset_copies(np.asarray(vertex), K, n, wp.int32, d)
        self.adj_edge = _offset_copies(np.asarray(edge), K, e, wp.int32, d)
        self.arrays = struct_from(TissueArrays, self, q_rest=self.particle_q_rest)
        """The items' TissueArrays as one (kernels/arrays.py)."""
        self._stack_entries(models)
        self._bounds = force_bounds

    def _stack_entries(self, models) -> None:
        # the law's entries (Model.entries): offsets and topology the mesh's with offsets, parameters the items'
        base, K, d = self.base, self.item_count, self.device
        topology = base.entry_topology
        self.entry_offsets = _csr_copies(base.entry_offsets.numpy(), K, d)
        self.entry_topology = _offset_copies(topology.numpy(), K, self.vertex_stride, topology.dtype, d)
        self.entry_params = _concat([m.entry_params for m in models], d)
        self.nodal_pressure = wp.zeros(self.particle_count if self.law_entry.volumetric else 1, dtype=wp.float32, device=d)
        self.entries = self.law_entry.kernels.Entries()
        self.entries.offsets, self.entries.topology, self.entries.params = self.entry_offsets, self.entry_topology, self.entry_params
        self.entries.pressure = self.nodal_pressure

    def stiffness_bound(self) -> float:
        """The stiffest item's stiffness bound [N/m] (Model.stiffness_bound)."""
        return max(m.stiffness_bound() for m in self.models)

    def force_bound(self, k: int) -> float:
        """Item k's force bound [N] (solvers.stepper.force_bound of its model): a press past it diverged."""
        if self._bounds is None:
            self._bounds = [force_bound(m) for m in self.models]
        return self._bounds[k]


class ItemBatch(BatchPalpation):
    """B palpations of the items of a StackedModel: palpation b presses item items[b]'s copy.

    Made as a BatchPalpation (rings, dt, integrator, probe, substeps: every palpation the same; a
    dataset groups its items by the substeps each needs). build(vertices, depth, items) builds the
    regions on the shared mesh (or gathers them from `region_table`) and offsets each to its item;
    the press is BatchPalpation's; each palpation's result is checked against its own item's bound.
    item_critical_dt: {item: its critical step [s]} (the caller's estimates, which a diverged press's error
    names); where none are given, substeps "auto" takes the shortest of each item's own (Model.critical_dt
    of the free vertices of its palpations)."""

    def __init__(self, stacked: StackedModel, **kw):
        super().__init__(model=stacked, **kw)
        self.item_critical_dt = {}
        if self.probe_radius > 0:  # each copy's surface vertices
            surface = np.zeros(stacked.vertex_stride, dtype=np.int32)
            surface[self.mesh.surface_vertices] = 1
            self.probe_surface = wp.array(np.tile(surface, stacked.item_count), dtype=wp.int32, device=self.device)
        if self.records.spec.tactile_size:  # each copy's vertex areas (the contact patch's, kernels/probes/press.py)
            area = self.records.vertex_area.numpy()
            self.records.vertex_area = self.buffers.upload("records.vertex_area", np.tile(area, stacked.item_count), wp.float32)
            self.records.allocate(1)
        self.items = np.zeros(0, dtype=np.int64)
        """The item (stack index) each palpation presses, int64 [B]."""

    def build(self, vertices, depth=None, items=None) -> "ItemBatch":
        """The regions of `vertices` (mesh ids, as BatchPalpation.build) for items `items` (stack indices,
        one a vertex; default: the last build's, else item 0)."""
        super().build(vertices, depth)
        if items is None:  # the same palpations built again (a sphere's patches at another depth), or item 0
            items = self.items if len(self.items) == self.batch_size else np.zeros(self.batch_size, dtype=np.int64)
        items = np.asarray(items).reshape(-1)
        if len(items) != self.batch_size or not np.issubdtype(items.dtype, np.integer):
            raise ValueError(f"items must be {self.batch_size} integers (one a vertex), got {len(items)} of {items.dtype}")
        bad = np.flatnonzero((items < 0) | (items >= self.model.item_count))
        if len(bad):
            raise ValueError(f"item {int(items[bad[0]])} (palpation {bad[0]}) is not in the stack of {self.model.item_count}")
        self.items = items.astype(np.int64)
        m = self.model
        br.offset_regions(self.regions, self.buffers.upload("items", self.items.astype(np.int32), wp.int32), m.vertex_stride, m.edge_stride)
        return self

    def _union_critical_dt(self) -> float:
        # the caller's estimates, else each item's over its own palpations' free vertices: the shortest
        if self.item_critical_dt:
            return min(self.item_critical_dt.values())
        rv = host_copy(self.regions.region_vertex) % self.model.vertex_stride
        free = np.arange(rv.shape[1])[None, :] < self.free_vertex_counts[:, None]
        caches = self.__dict__.setdefault("_item_critical_cache", {})
        return min(union_critical_dt(self.model.models[k], lambda k=k: rv[self.items == k][free[self.items == k]], self.frame_dt,
                                     None, self._fixed_substeps, caches.setdefault(int(k), {})) for k in np.unique(self.items))

    def _sibling(self, substeps: int) -> "ItemBatch":
        kw = self._sibling_kw(substeps)
        batch = ItemBatch(kw.pop("model"), **kw)
        batch.item_critical_dt = self.item_critical_dt
        return batch

    def _build_rows(self, batch: "ItemBatch", rows: np.ndarray) -> "ItemBatch":
        return batch.build(self.vertices[rows], self.depth, self.items[rows])

    def _row_bounds(self) -> np.ndarray:
        return np.array([self.model.force_bound(int(k)) for k in range(self.model.item_count)])[self.items]

    def _check_results(self, peak, hold, recovery) -> None:
        """SimulationDiverged naming the first palpation whose result is not finite or past its item's bound."""
        size = self._mesh_size()
        for k in np.unique(self.items):
            sel = self.items == k
            check_results(f"batch's {self.integrator}", self.vertices[sel], peak[sel], recovery[sel], self.model.force_bound(int(k)),
                          size, self.frame_dt, self.substeps, self.item_critical_dt.get(int(k), self.critical_dt), hold=hold[sel])


def result_rows(result: BatchResult, begin: int, end: int) -> BatchResult:
    """Palpations begin..end of a batch's result (its learning records too), as a result of their own."""
    return BatchResult(vertex=result.vertex[begin:end], depth=result.depth, peak_force=result.peak_force[begin:end],
                       hold_force=result.hold_force[begin:end], recovery_error=result.recovery_error[begin:end],
                       region_vertices=result.region_vertices[begin:end], free_vertices=result.free_vertices[begin:end],
                       records={name: values[begin:end] for name, values in result.records.items()},
                       substeps=None if result.substeps is None else result.substeps[begin:end],
                       ring_gap=None if result.ring_gap is None else result.ring_gap[begin:end])
