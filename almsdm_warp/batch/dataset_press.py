"""A dataset's items pressed together: the items of a scene share its launches, on every device given.

The items of one scene (batch/dataset.py) press the same points of the same mesh with the same press;
only their lesion's constants differ. They are pressed as one batch (batch/item_batch.py): a
StackedModel of their models, the scene's regions built once a device (a RegionTable of its distinct
contacts) and gathered for each chunk, each palpation offset to its item's constants. The work is cut
into units, (scene, chunk, items): a chunk's points for some of the items that still need that chunk,
pressed in one launch a substep count (each (item, chunk) takes the substeps its own sweep would:
batch_palpation.union_critical_dt over the chunk's free vertices with the item's model; the items of
one count share a launch). Units go to a thread a device, in order, to whichever is free, two in
flight on a GPU (ItemLane: one built and launched while the other presses, as a sweep's chunks);
the items' models and critical steps are made ahead on a thread of their own. Each unit's rows are
written as each item's part (batch/sweep_store.py's Parts, as a sweep writes its chunks), and an
item whose last chunk is written becomes its table and its line in dataset.json at once: a run
killed at any point resumes item by item, chunk by chunk, as before. The numbers are those of
pressing each item as a sweep of its own (tests/test_dataset.py).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from ..solvers import solver_class
from ..solvers.stepper import REPRESSES, force_bound, plan_substeps
from .batch_palpation import host_copy, union_critical_dt
from .item_batch import ItemBatch, StackedModel, result_rows, stack_limit
from .sweep import run_threads
from .sweep_lanes import Lane, checked_columns, frames, run_lanes
from .sweep_plan import GPU_CHUNK
from .sweep_times import SweepTimes


@dataclass
class ItemWork:
    """One item still to press: its parts on disk and the chunks they lack."""

    item: object
    """batch.dataset.DatasetItem."""
    parts: object
    """Its Parts (opened)."""
    todo: set = field(default_factory=set)
    """Chunk indices not written yet."""


class SceneStack:
    """Items of one scene pressed together (at most stack_limit of them): their models, made once on
    the host and stacked on each device as it first needs them."""

    def __init__(self, works: list[ItemWork]):
        self.works = works
        self.plan = works[0].item.plan
        """The first item's plan: the mesh, points, chunks, press, rings, probe and support of them all."""
        self._lock = threading.Lock()
        self._models = None
        self._bounds = self._force_bounds = None

    def models(self) -> list:
        """Each item's Model on the CPU (its constants, derived once for every device; on threads)."""
        with self._lock:
            if self._models is None:
                self._models = host_map(lambda w: w.item.plan.model("cpu"), self.works)
            return self._models

    def force_bounds(self) -> list:
        """Each item's force bound [N] (solvers.stepper.force_bound of its model: a press past it diverged)."""
        models = self.models()
        with self._lock:
            if self._force_bounds is None:
                self._force_bounds = host_map(force_bound, models)
            return self._force_bounds

    def bounds(self) -> list:
        """Each item's critical step bound [s] (sweep_critical_dt: its whole mesh's), or None each for an
        implicit press, and for a plan of one chunk (a GPU's default): there the bound would save no
        estimate of a chunk's free vertices (union_critical_dt), only add its own where one substep
        is not stable under it; the chunk's, which is no shorter, then decides the same substeps."""
        models = self.models()
        with self._lock:
            if self._bounds is None:
                explicit = solver_class(self.plan.integrator).conditionally_stable  # as sweep_critical_dt
                many = len(self.plan.chunks) > 1
                self._bounds = host_map(lambda m: m.critical_dt(), models) if explicit and many else [None] * len(models)
            return self._bounds


