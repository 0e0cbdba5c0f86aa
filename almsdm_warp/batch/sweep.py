"""Palpation sweeps: a press at N points spread over an organ's surface, a force map as a table.

The points are spread evenly (batch/sampling.py). The work is cut into chunks of points
(batch/sweep_plan.py's SweepPlan); each chunk is pressed as one batch (BatchPalpation) on one
device and written at once, as its own file, atomically, beside the output (``OUT.parts/``,
batch/sweep_store.py), so an interrupted sweep resumes from what it wrote. Here the chunks are
run: in order, to whichever device given is free (a host thread a GPU), where the next chunk is
built and launched while one presses and the results are read back and written on the side
(run_local; the device's side, each distinct contact's region built once a sweep and each chunk's
regions gathered from that table on the device: batch/sweep_lanes.py); or to Ray actors of one
GPU each (``ray`` extra, run_ray). Where the wall time goes: batch/sweep_times.py. Many points
are sampled behind the first chunks (Sampling), and an .npz output takes each chunk's rows as it
is written (export/npz_rows.py). When all are done they are gathered, in point order, into the
output (export/tables.py: .csv, .npz or .parquet) and the parts removed.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future

from ..errors import InputError
from .sweep_lanes import Lane, RingBatches, press_chunk, run_device
from .sweep_plan import SweepPlan, press_steps, sweep_critical_dt
from .sweep_store import Parts
from .sweep_times import SweepTimes


class Writer:
    """Writes the chunks' part files on `threads` threads of its own (a sweep's: one a device), in the order
    given where one (at most `depth` a thread waiting).

    An error there (a full disk; an interrupt in tests) is raised again in the sweep's thread by
    put() or close(); after it nothing more is written."""

    def __init__(self, parts: Parts, times: SweepTimes, depth: int = 4, threads: int = 1):
        import queue

        self.parts, self.times, self.error = parts, times, None
        self.queue = queue.Queue(depth * threads)
        self.threads = [threading.Thread(target=self._run, name=f"sweep-writer-{k}", daemon=True) for k in range(threads)]
        for thread in self.threads:
            thread.start()

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
            for thread in self.threads:
                self.queue.put(None)
            for thread in self.threads:
                thread.join()
        if wait:
            self.check()


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
    lock, queue, stop = threading.Lock(), iter(todo), threading.Event()

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
    writer = Writer(parts, times, threads=len(groups))  # a writing thread a device's
    run_threads(work, groups, stop, writer)


def run_threads(work, groups, stop, writer):
    """work(group) for each of `groups`, on a thread each where several; then writer.close() (Writer), which
    raises its error; on an error or an interrupt, `stop` set (the other threads end after their current
    piece of work), the writer closed without writing what is queued, and the error raised again."""
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

    from ..kernels.explicit import batch as batch_press
    from ..kernels.region import batch_rings

    for d in devices:
        if wp.get_device(d).is_cuda:
            for module in (batch_rings, batch_press):
                try:
                    wp.load_module(module, device=d)
                except Exception:  # the launch that needs it loads it again and says what is wrong
                    pass


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


def require_ray():
    """The ray module, or InputError saying how to install it (checked before a sweep writes anything)."""
    try:
        import ray
    except ImportError as exc:
        raise InputError("--ray needs Ray: pip install 'almsdm_warp[ray]'") from exc
    return ray


def run_ray(plan: SweepPlan, parts: Parts, todo: list[int], gpu: bool, address=None, progress=None) -> None:
    """Press the chunks `todo` on Ray actors of one GPU each (or one CPU), one per GPU (CPU) of the
    cluster, two chunks queued on each so the next starts as one returns; written as they come back."""
    ray = require_ray()
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
