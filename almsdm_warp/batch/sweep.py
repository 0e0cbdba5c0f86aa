"""Palpation sweeps: a press at N points spread over an organ's surface, a force map as a table.

The points are spread evenly (farthest-point sampling of the surface vertices, or of a dense
surface sample snapped to the nearest vertex when N exceeds them). The work is cut into chunks of
points; each chunk is pressed as one batch (BatchPalpation) on one device and written at once, as
its own file, atomically, beside the output (``OUT.parts/``), so an interrupted sweep resumes
from what it wrote. Chunks go, in order, to whichever device given is free (a host thread a GPU),
where the next chunk is built and launched while one presses and the results are read back and
written on the side (run_local), each distinct contact's region built once a sweep and each
chunk's regions gathered from that table on the device (RingBatches); or to Ray actors of one GPU
each (``ray`` extra). Many points are sampled behind the first chunks (Sampling), and an .npz
output takes each chunk's rows as it is written (export/npz_rows.py). When all are done they are
gathered, in point order, into the output (.csv or .npz) and the parts removed.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import threading
import time
import zipfile
from concurrent.futures import Future
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..export.output import atomic_write
from ..export.tables import TableLayout

FPS_MAX = 20000
"""Beyond this many points (and the mesh's vertices), points are area-uniform random, not farthest-point."""
COLUMNS = ("x_mm", "y_mm", "z_mm", "vertex", "peak_force_N", "stiffness_N_per_mm", "recovery_error_mm", "rings")
"""The table's columns; `rings`: the ring count of each point's region (the same for all but at --rings auto)."""
SWEEP_TABLE = TableLayout("sweep table", {c: "int64" if c in ("vertex", "rings") else "float64" for c in COLUMNS},
                          optional=("rings",))
"""The sweep's table and its parts' (export/tables.py: .csv or .npz); a table written before the rings column has none."""


# -- points ------------------------------------------------------------------------------------
def farthest_points(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """Indices of `n` of `points` chosen greedily, each farthest from those already chosen."""
    p = np.asarray(points, dtype=np.float64)
    n = min(int(n), len(p))
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    diff = p - p[start]
    d2 = np.einsum("ij,ij->i", diff, diff)
    tmp = np.empty_like(d2)
    for i in range(1, n):  # buffers reused: no allocation per point
        chosen[i] = k = int(np.argmax(d2))
        np.subtract(p, p[k], out=diff)
        np.einsum("ij,ij->i", diff, diff, out=tmp)
        np.minimum(d2, tmp, out=d2)
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
    return max(1, min(per_device, max(16384, min(-(-per_device // 4), 65536))))


# -- the plan ----------------------------------------------------------------------------------
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

    def wait(self, end: int | None = None) -> None:
        """Return once the points up to `end` (all: None) are there (see `sampling`)."""
        if self.sampling is not None:
            self.sampling.wait(end)

    def __getstate__(self) -> dict:
        # pickled (Ray) with every point sampled and without the sampling's threads
        self.wait()
        return {**self.__dict__, "sampling": None}

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
        scalars = ["table v2 (rings column)", self.mesh.path, self.mesh.vertex_count, self.dt, self.depth]
        scalars += [self.ramp, self.hold, self.settle, self.chunk, self.integrator, self.tol]
        if self.probe_radius or self.fixed_below is not None:
            scalars += [self.probe_radius, self.fixed_below]
        h.update(json.dumps([str(s) for s in scalars] + [repr(self.tissue)]).encode())
        for a in (self.mesh.vertices, self.points, self.vertices, self.edge_scale, self.anchor_scale, self.point_rings):
            if a is not None:
                h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()[:16]

    @property
    def chunks(self) -> list[tuple[int, int]]:
        """(begin, end) of each chunk of points (made once for the plan's point count and chunk size:
        a CPU sweep of 1e6 points has 15,625 chunks, each looked up here)."""
        n = len(self.vertices)
        key = (n, self.chunk)
        if self.__dict__.get("_chunks_key") != key:
            self.__dict__["_chunks"] = [(i, min(i + self.chunk, n)) for i in range(0, n, self.chunk)]
            self.__dict__["_chunks_key"] = key
        return self.__dict__["_chunks"]

    def batch(self, device, model=None) -> "RingBatches":
        """The batches of this plan on `device`, one per ring count (with `model`, made on that device, when given)."""
        return RingBatches(self, model if model is not None else self.model(device))

    def critical_dt(self) -> float:
        """The whole mesh's critical step [s] (Model.critical_dt at rest, a bound of every region's),
        computed once a plan: the command line's cost check and the sweep's substeps share it."""
        if "_critical_dt" not in self.__dict__:
            self.__dict__["_critical_dt"] = self.model("cpu").critical_dt()
        return self.__dict__["_critical_dt"]

    def model(self, device):
        from ..sim.model import Model
        from ..warp_init import devices_started

        if str(device) != "cpu":
            devices_started()  # a context the command line started (warp_init.start_devices)

        return Model(self.mesh, self.tissue, device, edge_scale=self.edge_scale, anchor_scale=self.anchor_scale,
                     fixed_below=self.fixed_below)

    def columns(self, begin: int, end: int, results) -> dict:
        """The output columns of points begin..end from [(indices in the chunk, BatchResult)], one per ring count."""
        p = self.points[begin:end] * 1e3
        n = end - begin
        out = {"x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "vertex": np.empty(n, dtype=np.int64),
               "rings": self.point_rings[begin:end].copy()}
        for c in ("peak_force_N", "stiffness_N_per_mm", "recovery_error_mm"):
            out[c] = np.empty(n, dtype=np.float64)
        for idx, result in results:
            out["vertex"][idx] = result.vertex
            out["peak_force_N"][idx] = result.peak_force
            out["stiffness_N_per_mm"][idx] = result.stiffness_N_per_mm
            out["recovery_error_mm"][idx] = result.recovery_error * 1e3
        return out


def checked_columns(columns: dict) -> dict:
    """`columns`, or SimulationDiverged where a number is not finite: a sweep never writes one."""
    from ..protocol.palpation import SimulationDiverged

    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            raise SimulationDiverged(f"the sweep's {name} is not finite at vertex {int(columns['vertex'][bad[0]])} "
                                     f"({len(bad)} of {len(values)} points): nothing is written")
    return columns


# -- files -------------------------------------------------------------------------------------
def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class Parts:
    """The chunks a sweep has written so far, beside its output: OUT.parts/{plan.json, chunk_*.npz}.

    plan.json holds the plan's key and the SHA-256 of every chunk written (rewritten, atomically,
    after each chunk). A chunk counts as done only when its bytes match that checksum: a chunk
    truncated or changed on disk, or one written but not yet in plan.json (an interrupt between
    the two), is removed and pressed again on resume (:attr:`damaged` lists them).
    """

    def __init__(self, out: Path, plan: SweepPlan):
        self.dir = Path(str(out) + ".parts")
        self.plan = plan
        self._key = None
        self._manifest_due = False  # a new folder's plan.json: written with its first chunk
        self.sums: dict[int, str] = {}
        """Chunk index -> SHA-256 of its file, as written."""
        self.damaged: list[int] = []
        """Chunks found on disk by open() that did not match their checksum (removed, to be pressed again)."""
        self.written: dict[int, dict] = {}
        """Chunk index -> the columns this process wrote to its file (gather() takes them as they are)."""
        self.table: dict | None = None
        """The output's columns, every point, filled in as write() writes each chunk (on the writer's
        thread, while the next chunks press): gather() returns it when this process wrote every chunk."""
        self.rows_file = None
        """An NpzRows of the output (export/npz_rows.py) that write() also writes each chunk's rows to,
        or None."""
        self._lock = threading.Lock()  # chunks finish on several threads (several GPUs)

    @property
    def key(self) -> str:
        """The plan's key (SweepPlan.key: it hashes every point, so it waits for their sampling)."""
        if self._key is None:
            self._key = self.plan.key()
        return self._key

    @property
    def manifest(self) -> Path:
        return self.dir / "plan.json"

    def chunk_path(self, i: int) -> Path:
        return self.dir / f"chunk_{i:06d}.npz"

    def open(self) -> list[int]:
        """Create or reuse the parts folder; returns the chunk indices already done (checksums verified).

        A new folder's plan.json is written with its first chunk (on the writer's thread: the key waits
        for the points), so a folder with neither plan.json nor a chunk is one a run left before its
        first chunk: taken as new."""
        if self.dir.exists() and (self.manifest.exists() or any(self.dir.glob("chunk_*.npz"))):
            try:
                data = json.loads(self.manifest.read_text())
                found = data["key"]
                self.sums = {int(i): str(h) for i, h in data.get("chunks", {}).items()}
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                found = None
            if found != self.key:
                raise InputError(
                    f"{self.dir} holds parts of a different sweep (other mesh, points or parameters): "
                    f"delete it, or give another --out"
                )
        else:
            self.dir.mkdir(exist_ok=True)
            self._manifest_due = True
            return []
        done, self.damaged = [], []
        present = {p.name for p in self.dir.iterdir()}  # one listing, not a look-up a chunk
        for i in range(len(self.plan.chunks)):
            path = self.chunk_path(i)
            if path.name not in present:
                continue
            if self.sums.get(i) == file_sha256(path):
                done.append(i)
            else:
                self.damaged.append(i)
                path.unlink()
                self.sums.pop(i, None)
        return done

    def _write_manifest(self) -> None:
        data = {"key": self.key, "points": len(self.plan.vertices), "chunks": {str(i): h for i, h in sorted(self.sums.items())}}
        atomic_write(self.manifest, lambda tmp: Path(tmp).write_text(json.dumps(data)))

    def write(self, i: int, columns: dict) -> None:
        """Write chunk `i` atomically, then its checksum into plan.json."""
        with self._lock:
            if self._manifest_due:  # before any chunk: a folder with a chunk always has its plan.json
                self._write_manifest()
                self._manifest_due = False
        digest = file_sha256(SWEEP_TABLE.write(self.chunk_path(i), columns))
        with self._lock:
            self.sums[i] = digest
            self._write_manifest()
            self.written[i] = columns
            if self.table is None:
                n = len(self.plan.vertices)
                self.table = {c: np.empty(n, dtype=np.asarray(columns[c]).dtype) for c in COLUMNS}
            begin, end = self.plan.chunks[i]
            for c in COLUMNS:
                self.table[c][begin:end] = columns[c]
        if self.rows_file is not None:  # the output's rows too, in place (one writer thread: no lock)
            self.rows_file.rows(begin, columns)

    def gather(self) -> dict:
        """Every chunk's columns, in point order: those this process wrote from memory, the others read
        back; InputError for a chunk found damaged."""
        if len(self.written) == len(self.plan.chunks):
            return self.table
        parts = []
        for i in range(len(self.plan.chunks)):
            if i in self.written:
                parts.append(self.written[i])
                continue
            path = self.chunk_path(i)
            try:
                if self.sums.get(i) != file_sha256(path):
                    raise ValueError("its checksum does not match plan.json")
                parts.append(SWEEP_TABLE.read(path))
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, InputError) as exc:
                raise InputError(f"{path}: damaged ({exc}); run the same command again to press that chunk again") from exc
        return {c: np.concatenate([p[c] for p in parts]) for c in COLUMNS}

    def remove(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


# -- running -----------------------------------------------------------------------------------
PHASES = ("sampling", "set-up", "waiting for the points", "region build", "planning", "launch", "waiting for the device", "read-back", "checks",
          "writing", "waiting for the writer", "gather", "output")
"""The host phases of a sweep's wall time (SweepTimes); the device's press time is counted apart."""


class SweepTimes:
    """Where a sweep's wall time goes: seconds per host phase, summed over the threads that ran it
    (one a device, and the writer's), and the press kernels' time on the device.

    On CUDA the press time is the union of the intervals between events recorded around each
    chunk's press on its stream, read when the chunk's results are read (a synchronisation the sweep
    makes anyway); on the CPU, where launches are synchronous, it is the launches' wall time.
    """

    def __init__(self):
        self.t0 = time.perf_counter()
        self.seconds = dict.fromkeys(PHASES, 0.0)
        self.press_s = 0.0
        """Press kernels [s]: per device, the time it was pressing, summed over devices."""
        self.pressing: list[tuple[float, float]] = []
        """(begin, end) of each chunk's press [s since t0], on the host's clock (on CUDA the device's
        events moved by the host time of a synchronised origin event: within a few microseconds)."""
        self.marks: dict[str, float] = {}
        """When [s since t0] each milestone of the way to the first press was first reached (mark())."""
        self.host_per_chunk: list[float] = []
        """Host time [s] of each chunk on its device's thread (build, plan, launch, read-back, checks)."""
        self._lock = threading.Lock()

    @contextmanager
    def phase(self, name: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(name, time.perf_counter() - t0)

    def add(self, name: str, seconds: float) -> None:
        with self._lock:
            self.seconds[name] += seconds

    def mark(self, name: str) -> None:
        """Note the first time `name` is reached (the way to the first press: what it waits for)."""
        with self._lock:
            self.marks.setdefault(name, time.perf_counter() - self.t0)

    def add_press(self, intervals) -> None:
        """One device's presses, (begin, end) [s] on the host's clock (time.perf_counter)."""
        intervals = [(b - self.t0, e - self.t0) for b, e in intervals]
        with self._lock:
            self.press_s += union_length(intervals)
            self.pressing += intervals

    def timeline(self, wall_s: float) -> dict:
        """When the devices pressed [s]: the first press's start, the idle time between the first and the
        last press (no device pressing), and the time after the last press to `wall_s`."""
        if not self.pressing:
            return {}
        first, last = min(b for b, _ in self.pressing), max(e for _, e in self.pressing)
        return {"before_first_press_s": first, "idle_between_presses_s": last - first - union_length(self.pressing),
                "after_last_press_s": wall_s - last}

    def table(self, wall_s: float) -> str:
        """The breakdown as lines of text: each phase, the press kernels and the rest of `wall_s` [s]."""
        rows = [(name, s) for name, s in self.seconds.items() if s > 0]
        rows.append(("press kernels (device)", self.press_s))
        lines = [f"{name:<26}{s:10.3f} s{100 * s / wall_s:7.1f} %" for name, s in rows]
        lines.append(f"{'wall':<26}{wall_s:10.3f} s  (host phases of several threads may overlap the press)")
        for name, s in self.timeline(wall_s).items():
            lines.append(f"{name[:-2].replace('_', ' '):<26}{s:10.3f} s{100 * s / wall_s:7.1f} %")
        if self.marks:
            lines.append("on the way to the first press: " + ", ".join(f"{name} {s:.3f} s" for name, s in sorted(self.marks.items(), key=lambda m: m[1])))
        if self.host_per_chunk:
            h = np.array(self.host_per_chunk)
            lines.append(f"host time per chunk: median {np.median(h) * 1e3:.1f} ms, max {h.max() * 1e3:.1f} ms ({len(h)} chunks)")
        return "\n".join(lines)

    def as_dict(self, wall_s: float) -> dict:
        """The breakdown in seconds, JSON keys with their unit."""
        out = {f"{name.replace(' ', '_').replace('-', '_')}_s": s for name, s in self.seconds.items()}
        return {**out, "press_kernels_s": self.press_s, "wall_s": wall_s, **self.timeline(wall_s)}


class RingBatches:
    """A plan's BatchPalpations on one device, one per ring count (made when first asked for).

    critical_dt_bound: the whole mesh's critical step (BatchPalpation.critical_dt_bound), or None, or a
    Future of it (concurrent.futures), waited for after the region tables are built.
    Where the plan presses a vertex more than once with a ring count, that count's batch gathers each
    chunk's regions from a table of its distinct contacts built once (BatchPalpation.cache_regions;
    the same bits): `tables` (ring count -> RegionTable), shared by the RingBatches of one model."""

    def __init__(self, plan: SweepPlan, model, critical_dt_bound=None, tables: dict | None = None):
        self.plan, self.model, self.device = plan, model, model.device
        self.critical_dt_bound = critical_dt_bound
        self.tables = {} if tables is None else tables
        self._batches = {}

    def get(self, rings: int):
        from .batch_palpation import BatchPalpation

        if rings not in self._batches:
            p = self.plan
            batch = BatchPalpation(model=self.model, rings=int(rings), dt=p.dt, integrator=p.integrator,
                                   probe_radius=p.probe_radius)
            if rings in self.tables:
                batch.region_table = self.tables[rings]
            elif (contacts := p.contacts(rings)) is not None:  # contacts pressed again: each region built once
                self.tables[rings] = batch.cache_regions(contacts, p.depth)
            if isinstance(self.critical_dt_bound, Future):
                self.critical_dt_bound = self.critical_dt_bound.result()
            batch.critical_dt_bound = self.critical_dt_bound
            self._batches[rings] = batch
        return self._batches[rings]


def press_chunk(batches: RingBatches, plan: SweepPlan, begin: int, end: int, on_launch=None):
    """Start the presses of points begin..end (a batch per ring count among them); returns a finisher."""
    plan.wait(end)
    rings = plan.point_rings[begin:end]
    per_launch = 200 if batches.device.is_cpu else None  # on the CPU, launches of 200 steps move the progress bar
    started = []
    for k in np.unique(rings):
        idx = np.flatnonzero(rings == k)
        batch = batches.get(int(k))
        batch.touch(plan.vertices[begin:end][idx], plan.depth)
        batch.start_press(plan.depth, plan.ramp, plan.hold, plan.settle, steps_per_launch=per_launch, on_launch=frames(on_launch, batch, len(idx)))
        started.append((idx, batch))
    return lambda: checked_columns(plan.columns(begin, end, [(idx, batch.finish_press()) for idx, batch in started]))


def frames(on_launch, batch, n: int):
    """The progress counts frames: a launch of `steps` substeps of `n` presses advances it by n x steps / substeps."""
    return None if on_launch is None else (lambda steps: on_launch(steps * n // batch.substeps))


class Lane:
    """One chunk in flight on a device: its batches (one per ring count), its CUDA stream and its
    read-back buffers in pinned host memory.

    A device's thread keeps two lanes: it builds, plans and launches chunk i + 1 on one stream while
    chunk i presses on the other, then reads chunk i back on its own stream (never the null stream,
    which would wait for both). On the CPU, where launches are synchronous, the same steps in order.
    """

    def __init__(self, batches: RingBatches, times: SweepTimes):
        import warp as wp

        self.batches, self.times, self.device = batches, times, batches.device
        self.stream = wp.Stream(self.device) if self.device.is_cuda else None
        with times.phase("region build"):  # made now: their set-up (and region tables) read on the null stream
            for k in batches.plan.ring_counts:
                batches.get(k)
        times.mark("region tables")
        self.started = []
        """(indices in the chunk, batch, pinned (peak, hold, q0), events) of the chunk in flight."""
        self._pinned = {}

    @contextmanager
    def scope(self):
        """This lane's stream as its device's current one (wp.ScopedStream would also set the process's
        default device, which the threads of several GPUs would race for)."""
        import warp as wp

        if self.stream is None:
            yield
            return
        saved = wp.get_stream(self.device)
        wp.set_stream(self.stream, self.device, sync=True)  # after what the device's stream holds (the model)
        try:
            yield
        finally:
            wp.set_stream(saved, self.device)

    def start(self, plan: SweepPlan, i: int, on_launch=None, origin=None) -> None:
        """Build, plan and launch chunk `i`, and queue its read-back (asynchronous on CUDA)."""
        begin, end = self.chunk = plan.chunks[i]
        with self.times.phase("waiting for the points"):
            plan.wait(end)
        self.times.mark("first chunk's points")
        rings = plan.point_rings[begin:end]
        per_launch = 200 if self.device.is_cpu else None  # on the CPU, launches of 200 steps move the progress bar
        t0, self.started = time.perf_counter(), []
        with self.scope():
            for k in np.unique(rings):
                idx = np.flatnonzero(rings == k)
                batch = self.batches.get(int(k))
                with self.times.phase("region build"):
                    batch.build(plan.vertices[begin:end][idx], plan.depth)
                self.times.mark("first chunk built")
                with self.times.phase("planning"):
                    batch.plan()
                self.times.mark("first chunk planned")
                with self.times.phase("launch"):
                    events = self._record()
                    batch.start_press(plan.depth, plan.ramp, plan.hold, plan.settle, steps_per_launch=per_launch,
                                      on_launch=frames(on_launch, batch, len(idx)))
                    events += self._record()
                    self.times.mark("first press launched")
                    self.started.append((idx, batch, self._read_back(batch, int(k)), events))
        pressed = 0.0
        if self.stream is None:  # the CPU, synchronous: the launch was the press
            pressed = sum(e[1] - e[0] for *_, e in self.started)
        self.host_s = time.perf_counter() - t0 - pressed

    def clock_origin(self):
        """(an event on this stream, the host's time.perf_counter when it ran): the zero of the press
        intervals on the device's clock, and where it falls on the host's (None on the CPU)."""
        import warp as wp

        if self.stream is None:
            return None
        event = self._record()[0]
        wp.synchronize_event(event)
        return event, time.perf_counter()

    def _record(self):
        import warp as wp

        if self.stream is None:
            return [time.perf_counter()]
        event = wp.Event(self.device, enable_timing=True)
        self.stream.record_event(event)
        return [event]

    def _read_back(self, batch, rings: int):
        # the results copied into pinned host buffers on this stream, after the press: no wait here
        import warp as wp

        from ..kernels.batch_press import contact_positions

        if self.stream is None:
            return None
        n = batch.batch_size
        buffers = self._pinned.get(rings)
        if buffers is None or len(buffers[0]) < n:
            buffers = self._pinned[rings] = [wp.empty(n, dtype=wp.vec3, device="cpu", pinned=True) for _ in range(3)]
        out = [b[:n] for b in buffers]
        for dst, src in zip(out, (batch.peak_reaction, batch.hold_reaction, contact_positions(batch))):
            wp.copy(dst, src, stream=self.stream)
        return out

    def finish(self, plan: SweepPlan, origin=None) -> dict:
        """Wait for the chunk started last and return its checked columns."""
        import warp as wp

        t0 = time.perf_counter()
        if self.stream is not None:
            with self.times.phase("waiting for the device"):
                wp.synchronize_stream(self.stream)
            at = lambda event: origin[1] + 1e-3 * wp.get_event_elapsed_time(origin[0], event)
            self.busy = [(at(e[0]), at(e[1])) for *_, e in self.started]
        else:
            self.busy = [(e[0], e[1]) for *_, e in self.started]
        results = []
        with self.times.phase("read-back"):
            for idx, batch, pinned, _ in self.started:
                result = batch.finish_press() if pinned is None else batch.result_from(*(b.numpy() for b in pinned))
                results.append((idx, result))
            columns = plan.columns(*self.chunk, results)
        with self.times.phase("checks"):
            columns = checked_columns(columns)
        self.host_s += time.perf_counter() - t0
        self.times.host_per_chunk.append(self.host_s)
        return columns


class Writer:
    """Writes the chunks' part files on a thread of its own, in the order given (at most `depth` waiting).

    An error there (a full disk; an interrupt in tests) is raised again in the sweep's thread by
    put() or close(); after it nothing more is written."""

    def __init__(self, parts: Parts, times: SweepTimes, depth: int = 4):
        import queue

        self.parts, self.times, self.error = parts, times, None
        self.queue = queue.Queue(depth)
        self.thread = threading.Thread(target=self._run, name="sweep-writer", daemon=True)
        self.thread.start()

    def _run(self):
        while (item := self.queue.get()) is not None:
            if self.error is None:
                try:
                    with self.times.phase("writing"):
                        self.parts.write(*item)
                except BaseException as exc:  # handed to the sweep's thread
                    self.error = exc

    def put(self, i: int, columns: dict) -> None:
        self.check()
        with self.times.phase("waiting for the writer"):
            self.queue.put((i, columns))

    def check(self) -> None:
        if self.error is not None:
            raise self.error

    def close(self, wait: bool = True) -> None:
        """Write what is queued (wait) or drop it, end the thread, raise its error if any."""
        if not wait:
            while not self.queue.empty():
                self.queue.get_nowait()
        with self.times.phase("waiting for the writer"):
            self.queue.put(None)
            self.thread.join()
        if wait:
            self.check()


def run_device(plan: SweepPlan, batches: list, take, put, times: SweepTimes, on_launch=None) -> None:
    """Press the chunks that `take()` hands out (None: no more) on one device, a lane (Lane) for each
    of `batches`: with two, chunk i + 1 is launched before chunk i is read; put(i, columns) each when done."""
    lanes = [Lane(b, times) for b in batches]
    origin = lanes[0].clock_origin()
    busy, flying, n = [], None, 0

    def finish(chunk):
        j, lane = chunk
        put(j, lane.finish(plan, origin))
        busy.extend(lane.busy)

    while True:
        i = take()
        lane = lanes[n % len(lanes)]
        if flying is not None and flying[1] is lane:  # a single lane: its chunk is read first
            finish(flying)
            flying = None
        if i is not None:
            lane.start(plan, i, on_launch, origin)
            n += 1
        if flying is not None:
            finish(flying)
        if i is None:
            break
        flying = (i, lane)
    times.add_press(busy)


def union_length(intervals) -> float:
    """Total length of the union of (begin, end) intervals."""
    total, reach = 0.0, -math.inf
    for b, e in sorted(intervals):
        if e > reach:
            total += e - max(b, reach)
            reach = e
    return total


def run_local(plan: SweepPlan, parts: Parts, todo: list[int], devices: list[str], progress=None, *, pipeline: bool = True,
              times: SweepTimes | None = None, models=None) -> None:
    """Press the chunks `todo` over `devices` (each chunk written when it is done).

    pipeline: a host thread per device (a device named twice gets two), each with its own model and
    two lanes (Lane): chunk i + 1 is built and launched while chunk i presses, results read back
    into pinned memory, part files written on a thread of their own; chunks are handed out in
    order to whichever device is free. Without: one thread, chunks interleaved over the devices,
    each built, pressed, read and written in turn. Both give the same bits for the same plan.
    times: where the wall time goes (SweepTimes), filled in. models: the plan's model on each device,
    or a Future of them (models_behind), or None: made here.
    """
    times = times if times is not None else SweepTimes()
    advance = None if progress is None else progress.advance
    times.mark("run")
    with times.phase("set-up"):
        models = models.result() if isinstance(models, Future) else models or [plan.model(d) for d in devices]
    times.mark("models")
    todo = list(todo)
    if not pipeline:
        batches = [RingBatches(plan, m) for m in models]
        while todo:
            running = [(todo.pop(0), b) for b in batches if todo]
            with times.phase("launch"):
                running = [(i, press_chunk(b, plan, *plan.chunks[i], on_launch=advance)) for i, b in running]
            for i, finish in running:
                with times.phase("read-back"):
                    columns = finish()
                with times.phase("writing"):
                    parts.write(i, columns)
        return
    bound = Future()  # the critical step, on a thread of its own while the region tables are built

    def critical_dt():
        try:
            with times.phase("set-up"):
                bound.set_result(sweep_critical_dt(plan))
        except BaseException as exc:
            bound.set_exception(exc)

    threading.Thread(target=critical_dt, name="sweep-critical-dt", daemon=True).start()
    writer, lock, queue = Writer(parts, times), threading.Lock(), iter(todo)
    stop = threading.Event()

    def take():
        with lock:
            return None if stop.is_set() else next(queue, None)

    def work(lanes):
        tables = {id(m): {} for m in lanes}  # a model's region tables, shared by its lanes
        run_device(plan, [RingBatches(plan, m, bound, tables[id(m)]) for m in lanes], take, writer.put, times, advance)

    cuda = [m for m in models if m.device.is_cuda]
    if len(cuda) == len(models) and len({m.device.alias for m in cuda}) == len(cuda):
        groups = [[m, m] for m in models]  # a thread a GPU, two lanes on its model
    elif all(m.device.is_cpu for m in models):  # synchronous launches: one thread, a lane a model
        groups = [models]
    else:  # a GPU named twice: one thread, two lanes or more over the models
        groups = [[models[k % len(models)] for k in range(max(2, len(models)))]]
    _run_threads(work, groups, stop, writer)


def _run_threads(work, groups, stop, writer):
    from concurrent.futures import ThreadPoolExecutor

    try:
        if len(groups) == 1:
            work(groups[0])
        else:
            with ThreadPoolExecutor(len(groups)) as pool:
                futures = [pool.submit(work, g) for g in groups]
                try:
                    for f in futures:
                        f.result()
                except BaseException:  # an interrupt or an error: the other threads end after their current chunk
                    stop.set()
                    raise
    except BaseException:
        stop.set()
        writer.close(wait=False)
        raise
    writer.close()


def sweep_critical_dt(plan: SweepPlan) -> float | None:
    """The whole mesh's critical step [s] (a bound of every region's, BatchPalpation.critical_dt_bound)
    for an explicit plan, computed once a sweep; None for an implicit one."""
    return plan.critical_dt() if plan.integrator == "explicit" else None


class SweepDevice:
    """One device's share of a sweep in a Ray actor (one GPU, where Ray sets CUDA_VISIBLE_DEVICES, or
    one CPU): the plan's model made once there, a chunk a call, pressed through a Lane as the local
    pipeline presses it (the same bits)."""

    def __init__(self, plan: SweepPlan, gpu: bool, critical_dt_bound=None):
        from ..warp_init import init_warp

        init_warp()
        self.plan, self.times = plan, SweepTimes()
        self.lane = Lane(RingBatches(plan, plan.model("cuda:0" if gpu else "cpu"), critical_dt_bound), self.times)
        self.origin = self.lane.clock_origin()

    def press(self, i: int) -> dict:
        """The checked columns of chunk `i`."""
        self.lane.start(self.plan, i, None, self.origin)
        return self.lane.finish(self.plan, self.origin)


def run_ray(plan: SweepPlan, parts: Parts, todo: list[int], gpu: bool, address=None, progress=None) -> None:
    """Press the chunks `todo` on Ray actors of one GPU each (or one CPU), one per GPU (CPU) of the
    cluster, two chunks queued on each so the next starts as one returns; written as they come back."""
    try:
        import ray
    except ImportError as exc:
        raise InputError("--ray needs Ray: pip install 'almsdm_warp[ray]'") from exc
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    device = ray.remote(num_gpus=1, num_cpus=1)(SweepDevice) if gpu else ray.remote(num_cpus=1)(SweepDevice)
    plan_ref = ray.put(plan)
    bound = sweep_critical_dt(plan)
    count = max(1, min(len(todo), int(ray.cluster_resources().get("GPU" if gpu else "CPU", 1))))
    actors = [device.remote(plan_ref, gpu, bound) for _ in range(count)]
    queue, pending = list(todo), {}

    def submit(a: int) -> None:
        if queue:
            i = queue.pop(0)
            pending[actors[a].press.remote(i)] = (i, a)

    for a in range(count):
        submit(a)
        submit(a)
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        i, a = pending.pop(done[0])
        parts.write(i, ray.get(done[0]))
        submit(a)
        if progress is not None:
            b, e = plan.chunks[i]
            progress.advance((e - b) * press_steps(plan))


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


def start_sampling(mesh, n: int, fixed_below=None):
    """pressable_points(mesh, n, fixed_below) as (points, vertices, None); or, on its area-uniform
    path and where no support can drop points (so their number is n before they are drawn), a
    Sampling that fills them in behind the caller: (its points, its vertices, it). The same points."""
    if n > FPS_MAX and n > len(mesh.surface_vertices) and fixed_below is None:
        sampling = Sampling(mesh, n)
        return sampling.points, sampling.vertices, sampling
    return (*pressable_points(mesh, n, fixed_below), None)


def models_behind(plan: SweepPlan, devices: list[str]) -> Future:
    """The plan's model on each of `devices` (a list), made on a thread of its own while the caller
    goes on, then the first chunk's kernel modules loaded there (preload_modules)."""
    made = Future()

    def make():
        try:
            models = [plan.model(d) for d in devices]
            made.set_result(models)
        except BaseException as exc:
            made.set_exception(exc)
            return
        preload_modules(devices)

    threading.Thread(target=make, name="sweep-models", daemon=True).start()
    return made


def preload_modules(devices: list[str]) -> None:
    """Load the modules of the kernels a sweep's first chunk launches (region builds and gathers, rest
    states, the contacts' read-back) on each CUDA device of `devices`, as their first launch would
    (wp.load_module; cached code is only loaded): done on the models' thread, while the points are
    sampled, rather than on the way to the first press. Errors are left to that launch."""
    import warp as wp

    from ..kernels import batch_press, batch_rings

    for d in devices:
        if wp.get_device(d).is_cuda:
            for module in (batch_rings, batch_press):
                try:
                    wp.load_module(module, device=d)
                except Exception:  # the launch that needs it loads it again and says what is wrong
                    pass


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


def check_sphere_travel(radius: float, depth: float, dt: float, ramp: float) -> None:
    """InputError where a sphere of `radius` [m] would move its radius or more in one frame of the
    press's ramp (it would pass through vertices), before any work; BatchPalpation checks it again."""
    from ..protocol.schedule import PressSchedule

    travel = depth / PressSchedule.from_times(dt, ramp, 0.0, 0.0).ramp_n
    if radius > 0 and travel >= radius:
        raise InputError(f"the sphere would move {travel * 1e3:.3g} mm a step, not less than its "
                         f"radius {radius * 1e3:g} mm: it would pass through vertices; ramp longer or use a smaller --dt-ms")