def host_map(f, values) -> list:
    """[f(v) for v in values], on threads (host work of NumPy and SciPy: the critical steps of many items)."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    values = list(values)
    workers = min(len(values), os.cpu_count() or 1, 8)
    if workers <= 1:
        return [f(v) for v in values]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(f, values))


class DeviceStack:
    """One stack's share of one device: the StackedModel, a region table a ring count, each lane's batches."""

    def __init__(self, stack: SceneStack, device):
        from ..warp_init import devices_started

        if str(device) != "cpu":
            devices_started()  # a context the command line started (warp_init.start_devices)
        self.stack = stack
        self.model = StackedModel(stack.models(), device, stack.force_bounds())
        self.tables: dict = {}
        """Ring count -> (RegionTable of the plan's distinct contacts, its region_vertex on the host)."""
        self.batches: dict = {}
        """(lane, ring count, integrator, substeps) -> ItemBatch (a lane's own: its arrays are in flight)."""
        self.critical: list[dict] = [{} for _ in stack.works]
        """Per item: the critical steps of the free-vertex sets asked so far (union_critical_dt's cache)."""

    def _new_batch(self, rings: int, integrator: str, substeps) -> ItemBatch:
        p = self.stack.plan
        return ItemBatch(self.model, rings=rings, dt=p.dt, integrator=integrator, probe_radius=p.probe_radius, substeps=substeps,
                         records=p.records)

    def table(self, rings: int):
        """(the RegionTable of the plan's distinct contacts pressed with `rings` rings, its region_vertex on the host)."""
        if rings not in self.tables:
            p = self.stack.plan
            table = self._new_batch(rings, p.integrator, "auto").cache_regions(np.unique(p.vertices[p.point_rings == rings]), p.depth)
            self.tables[rings] = (table, host_copy(table.regions.region_vertex))
        return self.tables[rings]

    def batch(self, lane, rings: int, integrator: str, substeps: int) -> ItemBatch:
        """`lane`'s batch of `rings` rings pressed with `integrator` in `substeps` substeps (made once)."""
        key = (id(lane), rings, integrator, substeps)
        if key not in self.batches:
            # the implicit fall-back takes one step a frame (its plan's own)
            batch = self._new_batch(rings, integrator, substeps if integrator == self.stack.plan.integrator else "auto")
            batch.region_table, batch.represses = self.table(rings)[0], REPRESSES  # the substeps are a plan's: "auto"
            self.batches[key] = batch
        return self.batches[key]

    def free_vertices(self, rings: int, vertices: np.ndarray) -> np.ndarray:
        """The free vertices of the regions of `vertices` (ring count `rings`), mesh ids, each once a region."""
        table, rv = self.tables[rings]
        rows = table.rows(vertices, table.patch_depth)
        return rv[rows][np.arange(rv.shape[1])[None, :] < table.counts[1][rows][:, None]]

    def substep_groups(self, rings: int, vertices: np.ndarray, members, times: SweepTimes) -> dict:
        """{(integrator, substeps): {item: its critical step [s]}} for the presses of `vertices` by `members`:
        each item's plan as its own batch of these presses makes it (plan_substeps, union_critical_dt)."""
        p, groups = self.stack.plan, {}
        with times.phase("region build"):
            self.table(rings)
        with times.phase("critical steps"):
            bounds = self.stack.bounds()

            def item_plan(k):
                free = lambda: self.free_vertices(rings, vertices)
                critical = lambda: union_critical_dt(self.stack.models()[k], free, p.dt, bounds[k], None, self.critical[k])
                return plan_substeps(p.integrator, p.dt, critical, None, "the batch")

            plans = host_map(item_plan, members)
        for k, plan in zip(members, plans):
            groups.setdefault((plan.integrator, plan.substeps), {})[k] = plan.critical_dt
        return groups


class DeviceUnits:
    """The units of a dataset's stacks as one device's threads take them: unit i's DeviceStack (made on
    this device when first needed), chunk and items."""

    def __init__(self, stacks: list[SceneStack], units: list, device, times: SweepTimes):
        self.stacks, self.units, self.device, self.times = stacks, units, device, times
        self.mine: dict = {}

    def unit(self, i: int) -> tuple:
        s, chunk, members = self.units[i]
        if s not in self.mine:
            with self.times.phase("set-up"):
                self.mine[s] = DeviceStack(self.stacks[s], self.device)
        return self.mine[s], chunk, members


class ItemLane(Lane):
    """One unit in flight on a device: Lane's stream, clock and pinned read-back, for a unit's batches (a
    ring count and substep count each) of a DeviceStack; two on a GPU (run_lanes: unit i + 1 built and
    launched while unit i presses), one on the CPU."""

    def __init__(self, device, times: SweepTimes):  # nothing of a plan's to make ahead
        import warp as wp

        self.device, self.times = wp.get_device(device), times
        self.stream = wp.Stream(self.device) if self.device.is_cuda else None
        self.started, self._pinned, self.unit = [], {}, None

    def start(self, units: DeviceUnits, i: int, on_launch=None, origin=None) -> None:
        """Plan, build and launch unit `i` (each of its items' presses of its chunk: a batch a ring count
        and substep count, all planned before the first is launched: Lane.launch), and queue the read-back."""
        stack, chunk, members = self.unit = units.unit(i)
        p = stack.stack.plan
        begin, end = p.chunks[chunk]
        rings = p.point_rings[begin:end]
        per_launch = 200 if self.device.is_cpu else None  # on the CPU, launches of 200 steps move the progress bar
        planned = []
        with self.scope():
            for r in np.unique(rings):
                idx = np.flatnonzero(rings == r)
                vertices = p.vertices[begin:end][idx]
                for (integrator, substeps), critical in stack.substep_groups(int(r), vertices, members, self.times).items():
                    batch = stack.batch(self, int(r), integrator, substeps)
                    batch.item_critical_dt, items = critical, list(critical)
                    with self.times.phase("planning"):
                        batch.build(np.tile(vertices, len(items)), p.depth, np.repeat(items, len(vertices))).plan()
                    planned.append(((idx, items), batch, (int(r), integrator, substeps), len(items) * len(vertices)))
            self.launch(planned, (p.depth, p.ramp, p.hold, p.settle), per_launch, on_launch)

    def finish(self, units: DeviceUnits, origin=None) -> dict:
        """Wait for the unit started last: {item (stack index): its checked columns}."""
        stack, chunk, members = self.unit
        results = {k: [] for k in members}
        for (idx, items), result in self.results(origin):
            for j, k in enumerate(items):
                results[k].append((idx, result_rows(result, j * len(idx), (j + 1) * len(idx))))
        begin, end = stack.stack.plan.chunks[chunk]
        with self.times.phase("checks"):
            return {k: checked_columns(stack.stack.works[k].item.plan.columns(begin, end, results[k])) for k in members}


def stacks_of(works: list[ItemWork]) -> list[SceneStack]:
    """The works grouped by scene (in order), each scene's cut into stacks of at most stack_limit items."""
    by_scene: dict = {}
    for w in works:
        by_scene.setdefault(w.item.scene, []).append(w)
    stacks = []
    for group in by_scene.values():
        size = stack_limit(group[0].item.plan.mesh)
        stacks += [SceneStack(group[i:i + size]) for i in range(0, len(group), size)]
    return stacks


LAUNCH_PRESSES = GPU_CHUNK[1]
"""Presses of one unit at most (a GPU sweep's largest chunk, sweep_plan.GPU_CHUNK): its batch's arrays
stay the size of a sweep's chunk's; a chunk of many items is cut into several units."""


def units_of(stacks: list[SceneStack], devices: int) -> list[tuple]:
    """The work as (stack, chunk, items) units, in order: each chunk's items that lack it, in one unit of
    at most LAUNCH_PRESSES presses, or, where a stack has fewer than two chunks a device, cut into that
    many parts so every device gets work. On several devices the largest units go first (each to
    whichever device is free), so that the last ones, which one device may press while another waits,
    are the smallest."""
    units = []
    for s, stack in enumerate(stacks):
        chunks = sorted(set().union(*(w.todo for w in stack.works)))
        cut = 1 if devices == 1 else -(-2 * devices // max(len(chunks), 1))
        for c in chunks:
            members = [k for k, w in enumerate(stack.works) if c in w.todo]
            begin, end = stack.plan.chunks[c]
            parts = max(min(cut, len(members)), -(-len(members) // max(1, LAUNCH_PRESSES // (end - begin))))
            units += [(s, c, [int(k) for k in part]) for part in np.array_split(np.asarray(members), parts)]
    if devices > 1:
        size = lambda u: len(u[2]) * np.subtract(*stacks[u[0]].plan.chunks[u[1]][::-1])
        units.sort(key=size, reverse=True)  # stable: in order within a size
    return units


def press_stacks(stacks: list[SceneStack], devices: list[str], writer, progress=None, times: SweepTimes | None = None) -> None:
    """Press every unit of `stacks` over `devices` (a thread a device where several, each with its lanes:
    run_lanes), each item's rows of a unit handed to `writer` (sweep.Writer: put((work, chunk), columns)),
    closed at the end (sweep.run_threads). The stacks' models and critical steps are made on a thread of
    their own meanwhile, in order (prepare). times: where the wall time goes (SweepTimes), filled in."""
    import warp as wp

    from ..warp_init import devices_started

    times = times if times is not None else SweepTimes()
    # a GPU named twice: one thread (a device's current stream is the process's: one thread sets it); the
    # CPU named twice: two threads (its launches are synchronous)
    devices = [d for i, d in enumerate(devices) if wp.get_device(d).is_cpu or wp.get_device(d) not in map(wp.get_device, devices[:i])]
    units = units_of(stacks, len(devices))
    queue, lock, stop = iter(range(len(units))), threading.Lock(), threading.Event()
    advance = None if progress is None else progress.advance
    threading.Thread(target=prepare, args=(stacks, stop), name="dataset-models", daemon=True).start()

    def take():
        with lock:
            return None if stop.is_set() else next(queue, None)

    def put(i, columns):
        s, chunk, _ = units[i]
        for k, rows in columns.items():
            writer.put((stacks[s].works[k], chunk), rows)

    def work(device):
        cuda = wp.get_device(device).is_cuda
        if cuda:
            devices_started()  # before its streams: a context the command line started (warp_init.start_devices)
        lanes = [ItemLane(device, times) for _ in range(2 if cuda else 1)]
        run_lanes(DeviceUnits(stacks, units, device, times), lanes, take, put, times, advance)

    run_threads(work, devices, stop, writer)


def prepare(stacks: list[SceneStack], stop: threading.Event) -> None:
    """Each stack's models, critical step bounds and force bounds, in order, until `stop` (the devices'
    threads wait for a stack's when they reach it first; an error is left to them: they make it again
    and raise it)."""
    for stack in stacks:
        if stop.is_set():
            return
        try:
            stack.bounds()
            stack.force_bounds()
        except Exception:
            pass
