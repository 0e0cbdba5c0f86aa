"""A sweep's plan: everything that decides its numbers (SweepPlan, whose key names the parts a
resume may reuse), its table's columns, its chunks and step, and the checks made before any work."""

from __future__ import annotations

import hashlib
import json
import math
import threading
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..export.tables import TableLayout, millimetres
from .sampling import Sampling

_CPU_MODEL_LOCK = threading.Lock()
"""Held while a plan's CPU model is made (SweepPlan.model: the critical step's thread and the models' may ask at once)."""

COLUMNS = ("x_mm", "y_mm", "z_mm", "vertex", "peak_force_N", "hold_force_N", "stiffness_N_per_mm", "recovery_error_mm", "rings")
"""The table's columns; `hold_force_N`: the force at the end of the hold (BatchResult.hold_force); `rings`: the
ring count of each point's region (the same for all but at --rings auto)."""
SWEEP_TABLE = TableLayout("sweep table", {c: "int64" if c in ("vertex", "rings") else "float64" for c in COLUMNS},
                          optional=("hold_force_N", "rings"))
"""The sweep's table and its parts' (export/tables.py: .csv, .npz or .parquet); a table written before the rings or the
hold_force_N column has none."""


GPU_CHUNK = (16384, 65536)
"""The fewest and most points of a GPU's chunk (default_chunk; a dataset's units and item chunks keep to them)."""


