"""A sweep's chunks pressed on one device: its batches (RingBatches, one per ring count, each distinct
contact's region built once a sweep and each chunk's gathered from that table on the device), the
chunk in flight on a stream (Lane), and the loop that keeps two in flight (run_device)."""

from __future__ import annotations

import time
from concurrent.futures import Future
from contextlib import contextmanager

import numpy as np

from .sweep_plan import SweepPlan
from .sweep_times import SweepTimes


def checked_columns(columns: dict) -> dict:
    """`columns`, or SimulationDiverged where a number is not finite: a sweep never writes one."""
    from ..solvers.stepper import SimulationDiverged

    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values).reshape(len(values), -1).all(axis=1))  # rows (a curve: any sample)
        if len(bad):
            raise SimulationDiverged(f"the sweep's {name} is not finite at vertex {int(columns['vertex'][bad[0]])} "
                                     f"({len(bad)} of {len(values)} points): nothing is written")
    return columns


def near_ring(result, radius: float) -> int:
    """How many of a BatchResult's presses came near their region's fixed ring (protocol/palpation.py NEAR_RING)."""
    from ..protocol.palpation import NEAR_RING

    return 0 if result.ring_gap is None else int(np.count_nonzero(result.ring_gap < NEAR_RING * radius))


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
                                   probe_radius=p.probe_radius, records=p.records)
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
        t0, planned = time.perf_counter(), []
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
                planned.append((idx, batch, int(k), len(idx)))
            self.launch(planned, (plan.depth, plan.ramp, plan.hold, plan.settle), per_launch, on_launch)
        pressed = 0.0
        if self.stream is None:  # the CPU, synchronous: the launch was the press
            pressed = sum(e[1] - e[0] for *_, e in self.started)
        self.host_s = time.perf_counter() - t0 - pressed

    def launch(self, planned: list, press: tuple, per_launch, on_launch) -> None:
        """Launch each planned batch, (what it was started with, batch, its read-back key, its presses), in
        order, pressing `press` (depth, ramp, hold, settle), and queue its read-back (self.started). A
        chunk's batches (one a ring count, or a dataset unit's one a ring and substep count) are all
        planned before the first is launched: a plan reads its regions back on this lane's stream
        (host_copy), which would otherwise wait for the press launched before it, the device idle while
        the next batch is planned."""
        self.started = []
        for what, batch, key, presses in planned:
            with self.times.phase("launch"):
                events = self._record()
                batch.start_press(*press, steps_per_launch=per_launch, on_launch=frames(on_launch, batch, presses))
                events += self._record()
                self.times.add_steps(presses * batch.total_steps)
                self.times.mark("first press launched")
                self.started.append((what, batch, self._read_back(batch, key), events))

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

        from ..kernels.explicit.batch import contact_positions

        if self.stream is None:
            return None
        n = batch.batch_size
        buffers = self._pinned.get(rings)
        if buffers is None or len(buffers[0]) < n:
            buffers = self._pinned[rings] = [wp.empty(n, dtype=wp.vec3, device="cpu", pinned=True) for _ in range(3)]
        out = [b[:n] for b in buffers]
        for dst, src in zip(out, (batch.peak_reaction, batch.hold_reaction, contact_positions(batch))):
            wp.copy(dst, src, stream=self.stream)
        if batch.ring_gap is not None:  # a sphere on tets: each press's distance from its fixed ring
            gaps = self._pinned.get(("gap", rings))
            if gaps is None or len(gaps) < n:
                gaps = self._pinned[("gap", rings)] = wp.empty(n, dtype=wp.float32, device="cpu", pinned=True)
            out.append(gaps[:n])
            wp.copy(out[-1], batch.ring_gap, stream=self.stream)
        return out

    def results(self, origin=None) -> list:
        """Wait for what the lane started last (its press intervals in `busy`), then [(what each batch was
        started with, its BatchResult)], read from the pinned buffers."""
        import warp as wp

        if self.stream is not None:
            with self.times.phase("waiting for the device"):
                wp.synchronize_stream(self.stream)
            at = lambda event: origin[1] + 1e-3 * wp.get_event_elapsed_time(origin[0], event)
            self.busy = [(at(e[0]), at(e[1])) for *_, e in self.started]
        else:
            self.busy = [(e[0], e[1]) for *_, e in self.started]
        with self.times.phase("read-back"):
            out = [(what, self._result(batch, pinned)) for what, batch, pinned, _ in self.started]
        self.times.add_repressed(sum(int(np.count_nonzero(r.substeps > s[1].substeps)) for s, (_, r) in zip(self.started, out)))
        self.times.add_near_ring(sum(near_ring(r, s[1].probe_radius) for s, (_, r) in zip(self.started, out)))
        return out

    def _result(self, batch, pinned):
        if pinned is None:
            return batch.finish_press()
        if batch.records.on:  # the records read on this lane's stream (done), not waiting for the other lane
            with self.scope():
                return batch.result_from(*(b.numpy() for b in pinned))
        return batch.result_from(*(b.numpy() for b in pinned))

    def finish(self, plan: SweepPlan, origin=None) -> dict:
        """Wait for the chunk started last and return its checked columns."""
        t0 = time.perf_counter()
        results = self.results(origin)
        with self.times.phase("read-back"):
            columns = plan.columns(*self.chunk, results)
        with self.times.phase("checks"):
            columns = checked_columns(columns)
        self.host_s += time.perf_counter() - t0
        self.times.host_per_chunk.append(self.host_s)
        return columns


def run_device(plan: SweepPlan, batches: list, take, put, times: SweepTimes, on_launch=None) -> None:
    """Press the chunks that `take()` hands out (None: no more) on one device, a lane (Lane) for each
    of `batches`: with two, chunk i + 1 is launched before chunk i is read; put(i, columns) each when done."""
    run_lanes(plan, [Lane(b, times) for b in batches], take, put, times, on_launch)


def run_lanes(plan, lanes: list, take, put, times: SweepTimes, on_launch=None) -> None:
    """run_device's loop over ready lanes: objects with Lane's clock_origin(), start(plan, i, on_launch,
    origin), finish(plan, origin) (the work's result, handed to put(i, result)) and busy (its press intervals)."""
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
    times.add_press(busy, str(lanes[0].device))
