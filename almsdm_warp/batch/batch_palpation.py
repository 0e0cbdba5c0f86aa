"""Many palpations at once on one mesh: B contacts, each with its own region, probe and state.

``BatchPalpation(mesh).touch(vertices)`` builds B ring regions on the device in one launch
(kernels/region/batch_rings.py); ``press(depth, ramp, hold, settle)`` runs the press protocol of
``Palpation.press`` on all of them, many steps per launch, one block per palpation with the
region on chip on CUDA (kernels/explicit/batch_fast.py; the exact kernel, kernels/explicit/batch.py,
on the CPU). The physics, summation order and integration formula are the one-palpation explicit
step's, so a palpation of the exact kernel gives the same bits as ``Palpation`` on the same device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..mesh.device_mesh import check_vertex
from ..kernels.arrays import BatchElements, BatchPress, BatchRegionArrays, BatchSphere, struct_from
from ..kernels.explicit import batch as bk
from ..kernels.explicit import batch_fast as bkf
from ..kernels.region import batch_rings as br
from ..checks import fixed_substeps, substeps_for
from ..checks import check_value
from ..protocol.palpation import PATCH_DEPTH, check_probe_radius
from ..solvers import integrators, solver_class
from ..solvers.stepper import REPRESSES, check_results, diverged_rows, force_bound, may_press_again, plan_substeps
from ..sim.model import Model
from ..region.patch import sphere_patches
from ..region.region import check_rings
from .critical_step import certified_critical_dt


KERNELS = ("fast", "exact")


def host_copy(a: wp.array) -> np.ndarray:
    """A host copy of `a`, read on the device's current stream.

    ``array.numpy()`` copies on the CUDA null stream, which waits for every stream of the device:
    a read here waits only for the work queued before it on the current stream, so a sweep can
    build the next chunk's regions on one stream while another presses."""
    if a.device.is_cpu:
        return a.numpy()
    host = wp.empty(a.shape, dtype=a.dtype, device="cpu")
    wp.copy(host, a)
    wp.synchronize_stream(a.device.stream)
    return host.numpy()


class DeviceBuffers:
    """A batch's per-build device arrays, kept from one build to the next of the same size, and its
    uploads, copied on the device's current stream from pinned host buffers kept likewise.

    A sweep builds and launches one chunk on a stream while another chunk presses on a second
    stream. A new device array per build frees the last one on the CUDA null stream (Warp's
    stream-ordered free), and an upload from pageable memory makes the host wait for its stream;
    together they make the host wait for the other chunk's press. Arrays of the same shape are
    therefore reused (their earlier contents are only read by work queued before, on the same
    stream), and uploads go through pinned memory without a host wait: a pinned buffer is written
    again only after the copy that read it last has run (its event)."""

    def __init__(self, device):
        self.device = device
        self._arrays: dict = {}
        self._staging: dict = {}

    def array(self, name: str, shape, dtype, zero: bool = True) -> wp.array:
        """A device array of `shape` and `dtype` under `name`: the one held there where it has the same
        trailing shape and at least as many rows (its first rows: a sweep's smaller last chunks free
        nothing), else a new one, held; zeroed on the current stream when `zero`."""
        shape = tuple(int(n) for n in np.atleast_1d(shape))
        held = self._arrays.get(name)
        if held is None or held.shape[1:] != shape[1:] or held.shape[0] < shape[0] or held.dtype != dtype:
            held = self._arrays[name] = (wp.zeros if zero else wp.empty)(shape, dtype=dtype, device=self.device)
            return held
        if held.shape[0] > shape[0]:
            held = held[: shape[0]]
        if zero:
            held.zero_()
        return held

    def upload(self, name: str, values: np.ndarray, dtype) -> wp.array:
        """`values` as a device array of their shape under `name` (as array(); a vector dtype takes the last
        axis), copied on the current stream (no wait on CUDA)."""
        values = np.ascontiguousarray(values)
        if self.device.is_cpu:
            return wp.array(values, dtype=dtype, device=self.device)
        out = self.array(name, values.shape[:values.ndim - len(getattr(dtype, "_shape_", ()))], dtype, zero=False)
        size = out.size
        pinned, event = self._staging.get(name, (None, None))
        if pinned is None or len(pinned) < size or pinned.dtype != dtype:
            pinned, event = wp.empty(max(size, 1), dtype=dtype, device="cpu", pinned=True), None
        if event is not None:
            wp.synchronize_event(event)  # the last copy from this buffer has run
        view = pinned[:size]
        view.numpy()[...] = values.reshape(view.numpy().shape)
        if size:
            wp.copy(out, view, count=size)  # both contiguous: element for element
        self._staging[name] = (pinned, self.device.stream.record_event())
        return out


def union_critical_dt(model, free, frame_dt: float, bound, fixed, cache: dict) -> float:
    """The critical step [s] of a batch's free vertices together (Model.critical_dt of their union, `free()`:
    their mesh ids, asked only where needed), cached in `cache` by that set; `bound` (a lower bound of
    every region's, or None) where one substep of `frame_dt` [s] is stable under it and the substeps are
    not `fixed` (the union's step is no shorter: the same substeps), or where a piece of the union gives
    as many substeps as it (batch/critical_step.py)."""
    if not fixed and bound is not None and substeps_for(frame_dt, (1 - 1e-4) * bound) == 1:
        return bound
    held = np.zeros(model.particle_count, dtype=bool)
    held[free()] = True
    vertices = np.flatnonzero(held)  # np.unique's, without sorting every region's entries
    if not fixed and bound is not None:
        certain = certified_critical_dt(model, vertices, frame_dt, bound, cache)
        if certain is not None:
            return certain
    key = vertices.tobytes()
    if key not in cache:
        cache[key] = model.critical_dt(vertices)
    return cache[key]