def default_chunk(points: int, devices: list[str]) -> int:
    """Points a chunk when the command line gives none: 64 on the CPU (the progress moves, a resume
    loses little); on GPUs at least four chunks a device where the points allow (so the next chunk is
    built while one presses, and the devices share the work), 16384..65536 points each (a launch
    that fills an H200, a block a palpation, 40 times over; smaller chunks shorten what is not
    overlapped: the first chunk's build before the first press, the last one's read-back and
    writing after the last)."""
    if all(d == "cpu" for d in devices):
        return 64
    per_device = -(-points // len(devices))
    return max(1, min(per_device, max(GPU_CHUNK[0], min(-(-per_device // 4), GPU_CHUNK[1]))))


def default_tail(points: int, chunk: int, devices: list[str]) -> int:
    """The points at the end of a sweep over several GPUs pressed in chunks of a quarter (SweepPlan.tail): each
    device's last two chunks' worth, so that the devices finish within a small chunk of each other (a whole
    chunk apart before: 0.09-0.15 s of the stomach's). 0 on one GPU, where the small chunks' host work left
    the device idle longer (0.03-0.06 s a sweep) than their short last read-back saved; 0 on the CPU, and where
    a quarter chunk would be under GPU_CHUNK[0] points."""
    if len(devices) < 2 or all(d == "cpu" for d in devices) or chunk // 4 < GPU_CHUNK[0]:
        return 0
    return min(points, 2 * len(devices) * chunk)


@dataclass
class SweepPlan:
    """Everything that decides a sweep's numbers (its key names the parts a resume may reuse)."""

    mesh: object
    tissue: object
    edge_scale: np.ndarray | None
    anchor_scale: np.ndarray | None
    rings: "int | np.ndarray"
    """Rings of every point's region, or one ring count per point (--rings auto: sweep_auto.size_regions)."""
    dt: float
    depth: float
    ramp: float
    hold: float
    settle: float
    points: np.ndarray
    vertices: np.ndarray
    chunk: int
    integrator: str = "explicit"
    tol: float | None = None
    """--rings auto: the tolerance [m] the ring counts were sized to (for the record), else None."""
    probe_radius: float = 0.0
    """The spherical probe's radius [m] (BatchPalpation's probe_radius); 0: the paper's probe."""
    fixed_below: float | None = None
    """Support plane [m] (Model's fixed_below), or None."""
    sampling: "Sampling | None" = None
    """Where `points` and `vertices` are still being sampled (Sampling, filled block by block), or None;
    not part of the plan's numbers (the points are)."""
    law: str | None = None
    """The tissue law (Model's law; a law without kernels for a batch is refused before the plan)."""
    element_scale: np.ndarray | None = None
    """A volumetric law's lesion: each tet's modulus factor (Model's element_scale), or None."""
    records: "Records | None" = None
    """The learning records each press keeps (batch/records.py: the force curve, the patch and tactile map), or None."""
    lesion: object = None
    """The scene's lesion (tissue.lesion.Lesion) where the table labels each press with it (records.lesion_labels),
    else None; its effect on the numbers is in the scales above."""
    tail: int = 0
    """The last `tail` points are pressed in chunks of a quarter of `chunk` (default_tail), the others in chunks of `chunk`."""

    @property
    def table(self) -> TableLayout:
        """The layout of the sweep's table and its parts: SWEEP_TABLE, and the record columns asked for."""
        extra = self.records.dtypes(lesion=self.lesion is not None) if self.records is not None else {}
        return with_columns(SWEEP_TABLE, extra)

    def wait(self, end: int | None = None) -> None:
        """Return once the points up to `end` (all: None) are there (see `sampling`)."""
        if self.sampling is not None:
            self.sampling.wait(end)

    def __getstate__(self) -> dict:
        # pickled (Ray) with every point sampled and without the sampling's threads
        self.wait()
        return {k: v for k, v in self.__dict__.items() if k != "_cpu_model"} | {"sampling": None}

    def contacts(self, rings: int) -> np.ndarray | None:
        """The contacts whose regions of `rings` rings a sweep builds once and gathers (a RegionTable's,
        sorted), or None where no contact is pressed twice. Where the points are sampled behind the
        sweep (`sampling`): every surface vertex (there are more points than those, each snapped to
        one), whether or not the sampling is done, so that every device builds the same table."""
        if self.sampling is not None:
            return np.sort(self.mesh.surface_vertices).astype(np.int64)
        times = np.bincount(self.vertices[self.point_rings == rings], minlength=self.mesh.vertex_count)
        return np.flatnonzero(times) if times.max(initial=0) > 1 else None

    @property
    def point_rings(self) -> np.ndarray:
        """Ring count of each point's region, int64 [points]."""
        if isinstance(self.rings, (int, np.integer)):
            return np.full(len(self.vertices), int(self.rings), dtype=np.int64)
        return np.asarray(self.rings, dtype=np.int64)

    @property
    def ring_counts(self) -> list[int]:
        """The distinct ring counts of the plan's regions, ascending."""
        if isinstance(self.rings, (int, np.integer)):
            return [int(self.rings)]
        return [int(k) for k in np.unique(self.rings)]

    def key(self) -> str:
        self.wait()
        h = hashlib.sha256()
        scalars = ["table v3 (hold_force_N column)", self.mesh.path, self.mesh.vertex_count, self.dt, self.depth]
        scalars += [self.ramp, self.hold, self.settle, self.chunk, self.integrator, self.tol]
        if self.probe_radius or self.fixed_below is not None:
            scalars += [self.probe_radius, self.fixed_below]
        if self.law != "springs":
            scalars += [self.law]
        if self.tail:
            scalars += [f"tail {self.tail}"]
        if self.records is not None and (self.records.on or self.records.lesion_labels):  # other columns: other parts
            scalars += [f"records {self.records.curve_points} {self.records.tactile_size} {self.records.lesion_labels}"]
        h.update(json.dumps([str(s) for s in scalars] + [repr(self.tissue)]).encode())
        for a in (self.mesh.vertices, self.points, self.vertices, self.edge_scale, self.anchor_scale, self.point_rings,
                  *(() if self.element_scale is None else (self.element_scale,))):
            if a is not None:
                h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()[:16]

    @property
    def chunks(self) -> list[tuple[int, int]]:
        """(begin, end) of each chunk of points (made once for the plan's point count, chunk size and tail:
        a CPU sweep of 1e6 points has 15,625 chunks, each looked up here)."""
        n = len(self.vertices)
        key = (n, self.chunk, self.tail)
        if self.__dict__.get("_chunks_key") != key:
            head, small = n - min(self.tail, n), max(1, self.chunk // 4)
            self.__dict__["_chunks"] = [(i, min(i + self.chunk, head)) for i in range(0, head, self.chunk)] + [
                (i, min(i + small, n)) for i in range(head, n, small)]
            self.__dict__["_chunks_key"] = key
        return self.__dict__["_chunks"]

    def critical_dt(self) -> float:
        """The whole mesh's critical step [s] (Model.critical_dt at rest, a bound of every region's),
        computed once a plan: the command line's cost check and the sweep's substeps share it."""
        if "_critical_dt" not in self.__dict__:
            self.__dict__["_critical_dt"] = self.model("cpu").critical_dt()
        return self.__dict__["_critical_dt"]

    def model(self, device):
        """The plan's Model on `device`: made for each call, but the CPU's once a plan (the whole mesh's
        critical step and a CPU sweep's lanes read the same one: one model of a large mesh in memory)."""
        from ..sim.model import Model
        from ..warp_init import devices_started

        if str(device) != "cpu":
            devices_started()  # a context the command line started (warp_init.start_devices)
        make = lambda: Model(self.mesh, self.tissue, device, edge_scale=self.edge_scale, anchor_scale=self.anchor_scale,
                             fixed_below=self.fixed_below, law=self.law, element_scale=self.element_scale)
        if str(device) != "cpu":
            return make()
        with _CPU_MODEL_LOCK:
            if "_cpu_model" not in self.__dict__:
                self.__dict__["_cpu_model"] = make()
            return self.__dict__["_cpu_model"]

    def columns(self, begin: int, end: int, results) -> dict:
        """The output columns of points begin..end from [(indices in the chunk, BatchResult)], one per ring count."""
        p = millimetres(self.points[begin:end])
        n = end - begin
        out = {"x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "vertex": np.empty(n, dtype=np.int64),
               "rings": self.point_rings[begin:end].copy()}
        for c in ("peak_force_N", "hold_force_N", "stiffness_N_per_mm", "recovery_error_mm"):
            out[c] = np.empty(n, dtype=np.float64)
        for idx, result in results:
            out["vertex"][idx] = result.vertex
            out["peak_force_N"][idx] = result.peak_force
            out["hold_force_N"][idx] = result.hold_force
            out["stiffness_N_per_mm"][idx] = result.stiffness_N_per_mm
            out["recovery_error_mm"][idx] = result.recovery_error * 1e3
        if self.records is not None and self.records.on:
            from .records import record_columns

            widths = self.table.widths()
            for name in self.records.dtypes():
                out[name] = np.empty((n, widths[name]) if "[" in self.table.dtypes[name] else n, dtype=np.float64)
            for idx, result in results:
                for name, values in record_columns(result.records).items():
                    out[name][idx] = values
        if self.records is not None and self.records.lesion_labels and self.lesion is not None:
            from .records import lesion_columns

            out.update(lesion_columns(self.mesh, self.vertices[begin:end], self.lesion, self.probe_radius))
        return out


def with_columns(layout: TableLayout, extra: dict, meta: dict | None = None) -> TableLayout:
    """`layout` with the columns `extra` (name -> dtype) after its own (and `meta` for its entries): `layout`
    itself where there are none (the default tables stay as they were)."""
    from dataclasses import replace

    if not extra and meta is None:
        return layout
    return replace(layout, dtypes={**layout.dtypes, **extra}, meta=layout.meta if meta is None else meta)


def mesh_sha256(mesh) -> str:
    """The SHA-256 of a mesh's rest geometry and topology (vertices [m] float64, triangles, tetrahedra), in hex:
    the same mesh read from any file or made in memory gives the same hash."""
    h = hashlib.sha256()
    for a in (mesh.vertices, mesh.triangles, mesh.tetrahedra):
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def tissue_record(tissue) -> dict:
    """The tissue's type and parameters (SI units, as its dataclass names them), for a table's metadata."""
    from dataclasses import asdict, is_dataclass

    return {"type": type(tissue).__name__, **(asdict(tissue) if is_dataclass(tissue) else {"repr": repr(tissue)})}


def table_info(plan: SweepPlan, scene=None) -> dict:
    """What made a sweep's table (export/tables.py's `info`: a Parquet table's schema metadata): the package
    and its version, the scene, the mesh (file, hash, sizes), the material, the law, the lesion, the press, the
    rows for learning asked for (batch/records.py)."""
    from .. import __version__

    mesh = plan.mesh
    lesion = getattr(scene, "lesion", None)
    return {
        "package": "almsdm_warp", "version": __version__, "scene": None if scene is None else scene.name,
        "mesh": {"path": None if mesh.path is None else str(mesh.path), "sha256": mesh_sha256(mesh), "vertices": int(mesh.vertex_count),
                 "triangles": len(mesh.triangles), "tetrahedra": len(mesh.tetrahedra)},
        "material": tissue_record(plan.tissue), "law": plan.law, "lesion": None if lesion is None else lesion.as_dict(),
        "press": {"depth_mm": plan.depth * 1e3, "ramp_s": plan.ramp, "hold_s": plan.hold, "settle_s": plan.settle,
                  "dt_ms": plan.dt * 1e3, "probe_radius_mm": plan.probe_radius * 1e3, "integrator": plan.integrator,
                  "fixed_below_mm": None if plan.fixed_below is None else plan.fixed_below * 1e3},
        "records": None if plan.records is None else {"curve_points": plan.records.curve_points, "tactile_size": plan.records.tactile_size,
                                                      "lesion_labels": plan.records.lesion_labels},
    }


def sweep_critical_dt(plan: SweepPlan) -> float | None:
    """The whole mesh's critical step [s] (a bound of every region's, BatchPalpation.critical_dt_bound)
    for an explicit plan, computed once a sweep; None for an implicit one."""
    from ..solvers import solver_class

    return plan.critical_dt() if solver_class(plan.integrator).conditionally_stable else None


def press_steps(plan: SweepPlan) -> int:
    """Steps of one press of the plan (ramp, hold and settle), as BatchPalpation counts them."""
    from ..protocol.schedule import PressSchedule

    return PressSchedule.from_times(plan.dt, plan.ramp, plan.hold, plan.settle).total


def auto_dt(model, limit: float = 1e-3, safety: float = 0.9) -> float:
    """The step for a sweep: `limit` [s], or less where the model's critical step asks (a stiff lesion).

    Below the critical step of semi-implicit Euler over the whole mesh (Model.critical_dt, which
    bounds every region's), the step is `safety` x that, rounded down to a multiple of 0.05 ms.
    """
    crit = model.critical_dt()
    if not math.isfinite(crit) or crit >= limit:
        return limit
    step = math.floor(safety * crit / 5e-5) * 5e-5
    return step if step > 0 else safety * crit


def check_sphere_travel(radius: float, depth: float, dt: float, ramp: float) -> None:
    """InputError where a sphere of `radius` [m] would move its radius or more in one frame of the
    press's ramp (it would pass through vertices), before any work; BatchPalpation checks it again."""
    from ..protocol.schedule import PressSchedule

    travel = depth / PressSchedule.from_times(dt, ramp, 0.0, 0.0).ramp_n
    if radius > 0 and travel >= radius:
        raise InputError(f"the sphere would move {travel * 1e3:.3g} mm a step, not less than its "
                         f"radius {radius * 1e3:g} mm: it would pass through vertices; ramp longer or use a smaller --dt-ms")
