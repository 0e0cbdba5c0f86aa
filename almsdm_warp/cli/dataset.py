"""`almsdm sweep --dataset SPEC --out DIR`: sweeps over several organs and a lesion grid, one dataset."""

from __future__ import annotations

import sys
import time
from pathlib import Path

SPEC_DECIDES = ("scene", "points", "rings", "tol_mm", "depth_mm", "ramp_s", "hold_s", "settle_s", "dt_ms", "scale_mm", "png", "ray",
                "law", "integrator", "probe_radius_mm", "tissue", "support", "fixed_below_mm", "curve_points", "tactile_size", "lesion_labels",
                "volume", "wall")
"""sweep's arguments that a dataset spec decides (an error beside --dataset, not silently ignored)."""


def add_dataset_arg(parser) -> None:
    parser.add_argument("--dataset", default=None, metavar="SPEC",
                        help="a dataset spec (TOML: scenes, points, press, lesion grid; docs/datasets.md): sweep every "
                             "scene with and without each lesion into one dataset; --out is then a folder")


def cmd_dataset(args, devices: list[str]) -> int:
    """Run the dataset spec args.dataset into the folder args.out on `devices` (resuming what is there)."""
    from ..batch import dataset as ds
    from ..batch.sweep_times import SweepTimes
    from ..errors import InputError
    from ..progress import Progress
    from ..solvers.stepper import SimulationDiverged
    from ..checks import check_region_steps
    from .args import MATERIAL_FLAGS, quiet_warp

    decided = SPEC_DECIDES + tuple(MATERIAL_FLAGS)
    given = [f"--{a.replace('_', '-')}" if a != "scene" else "SCENE" for a in decided if getattr(args, a, None) is not None]
    if given:
        raise InputError(f"{given[0]} is decided by the dataset spec {args.dataset}: leave it out with --dataset")
    quiet_warp()
    spec = ds.load_spec(args.dataset)
    if args.chunk:
        spec.chunk = args.chunk
    ds.check_spec_cost(spec, args.max_region_steps)  # from the spec's counts, before any planning
    for scene in spec.scenes:
        if scene.lesion is not None:
            print(f"note: the scene {scene.name!r}'s own [lesion] is left out: the dataset's lesion grid decides")
    count = ds.spec_cost(spec)[0]
    print(f"planning {count} item(s) of {len(spec.scenes)} scene(s)", flush=True)
    with Progress(count, enabled=args.progress, label="planning") as bar:
        items = ds.plan_items(spec, cuda=devices[0] != "cpu", on_item=bar.advance, gpus=len(set(devices)))
    from ..batch.sweep_plan import press_steps

    check_region_steps(sum(len(i.plan.vertices) * press_steps(i.plan) for i in items), 1, 1, args.max_region_steps)
    folder = ds.DatasetFolder(args.out, items, spec)
    todo = folder.open()  # the first write: every check is behind it
    scenes = len({i.scene for i in items})
    points = sum(len(i.plan.vertices) for i in items)
    print(f"dataset: {len(items)} items ({scenes} scene(s) x lesions, baseline {'on' if spec.baseline else 'off'}), "
          f"{points} presses; {len(items) - len(todo)} item(s) already in {folder.dir}")
    if folder.note:
        print(f"note: {folder.note}", file=sys.stderr)
    total = sum(len(i.plan.vertices) * press_steps(i.plan) for i in todo)
    t0, times = time.perf_counter(), SweepTimes()
    try:
        with Progress(total, enabled=args.progress, label="dataset") as bar:
            ds.press_dataset(folder, todo, devices, bar, on_item=lambda item: print(f"item {item.name}: done"), times=times)
    except KeyboardInterrupt:
        print(f"almsdm: interrupted; the items done are in {folder.dir}: run the same command again to resume", file=sys.stderr)
        return 130
    except (SimulationDiverged, InputError) as exc:  # diverged, or a write refused: a folder this run made with no item goes
        folder.discard_if_new()
        raise InputError(str(exc)) from exc
    columns = ds.finish_dataset(folder)
    print(f"pressed {len(todo)} item(s) in {time.perf_counter() - t0:.2f} s; "
          f"wrote {Path(folder.dir) / 'table.npz'} ({len(columns['vertex'])} rows)")
    for note in times.notes():
        print(f"note: {note}")
    return 0