def _pow2(n: int, minimum: int = 1) -> int:
    return max(minimum, 1 << max(int(n) - 1, 0).bit_length())


@dataclass
class BatchResult:
    """One press at each of B contact vertices (SI inside; the properties give people's units)."""

    vertex: np.ndarray
    """Contact vertex of each palpation, int64 [B]."""
    depth: float
    """Press depth [m]."""
    peak_force: np.ndarray = field(repr=False)
    """Largest |feedback force| while pressed [N], [B] (as PressResult.peak_force_N computes it)."""
    hold_force: np.ndarray = field(repr=False)
    """|feedback force| at the last pressed step (full depth, end of hold) [N], [B]."""
    recovery_error: np.ndarray = field(repr=False)
    """Distance of the contact vertex from rest at the end of the settle window [m], [B]."""
    region_vertices: np.ndarray = field(repr=False)
    free_vertices: np.ndarray = field(repr=False)
    records: dict = field(default_factory=dict, repr=False)
    """The learning records asked for (batch/records.py's BatchRecordArrays.read: force_curve [N] and
    curve_depth [m], [B, points]; patch_area [m^2], [B]; tactile [Pa], [B, n * n]), else empty."""
    substeps: np.ndarray | None = field(default=None, repr=False)
    """The integrator's steps a frame each press took, int [B]: the batch's plan, or more where a press
    diverged at the plan and was pressed again (REPRESSES)."""
    ring_gap: np.ndarray | None = field(default=None, repr=False)
    """Each press's PressResult.ring_gap [m], [B]: its sphere's least distance at full depth from a vertex
    of its region's fixed outer ring; None but for a sphere on a tet mesh."""

    # the names of PressResult, each with its unit (the fields above are SI, named without one)
    @property
    def peak_force_N(self) -> np.ndarray:
        """Largest |feedback force| while pressed [N], [B] (PressResult.peak_force_N of each)."""
        return self.peak_force

    @property
    def hold_force_N(self) -> np.ndarray:
        """|feedback force| at the end of the hold [N], [B] (PressResult.hold_force_N of each)."""
        return self.hold_force

    @property
    def recovery_error_mm(self) -> np.ndarray:
        """Distance of the contact vertex from rest at the end of the settle window [mm], [B]
        (PressResult.recovery_error_mm of each; `recovery_error` is the same in metres)."""
        return self.recovery_error * 1e3

    @property
    def stiffness_N_per_mm(self) -> np.ndarray:
        """Hold force over depth [N/mm]: the tissue's stiffness under the probe."""
        return self.hold_force / (self.depth * 1e3)


class BatchRegions:
    """Compacted per-palpation regions of fixed capacity, on the device (see kernels/region/batch_rings.py)."""

    def __init__(self, batch_size: int, vertex_capacity: int, entry_capacity: int, rings: int, device, zeros=True, buffers=None):
        # zeros=False: left uninitialised, for a gather that writes every element (RegionTable.gather);
        # buffers (DeviceBuffers): the arrays of its last build of this size, reused
        B, cv, ce, d = batch_size, vertex_capacity, entry_capacity, device
        self.rings = rings
        if buffers is None:
            alloc = wp.zeros if zeros else wp.empty
        else:
            names = iter(range(1 << 8))
            alloc = lambda shape, dtype, device: buffers.array(f"regions.{next(names)}", shape, dtype, zero=zeros)
        self.vertex_capacity = cv
        self.entry_capacity = ce
        self.region_vertex = alloc((B, cv), dtype=wp.int32, device=d)
        """Mesh id of each region vertex in local order (ring after ring), shape [B, capacity]."""
        self.ring_offsets = alloc((B, rings + 2), dtype=wp.int32, device=d)
        """Ring r of palpation b is region_vertex[b, ring_offsets[b, r]:ring_offsets[b, r + 1]]."""
        self.region_count = alloc(B, dtype=wp.int32, device=d)
        self.free_count = alloc(B, dtype=wp.int32, device=d)
        """Free vertices (all but the fixed outer ring): the first free_count in local order."""
        self.local_offsets = alloc((B, cv + 1), dtype=wp.int32, device=d)
        """CSR offsets of the free vertices' neighbour lists, shape [B, capacity + 1]."""
        self.local_neighbour = alloc((B, ce), dtype=wp.int32, device=d)
        """Local index of each CSR neighbour (mesh CSR order), shape [B, entry capacity]."""
        self.local_edge = alloc((B, ce), dtype=wp.int32, device=d)
        """Mesh edge id (spring) of each CSR entry, shape [B, entry capacity]."""
        self.local_owner = alloc((B, ce), dtype=wp.int32, device=d)
        """Local index of the free vertex each CSR entry belongs to, shape [B, entry capacity]."""
        self.local_spring = alloc((B, ce), dtype=wp.int32, device=d)
        """Per CSR entry: s + 1 when it reads spring s as is, -(s + 1) negated (its mirror entry's)."""
        self.spring_entry = alloc((B, ce), dtype=wp.int32, device=d)
        """The CSR entry that computes each spring (each spring of the region once), [B, entry capacity]."""
        self.spring_count = alloc(B, dtype=wp.int32, device=d)
        self.entry_count = alloc(B, dtype=wp.int32, device=d)
        """CSR entries of each palpation's free vertices (its local_offsets[b, free_count[b]])."""
        self.status = alloc(B, dtype=wp.int32, device=d)
        self.arrays = struct_from(BatchRegionArrays, self)
        """The arrays above as one kernel argument (kernels/arrays.py)."""


