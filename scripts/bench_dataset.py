"""A dataset's presses a second against a single sweep's, on the same device(s): a table.

    python scripts/bench_dataset.py                                   # scenes/datasets/example.toml, cuda:0 (or cpu)
    python scripts/bench_dataset.py --points 10000 --device cuda:0
    python scripts/bench_dataset.py --points 10000 --devices all      # every GPU of the host
    python scripts/bench_dataset.py --points 16 --device cpu --item-by-item
    python scripts/bench_dataset.py --points 10000 --devices all --runs 1 --no-sweeps   # the dataset alone

Presses the spec's dataset (its [dataset] points replaced by --points) with its items together
(batch/dataset_press.py) into a temporary folder, and with --item-by-item also as before, each item
a sweep of its own; then, for each scene of the spec, one sweep of its baseline (no lesion) with as
many points as the dataset presses on that scene, on the same device(s). Each is run --runs times
(default 2: the first compiles and loads the kernels; the dataset's ways interleaved, so that a
shared machine's load falls on each alike) and the best run's wall time is reported: the dataset's
from the first item pressed to the last table written (its models, critical steps, region tables,
presses and writes; not the planning of its items, timed apart), the sweep's that of
batch.sweep.run_local (its model, region tables, chunks and writes). Presses a second are presses
over that time. "at each scene's single-sweep rate" is the time the dataset's presses would take,
each scene's at that scene's sweep rate; the dataset's share of that rate is the figure issue 25
asks >= 50% of (on one scene, simply the dataset's presses/s over the sweep's).
Where the dataset's time went (SweepTimes: set-up, critical steps, region build, planning, press...)
follows. Prints only; writes nothing outside the temporary folder.
"""

import argparse
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(HERE))


def devices_of(args) -> list[str]:
    import warp as wp

    if args.devices:
        if args.devices == "all":
            found = [d.alias for d in wp.get_cuda_devices()]
            return found or ["cpu"]
        return [d.strip() for d in args.devices.split(",") if d.strip()]
    if args.device:
        return [args.device]
    return ["cuda:0"] if wp.get_cuda_device_count() else ["cpu"]


def press_dataset(spec, devices, together, tmp):
    """(items, presses, planning s, pressing s, SweepTimes) of one run of the dataset into a new folder."""
    from almsdm_warp.batch import dataset as ds
    from almsdm_warp.batch.sweep_times import SweepTimes

    t0 = time.perf_counter()
    items = ds.plan_items(spec, cuda=devices[0] != "cpu", gpus=len(set(devices)))
    planned = time.perf_counter() - t0
    folder = ds.DatasetFolder(Path(tempfile.mkdtemp(dir=tmp)) / "ds", items, spec)
    todo = folder.open()
    times = SweepTimes()
    t0 = time.perf_counter()
    ds.press_dataset(folder, todo, devices, together=together, times=times)
    pressed = time.perf_counter() - t0
    return items, sum(len(i.plan.vertices) for i in items), planned, pressed, times


def sweep_plan(item, points: int, devices):
    """The item's scene swept without a lesion at `points` points (a sweep's points and chunks)."""
    from almsdm_warp.batch.sampling import pressable_points
    from almsdm_warp.batch.sweep_plan import default_chunk

    p = item.plan
    pts, verts = pressable_points(p.mesh, points, p.fixed_below)
    return replace(p, edge_scale=None, anchor_scale=None, element_scale=None, points=pts, vertices=verts,
                   chunk=default_chunk(len(verts), devices), rings=p.rings if np.ndim(p.rings) == 0 else int(np.max(p.rings)))


def press_sweep(plan, devices, tmp) -> tuple[float, int]:
    """(seconds, region-steps) of one sweep of `plan` on `devices` (batch.sweep.run_local, parts written and removed)."""
    from almsdm_warp.batch.sweep import run_local
    from almsdm_warp.batch.sweep_store import Parts
    from almsdm_warp.batch.sweep_times import SweepTimes

    parts = Parts(Path(tempfile.mkdtemp(dir=tmp)) / "sweep.npz", plan)
    parts.open()
    times = SweepTimes()
    t0 = time.perf_counter()
    run_local(plan, parts, list(range(len(plan.chunks))), devices, times=times)
    seconds = time.perf_counter() - t0
    parts.remove()
    return seconds, times.region_steps


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("spec", nargs="?", default=str(HERE / "scenes" / "datasets" / "example.toml"))
    ap.add_argument("--points", type=int, default=None, help="points a scene (default: the spec's)")
    ap.add_argument("--device", default=None, help="one device (default cuda:0 where present, else cpu)")
    ap.add_argument("--devices", default=None, help="a comma list of devices, or 'all' (every CUDA device)")
    ap.add_argument("--runs", type=int, default=2, help="runs of each; the best is reported (default 2)")
    ap.add_argument("--item-by-item", action="store_true", help="also press the dataset as before, item after item")
    ap.add_argument("--no-sweeps", action="store_true", help="time the dataset alone (no single sweeps to compare with)")
    args = ap.parse_args(argv)

    from almsdm_warp.batch import dataset as ds
    from almsdm_warp.warp_init import init_warp

    init_warp()
    devices = devices_of(args)
    spec = ds.load_spec(args.spec)
    spec.points = args.points or spec.points
    spec.maps, spec.csv = "none", False
    print(f"{args.spec}: {spec.points} points a scene, on {', '.join(devices)}")
    with tempfile.TemporaryDirectory() as tmp:
        ways = [("together", True)] + ([("item by item", False)] if args.item_by_item else [])
        best = {}
        for _ in range(args.runs):  # the ways interleaved, so that a machine's load falls on each alike
            for name, together in ways:
                run = press_dataset(spec, devices, together, tmp)
                if name not in best or run[3] < best[name][3]:
                    best[name] = run
        for name, (items, presses, planned, pressed, _) in best.items():
            print(f"dataset ({name}): {len(items)} items, {presses} presses in {pressed:.3f} s: {presses / pressed:,.1f} presses/s "
                  f"(planning its items: {planned:.3f} s, apart)")
        items, presses, _, pressed, times = best["together"]
        if args.no_sweeps:
            print(times.table(pressed))
            return
        equivalent, steps_equivalent = 0.0, 0.0
        for scene in dict.fromkeys(i.scene for i in items):
            mine = [i for i in items if i.scene == scene]
            n = sum(len(i.plan.vertices) for i in mine)
            plan = sweep_plan(mine[0], n, devices)
            seconds, steps = min(press_sweep(plan, devices, tmp) for _ in range(args.runs))
            rate = len(plan.vertices) / seconds
            equivalent += n / rate
            steps_equivalent += n * steps / len(plan.vertices)
            print(f"single sweep of {scene} ({len(plan.vertices)} points, no lesion): {seconds:.3f} s: {rate:,.1f} presses/s, "
                  f"{steps / seconds:,.0f} region-steps/s")
    print(f"the dataset's presses at each scene's single-sweep rate: {equivalent:.3f} s; the dataset together: "
          f"{presses / pressed:,.1f} presses/s, {100 * equivalent / pressed:.0f}% of that rate")
    print(f"region-steps (substeps counted: a stiff lesion's item takes more): the dataset {times.region_steps:,} "
          f"({times.region_steps / pressed:,.0f} /s), its scenes' sweeps of as many presses {steps_equivalent:,.0f}; "
          f"the dataset at {100 * (times.region_steps / pressed) / (steps_equivalent / equivalent):.0f}% of their region-steps/s")
    print("where the dataset's time went (together, its best run):")
    print(times.table(pressed))


if __name__ == "__main__":
    main()