class RegionTable:
    """The regions of distinct contacts, built once (a BatchRegions row each) and gathered by index.

    A sweep presses each vertex of a mesh many times (1e6 points on 1,002 vertices); the table builds
    each distinct contact's region once (with a sphere, for one patch depth), and a batch of those
    contacts takes its regions from it with one gather launch and no read-back: the counts the batch
    plans with and each contact's local index are host copies taken once here."""

    def __init__(self, vertices: np.ndarray, patch_depth, regions: BatchRegions, contact_local: np.ndarray):
        self.vertices = vertices
        """The distinct contact vertices, sorted, int64: row r holds vertices[r]'s region."""
        self.patch_depth = patch_depth
        """Depth [m] the sphere's patches were sized for, or None (no sphere)."""
        self.regions = regions
        self.counts = tuple(host_copy(a) for a in (regions.region_count, regions.free_count, regions.entry_count,
                                                   regions.spring_count))
        """Host copies of region_count, free_count, entry_count and spring_count, a row each."""
        self.contact_local = contact_local

    def rows(self, vertices: np.ndarray, patch_depth) -> "np.ndarray | None":
        """Each of `vertices`' row, or None where one is not in the table (or the patch depth differs)."""
        if patch_depth != self.patch_depth:
            return None
        rows = np.minimum(np.searchsorted(self.vertices, vertices), len(self.vertices) - 1)
        return rows if np.array_equal(self.vertices[rows], vertices) else None

    def gather(self, rows: np.ndarray, buffers: DeviceBuffers) -> BatchRegions:
        """The regions of the contacts at `rows`, as a build of them gives them (the same bits), in
        `buffers`' arrays (the gathering batch's DeviceBuffers)."""
        t = self.regions
        out = BatchRegions(len(rows), t.vertex_capacity, t.entry_capacity, t.rings, t.region_vertex.device, zeros=False, buffers=buffers)
        br.gather_regions(t, buffers.upload("rows", rows.astype(np.int32), wp.int32), out)
        return out


class BatchPalpation:
    """B palpations of one mesh, built and stepped together.

    integrator: "explicit" (semi-implicit Euler, many steps per launch, a block per palpation) or
    "implicit" (backward Euler with CG, as SolverImplicit's: one thread per palpation, one launch a
    step; cg_max_iterations and cg_tolerance as the solver's).

    rings: the local model's rings (the outermost fixed). dt [s]: the frame. The explicit
    integrator steps dt / substeps, with substeps chosen at each touch() to keep that step under
    0.9 x the critical step of the batch's free vertices together (Model.critical_dt of their union,
    which no single region's exceeds); past LIMITS["substeps"] the batch runs the implicit
    integrator and says so in `notes`. substeps: "auto" (that) or a fixed int >= 1.
    A press whose result is not finite or beyond force_bound diverged: where its substeps were planned
    ("auto"), it is pressed again at twice the substeps, up to REPRESSES times (BatchResult.substeps
    says each press's); else, or still, the press raises SimulationDiverged.
    kernel (explicit): "fast" (CUDA's default where the regions fit: one block per palpation, its
    threads sharing the springs, each computed once, with an approximate reciprocal square root
    and no division in the step: forces within 5e-6 relative of the exact kernel's) or "exact" (a
    block's threads share the free vertices, the same bits as Palpation on the same device; the
    CPU's default, and CUDA's where the fast kernel cannot hold the regions). threads: threads
    per block on CUDA (default 64 for "fast"; for "exact" enough for the largest region's free
    vertices, 32..256).
    capacity: first guess of a region's vertex count (default: twice a regular mesh's); a build
    that overflows it is redone with twice the capacity.
    probe_radius [m]: 0, the paper's probe (each contact vertex driven); > 0, a rigid sphere in
    frictionless one-sided contact with every free surface vertex it would contain, each region
    grown from the patch the sphere covers at the press's depth (Palpation's rule); the feedback
    force is the sum of the contact reactions.
    Model keywords (edge_scale, anchor_scale: a lesion; fixed_below [m]: vertices with z below it are
    supported, left out of every free set, as Palpation does); or pass a ready `model`.
    records: the learning records (batch/records.py's Records: a force curve along the ramp, the contact
    patch and tactile map at the end of the hold), in BatchResult.records; the patch and map by the exact kernel.
    """

    def __init__(
        self, mesh=None, tissue=None, *, rings=4, dt=1e-3, device=None, model=None, integrator="explicit",
        kernel=None, threads=None, capacity=None,
        cg_max_iterations=200, cg_tolerance=1e-6, substeps="auto", probe_radius=0.0, records=None, **model_kw,
    ):
        check_probe_radius(probe_radius)  # its type and magnitude before the model is made
        self.model = model if model is not None else Model(mesh, tissue, device, **model_kw)
        self.probe_radius = check_probe_radius(probe_radius, self.model.mesh)
        self.device = self.model.device
        held = self.model.support_mask if self.model.support_count else np.zeros(1, dtype=bool)
        self.support = wp.array(held.astype(np.int32), dtype=wp.int32, device=self.device)
        """1 for each supported mesh vertex (one 0 where none is), int32: the region build leaves them out of the free set."""
        surface = np.zeros(max(self.model.particle_count, 1), dtype=np.int32)
        if self.probe_radius > 0:
            surface[self.model.mesh.surface_vertices] = 1
        self.probe_surface = wp.array(surface, dtype=wp.int32, device=self.device)
        """1 for each mesh vertex the sphere may touch (a surface vertex), int32."""
        self.patch_depth = None
        """Depth [m] the sphere's patches (each region's ring 0) were sized for; None: no sphere."""
        self.mesh = self.model.mesh
        self.rings = check_rings(rings)
        if self.rings < 1:
            raise ValueError(f"rings must be >= 1, got {rings}")
        self.frame_dt = check_value(dt, float, "> 0", "dt [s]")
        """The frame [s]: the dt asked for; the kernels step `dt`, the frame over its substeps."""
        if integrator not in integrators(batch=True):
            solver_class(integrator)  # an unknown name: the registry's error
            raise ValueError(f"the {integrator} integrator has no batch press (those that have: {', '.join(integrators(batch=True))})")
        self.model.law_entry.require(integrator=integrator, path="batch")
        self.integrator = self.requested_integrator = integrator
        self._fixed_substeps = fixed_substeps(substeps)
        # substeps (explicit steps a frame), critical_dt [s] of the batch's free vertices and notes (what
        # the batch changed on its own): as Palpation's, set by plan_substeps at each touch()
        self.substeps, self.critical_dt, self.notes = 1, math.inf, []
        self.represses = REPRESSES if self._fixed_substeps is None else 0
        """How many more times a press that diverged is pressed again at twice the substeps (REPRESSES)."""
        self.known_critical_dt = None
        """The critical step [s] of the contacts' free vertices where the caller knows it (a re-press:
        the batch's that diverged), or None: estimated at each touch()."""
        self._critical_cache, self._bound = {}, force_bound(self.model)
        self.critical_dt_bound = None
        """A lower bound [s] of every region's critical step (the whole mesh's Model.critical_dt()),
        or None. Where one substep is stable under that bound (less 1e-4 relative: the estimates of a
        region and of the whole mesh agree to 1e-7 where they meet), touch() takes one substep
        without estimating the batch's own critical step, which is no shorter: the same substeps."""
        self.cg_max_iterations = int(cg_max_iterations)
        self.cg_tolerance = float(cg_tolerance)
        if kernel is not None and kernel not in KERNELS:
            raise ValueError(f"unknown kernel {kernel!r} (known: {', '.join(KERNELS)})")
        self._kernel = kernel
        self._threads = threads
        self._capacity = capacity
        self.batch_size = 0
        self.regions = None
        self.region_table = None
        """A RegionTable (cache_regions) that build() gathers from where it holds every contact, or None."""
        self._region_host = None  # host copies of the regions' counts where build() has them without a read-back
        self._entry_offsets_host = None  # the model's entry offsets, read once (_entry_offsets)
        self.buffers = DeviceBuffers(self.device)
        """The per-build device arrays and uploads, reused from one build to the next (DeviceBuffers)."""
        self.vertices = np.zeros(0, dtype=np.int64)
        from .records import BatchRecordArrays

        if records is not None:
            records.check(self.probe_radius, integrator)
        self.records = BatchRecordArrays(records, self)
        """The learning records' device arrays (batch/records.py), placeholders where none is asked for."""
        offsets = self.mesh.adjacency[0]
        self._max_degree = int(np.diff(offsets).max(initial=1))

    # -- regions -------------------------------------------------------------------------------
    def touch(self, vertices, depth=None) -> "BatchPalpation":
        """Put a probe on each of `vertices` and build their regions (one launch, on the device). With
        a sphere, each region's ring 0 is the patch it covers pressed `depth` [m] deep (default PATCH_DEPTH)."""
        return self.build(vertices, depth).plan()

    def build(self, vertices, depth=None) -> "BatchPalpation":
        """touch()'s first half: the regions of `vertices` (and the sphere's patches), built on the device,
        or gathered from region_table where it holds them all (the same bits)."""
        self.vertices = self._checked_vertices(vertices)
        self.batch_size = len(self.vertices)
        if self.probe_radius > 0:
            self.patch_depth = PATCH_DEPTH if depth is None else float(depth)
        table = self.region_table
        rows = None if table is None else table.rows(self.vertices, self.patch_depth)
        if rows is not None:
            self.regions = table.gather(rows, self.buffers)
            self._region_host = tuple(c[rows] for c in table.counts)
            self._find_contacts(table.contact_local[rows])
            return self
        self._region_host = None
        self.regions = self._build_seeds(self.vertices)
        self._find_contacts()
        return self

    def _build_seeds(self, vertices) -> BatchRegions:
        # each contact's ring 0: the vertex itself, or the sphere's patch at patch_depth
        if self.probe_radius > 0:
            offsets, seeds = sphere_patches(self.model, vertices, self.probe_radius, self.patch_depth)
        else:
            offsets, seeds = np.arange(len(vertices) + 1, dtype=np.int32), vertices.astype(np.int32)
        return self._build_regions(offsets, seeds)

    def cache_regions(self, vertices, depth=None) -> RegionTable:
        """Build the regions of the distinct `vertices` once (with a sphere, for patches `depth` [m] deep,
        default PATCH_DEPTH) into region_table: build() of contacts among them then gathers their
        regions from it instead of building them (the same bits). Returns the table (a batch of the
        same model, rings and probe may share it: assign its region_table)."""
        distinct = np.unique(self._checked_vertices(vertices))
        patch_depth = None
        if self.probe_radius > 0:
            patch_depth = self.patch_depth = PATCH_DEPTH if depth is None else float(depth)
        regions = self._build_seeds(distinct)
        rv = host_copy(regions.region_vertex)
        local = np.argmax(rv == distinct[:, None], axis=1).astype(np.int32)
        self.region_table = RegionTable(distinct, patch_depth, regions, local)
        return self.region_table

    def plan(self) -> "BatchPalpation":
        """touch()'s second half, after build(): the kernel, substeps and states of those regions."""
        self._choose_kernel()
        self._build_elements()
        self.plan_substeps()
        self._allocate_states()
        br.rest_states(self)
        return self

    @property
    def dt(self) -> float:
        """The integrator's step [s]: the frame over its substeps (what every batch kernel reads)."""
        return self.frame_dt / self.substeps

    step_dt = dt

    def plan_substeps(self) -> None:
        """Substeps of the explicit integrator for the batch's regions (or the implicit fall-back):
        solvers.stepper.plan_substeps over the critical step of the batch's free vertices together."""
        known = self.known_critical_dt
        critical = self._union_critical_dt if known is None else (lambda: known)
        plan = plan_substeps(self.requested_integrator, self.frame_dt, critical, self._fixed_substeps, "the batch")
        if plan.note and plan.note not in self.notes:
            self.notes.append(plan.note)
        self.integrator, self.substeps, self.critical_dt = plan.integrator, plan.substeps, plan.critical_dt

    def _union_critical_dt(self) -> float:
        def free():
            rv = host_copy(self.regions.region_vertex)
            return rv[np.arange(rv.shape[1])[None, :] < self.free_vertex_counts[:, None]]

        return union_critical_dt(self.model, free, self.frame_dt, self.critical_dt_bound, self._fixed_substeps, self._critical_cache)

    def _checked_vertices(self, vertices) -> np.ndarray:
        verts = np.asarray(vertices)
        if verts.ndim != 1 or len(verts) == 0:
            raise ValueError(f"vertices must be a non-empty 1-D list of vertex ids, got shape {verts.shape}")
        if not np.issubdtype(verts.dtype, np.integer):
            raise TypeError(f"vertices must be integers, got {verts.dtype}")
        bad = np.flatnonzero((verts < 0) | (verts >= self.mesh.vertex_count))
        if len(bad):
            check_vertex(self.mesh, int(verts[bad[0]]), f"contact vertex (palpation {bad[0]})")
        if self.model.support_count:
            held = np.flatnonzero(self.model.support_mask[verts])
            if len(held):
                raise ValueError(f"vertex {int(verts[held[0]])} (palpation {held[0]}) is held by the support "
                                 f"(below the fixed plane): the probe cannot move it")
        return verts.astype(np.int64)

    def _find_contacts(self, local=None) -> None:
        # each contact vertex's local index (ring 0 is sorted, so a sphere's contact may be anywhere in it)
        if local is None:
            rv = host_copy(self.regions.region_vertex)
            local = np.argmax(rv == self.vertices[:, None], axis=1).astype(np.int32)
        self.contact_local = self.buffers.upload("contact_local", np.asarray(local, dtype=np.int32), wp.int32)
        """Local index of each palpation's contact vertex in its region, int32 [B]."""
        self._contact_local = local
        self.sphere_arrays = BatchSphere()
        self.sphere_arrays.radius = self.probe_radius
        self.sphere_arrays.radius64 = self.probe_radius
        self.sphere_arrays.probe_surface = self.probe_surface
        self.sphere_arrays.contact_local = self.contact_local

    def _build_regions(self, seed_offsets, seeds) -> BatchRegions:
        # build at a guessed capacity; a build that overflows it is redone with twice the capacity
        n, k = self.mesh.vertex_count, self.rings
        patch = int(np.diff(seed_offsets).max(initial=1))
        seed_offsets = wp.array(seed_offsets, dtype=wp.int32, device=self.device)
        seeds = wp.array(seeds, dtype=wp.int32, device=self.device)
        cv = _pow2(2 * (3 * k * (k + 1) + 1), 32) if self._capacity is None else int(self._capacity)
        if self._capacity is None and patch > 1:  # a patch grows by about its perimeter a ring
            cv = _pow2(2 * (patch + 4 * k * (int(math.sqrt(patch)) + k)), 32)
        # CSR entries of the free vertices: ~3.6 per region vertex on a surface (60% free, degree 6)
        ce = _pow2(cv * min(self._max_degree, 4), 8)
        while True:
            regions = BatchRegions(len(seed_offsets) - 1, cv, ce, k, self.device)
            br.build_regions(self.model.dmesh, seed_offsets, seeds, k, self.support, regions)
            status = host_copy(regions.status)
            if not np.any(status):
                return regions
            if np.any(status & br.BUILD_OVERFLOW):
                cv *= 2
            ce = ce * 2 if np.any(status & br.BUILD_CSR_OVERFLOW) else max(ce, _pow2(cv * min(self._max_degree, 4)))
            if cv > max(4 * n, 64):  # cannot happen for a valid mesh: a region never exceeds it
                raise RuntimeError("batch region build did not converge")

    def _choose_kernel(self) -> None:
        # the kernels' capacities: the largest region of this batch, not the build's guess
        regions = self.regions
        host = self._region_host or tuple(host_copy(a) for a in (regions.region_count, regions.free_count,
                                                                 regions.entry_count, regions.spring_count))
        counts = self.region_vertex_counts = host[0]
        free = self.free_vertex_counts = host[1]
        entries = int(host[2].max(initial=1))
        springs = int(host[3].max(initial=1))
        self.vertex_capacity = _pow2(int(counts.max()), 16)
        self.entry_capacity = _pow2(entries, 16)
        self.fast_plan = self._fast_plan(int(counts.max()), int(free.max()), entries, springs)
        cuda = self.device.is_cuda
        if self.model.law_entry.volumetric:  # the fast kernel is a layout of the springs law
            self.fast_plan = None
        if self.records.spec.tactile_size:  # the patch and tactile map are the exact kernel's (the fast one: the force curve)
            self.fast_plan = None
        kernel = self._kernel or ("fast" if cuda and self.fast_plan is not None else "exact")
        if kernel == "fast" and self.fast_plan is None:
            raise ValueError(
                f"the 'fast' kernel cannot hold these regions ({int(counts.max())} vertices, {springs} springs: "
                f"at most 16 springs a thread of 1024, and {bk.SHARED_BYTES_MAX // 1024} KiB of shared memory); use kernel='exact'"
            )
        self.kernel = kernel
        self.shared = bool(cuda and bk.shared_bytes(self.vertex_capacity, self.entry_capacity, self.model.law_entry.volumetric)
                           <= bk.SHARED_BYTES_MAX)
        if kernel == "fast":
            self.threads = self.fast_plan[0]
        elif not cuda:
            self.threads = 1
        elif self._threads is not None:
            self.threads = int(self._threads)
        else:
            self.threads = min(max(_pow2(int(free.max()), 32), 32), 256)

    def _build_elements(self) -> None:
        # a volumetric law's tets of each region's vertices (free and fixed ring), with local corners
        # (element_*), and its nodal pressures; a placeholder each for the springs law (its entries are
        # the regions' CSR)
        B, a = self.batch_size, self.buffers.array
        if not self.model.law_entry.volumetric:
            self.elements = BatchElements()
            self.elements.offsets = a("element_offsets", (1, 1), wp.int32)
            self.elements.topology = a("element_topology", (1, 1), wp.vec4i)
            self.elements.shift = a("element_shift", (1, 1), wp.int32)
            self.elements.pressure = a("element_pressure", (1, 1), wp.float32)
            return
        offsets = self._entry_offsets()
        member = np.arange(self.regions.vertex_capacity)[None, :] < self.region_vertex_counts[:, None]
        rv = np.where(member, host_copy(self.regions.region_vertex), 0)
        first = np.where(member, offsets[rv], 0)
        degree = np.where(member, offsets[rv + 1] - offsets[rv], 0)
        local = np.concatenate([np.zeros((B, 1), dtype=np.int64), np.cumsum(degree, axis=1)], axis=1)
        self.element_offsets = self.buffers.upload("element_offsets", local.astype(np.int32), wp.int32)
        """Each palpation's region vertices' tets (CSR, local entries), [B, vertex capacity + 1]."""
        self.element_topology = a("element_topology", (B, _pow2(int(local[:, -1].max(initial=1)), 16)), wp.vec4i, zero=False)
        """Each local entry's tet, its corners as local indices, [B, entry capacity]."""
        self.element_shift = self.buffers.upload("element_shift", (first - local[:, :-1]).astype(np.int32), wp.int32)
        """Per region vertex: its mesh entries' first index less its local entries' (the law's parameters are the mesh's)."""
        self.element_pressure = a("element_pressure", (B, rv.shape[1]), wp.float32)
        """Each region vertex's nodal pressure [Pa] (the implicit batch's; the explicit one keeps its own working array)."""
        br.build_elements(self, self.element_offsets, self.element_topology)
        self.elements = struct_from(BatchElements, self, offsets=self.element_offsets, topology=self.element_topology,
                                    shift=self.element_shift, pressure=self.element_pressure)
        """The four above as one kernel argument (kernels/arrays.py)."""

    def _entry_offsets(self) -> np.ndarray:
        # the model's entry offsets on the host, read once (array.numpy() would wait for every stream of the device)
        if self._entry_offsets_host is None:
            self._entry_offsets_host = host_copy(self.model.entry_offsets)
        return self._entry_offsets_host

    def _allocate_states(self) -> None:
        B, cv, a = self.batch_size, self.regions.vertex_capacity, self.buffers.array
        # global working arrays of the exact kernel where its regions do not fit in shared memory
        nv, nf, ni = bk.scratch_sizes(B, self.vertex_capacity, self.entry_capacity, self.shared or self.kernel != "exact",
                                      self.model.law_entry.volumetric)
        self.scratch_vec3 = a("scratch_vec3", nv, wp.vec3)
        self.scratch_float = a("scratch_float", nf, wp.float32)
        self.scratch_int = a("scratch_int", ni, wp.int32)
        self.scratch_wide = a("scratch_wide", 1, wp.vec4)  # a typed placeholder (shared memory is used)
        self.q_state = a("q_state", (B, cv), wp.vec3)
        """Positions of each palpation's region vertices [m], local order, shape [B, capacity]."""
        self.qd_state = a("qd_state", (B, cv), wp.vec3)
        """Velocities [m/s], same layout."""
        self.peak_force = a("peak_force", B, wp.float64)
        """Running largest |feedback force| [N] (its square with the "fast" kernel), [B]."""
        self.peak_reaction = a("peak_reaction", B, wp.vec3)
        self.hold_reaction = a("hold_reaction", B, wp.vec3)
        normals = -self.model.vertex_normal_rest[self.vertices]
        self.press_direction = self.buffers.upload("press_direction", normals, wp.vec3d)
        """Inward unit normal at each contact vertex (float64, as the host computes the target)."""
        self.press_arrays = struct_from(BatchPress, self, depth=0.0, ramp_steps=0, press_steps=0)
        """The press's schedule, directions and force records as one kernel argument (set again by start_press)."""

    def _fast_plan(self, max_vertices, max_free, max_entries, max_springs):
        """(threads, springs per thread, vertex, free-vertex and spring capacities, largest degree)
        of the "fast" kernel, or None where it cannot hold these regions."""
        threads = (bkf.SPHERE_THREADS if self.probe_radius > 0 else 64) if self._threads is None else int(self._threads)
        per_thread = -(-max_springs // threads)
        while per_thread > 16 and threads < 1024:  # registers are unrolled up to 16 springs a thread
            threads *= 2
            per_thread = -(-max_springs // threads)
        r16 = lambda x: -(-max(int(x), 1) // 16) * 16
        cv, cf, ce, cs = r16(max_vertices), r16(max_free), r16(max_entries), r16(max_springs)
        # CSR offsets and codes are int16 in shared memory
        if per_thread > 16 or max(cv, ce) > 32767 or bkf.shared_bytes_fast(cv, cf, cs, self._max_degree, threads if self.probe_radius > 0 else 0) > bk.SHARED_BYTES_MAX:
            return None
        return threads, max(per_thread, 1), cv, cf, cs, self._max_degree

    def region(self, b: int) -> np.ndarray:
        """Mesh ids of palpation b's region vertices in local order (host copy)."""
        return self.regions.region_vertex.numpy()[b, : self.region_vertex_counts[b]].copy()

    # -- the press -----------------------------------------------------------------------------
    def schedule(self, depth=0.01, ramp=0.1, hold=0.2, settle=1.0):
        """Steps of the press protocol: (ramp, pressed = ramp + hold, total), as Palpation.press counts."""
        from ..protocol.schedule import PressSchedule, check_press

        check_press(depth=depth, ramp=ramp, hold=hold, settle=settle)
        schedule = PressSchedule.from_times(self.step_dt, ramp, hold, settle)
        return schedule.ramp_n, schedule.release_step, schedule.total

    def start_press(self, depth=0.01, ramp=0.1, hold=0.2, settle=1.0, *, steps_per_launch=None, on_launch=None):
        """Launch the whole press (asynchronous on CUDA); `finish_press()` reads the results.

        steps_per_launch: steps in one launch (default: all); on_launch(steps) is called after each.
        """
        if self.regions is None:
            raise RuntimeError("touch(vertices) first: the batch has no contacts")
        ramp_n, press_n, total = self.schedule(depth, ramp, hold, settle)
        if self.probe_radius > 0:
            if self.patch_depth != depth:
                self.touch(self.vertices, depth)  # the patches the sphere covers at this depth
                ramp_n, press_n, total = self.schedule(depth, ramp, hold, settle)
            travel = depth / max(ramp_n, 1)
            if travel >= self.probe_radius:
                raise ValueError(f"the sphere would move {travel * 1e3:.3g} mm a step, not less than its radius "
                                 f"{self.probe_radius * 1e3:g} mm: it would pass through vertices; ramp longer or use a smaller dt")
        self.records.check_press(ramp_n)
        if self.records.spec.tactile_size and self.integrator != "explicit":
            raise ValueError(f"the tactile map is recorded by the explicit integrator only; the batch took the implicit "
                             f"fall-back ({'; '.join(self.notes)}): give a smaller dt")
        self.depth, self.press_args = float(depth), (depth, ramp, hold, settle)
        self.ring_gap = self._ring_gaps(float(depth))
        self.ramp_steps, self.press_steps, self.total_steps = ramp_n, press_n, total
        self.press_arrays = struct_from(BatchPress, self)
        if self.records.on:
            self.records.allocate(self.batch_size)  # zeroed: the patch and the map are sums
        br.rest_states(self)
        solver_class(self.integrator).press_batch(self, total, steps_per_launch, on_launch)

    def _ring_gaps(self, depth: float):
        # each palpation's BatchResult.ring_gap on the device (a [B] float array), or None: a sphere on tets only
        if self.probe_radius <= 0 or not self.mesh.tet_count:
            return None
        # the sphere's centre at full depth: touching the surface at rest, then `depth` along the inward normal
        centres = self.mesh.vertices[self.vertices] - self.model.vertex_normal_rest[self.vertices] * (depth - self.probe_radius)
        out = self.buffers.array("ring_gap", self.batch_size, wp.float32, zero=False)
        br.ring_gaps(self, self.buffers.upload("ring_gap.centre", centres.astype(np.float32), wp.vec3), out)
        return out

    def launch_steps(self, begin: int, count: int) -> None:
        """Launch steps begin..begin+count of the explicit press scheduled by start_press (no wait)."""
        solver_class("explicit").launch_batch_steps(self, begin, count)

    def finish_press(self) -> BatchResult:
        """Wait for the press and read it back (the force magnitudes as Palpation's host code takes them)."""
        q0 = bk.contact_positions(self).numpy()
        gap = None if self.ring_gap is None else host_copy(self.ring_gap)
        return self.result_from(self.peak_reaction.numpy(), self.hold_reaction.numpy(), q0, gap)

    def result_from(self, peak: np.ndarray, hold: np.ndarray, q0: np.ndarray, ring_gap: np.ndarray | None = None) -> BatchResult:
        """The press's result from host copies of peak_reaction, hold_reaction and each contact vertex's
        position (q_state at contact_local), as read when the press is done, and of ring_gap where it has
        one; SimulationDiverged as finish_press."""
        rest = self.mesh.vertices[self.vertices].astype(np.float32).astype(np.float64)
        # PressResult's expressions, vectorized: float32 components squared in float64 (Python's
        # x ** 2 and NumPy's agree), summed left to right; the norm of the float64 difference
        f64 = peak.astype(np.float64)
        peak_n = np.sqrt(f64[:, 0] ** 2 + f64[:, 1] ** 2 + f64[:, 2] ** 2)
        h64 = hold.astype(np.float64)
        hold_n = np.sqrt(h64[:, 0] ** 2 + h64[:, 1] ** 2 + h64[:, 2] ** 2)
        recovery = np.linalg.norm(q0 - rest, axis=1)
        result = BatchResult(
            vertex=self.vertices.copy(),
            depth=self.depth,
            peak_force=peak_n,
            hold_force=hold_n,
            recovery_error=recovery,
            region_vertices=self.region_vertex_counts.copy(),
            free_vertices=self.free_vertex_counts.copy(),
            records=self.records.read(self.depth, self.ramp_steps, host_copy) if self.records.on else {},
            substeps=np.full(self.batch_size, self.substeps, dtype=np.int32),
            ring_gap=None if ring_gap is None else np.asarray(ring_gap, dtype=np.float64).copy(),
        )
        bad = np.flatnonzero(diverged_rows(peak_n, recovery, self._row_bounds(), self._mesh_size(), hold_n))
        if len(bad):
            if not may_press_again(self.represses, self.integrator, self.substeps):
                self._check_results(peak_n, hold_n, recovery)
            self._press_again(result, bad)
        return result

    def _press_again(self, result: BatchResult, rows: np.ndarray) -> None:
        """Press the palpations `rows` again at twice the substeps (a batch of their own: the same model,
        regions and press, the next re-press its own) and put their results in `result`'s rows."""
        again = self._sibling(2 * self.substeps)
        again.region_table, again.critical_dt_bound = self.region_table, self.critical_dt_bound
        again.known_critical_dt, again.represses = self.critical_dt, self.represses - 1
        self._build_rows(again, rows).plan()
        redo = again.press(*self.press_args)
        for name in ("peak_force", "hold_force", "recovery_error", "region_vertices", "free_vertices", "substeps", "ring_gap"):
            if getattr(result, name) is not None:
                getattr(result, name)[rows] = getattr(redo, name)
        for name, values in redo.records.items():
            result.records[name][rows] = values

    def _sibling(self, substeps: int) -> "BatchPalpation":
        """A batch of this one's model, rings, frame, kernel and probe that steps `substeps` substeps."""
        return BatchPalpation(**self._sibling_kw(substeps))

    def _sibling_kw(self, substeps: int) -> dict:
        return dict(model=self.model, rings=self.rings, dt=self.frame_dt, integrator=self.requested_integrator, kernel=self._kernel,
                    threads=self._threads, capacity=self._capacity, probe_radius=self.probe_radius, substeps=substeps,
                    records=self.records.spec if self.records.on else None)

    def _build_rows(self, batch: "BatchPalpation", rows: np.ndarray) -> "BatchPalpation":
        """`batch` built for this batch's palpations `rows`."""
        return batch.build(self.vertices[rows], self.depth)

    def _row_bounds(self):
        """The force [N] past which a palpation's press diverged (solvers.stepper.force_bound): one for all."""
        return self._bound

    def _mesh_size(self) -> float:
        return float(np.ptp(self.mesh.vertices, axis=0).max())

    def _check_results(self, peak, hold, recovery) -> None:
        """SimulationDiverged naming the first palpation whose force or recovery is not finite or runs away."""
        check_results(f"batch's {self.integrator}", self.vertices, peak, recovery, self._bound, self._mesh_size(), self.frame_dt,
                      self.substeps, self.critical_dt, hold=hold)

    def press(self, depth=0.01, ramp=0.1, hold=0.2, settle=1.0, **kw) -> BatchResult:
        """Press every contact: ramp to `depth` [m] along the inward normal over `ramp` [s], hold
        `hold` [s], release and settle `settle` [s] (Palpation.press's protocol)."""
        self.start_press(depth, ramp, hold, settle, **kw)
        return self.finish_press()
