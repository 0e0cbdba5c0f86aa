"""`almsdm sweep`: press N points spread over an organ (a batch on the device), write the force map."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..checks import LIMITS, check_limit, check_protocol, check_region_steps, check_ring_count
from ..errors import InputError
from .dataset import add_dataset_arg, cmd_dataset
from .args import rings_text as words_for_rings
from .volume_arg import add_volume_arg, tets_for
from .args import (auto_tol, add_integrator_arg, add_law_arg, add_tissue_args, check_law, count_arg, get_device, load_scene_and_mesh,
                   number_arg, quiet_warp, rings_arg, scene_with_tissue_args)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "sweep",
        help="press N points spread over a scene or mesh at once (batched); write a force map (.csv/.npz/.parquet)",
        description="Press N points spread evenly over the surface, all at once on the device (the local ALMSDM "
        "region of each; explicit or implicit integrator), and write per point: x_mm, y_mm, z_mm, vertex, peak_force_N, "
        "hold_force_N (force at the end of the hold), stiffness_N_per_mm (hold_force_N / depth), recovery_error_mm, rings. An interrupted sweep resumes "
        "from the chunks it wrote (OUT.parts/) when run again with the same arguments.",
    )
    p.add_argument("scene", nargs="?", default=None, metavar="SCENE_OR_MESH", help="scene (.toml), scene name or mesh file; default: the stomach scene")
    p.add_argument("--out", required=True, metavar="FILE", help="output table: .csv, .npz or .parquet (the parquet extra)")
    p.add_argument("--points", type=count_arg, default=None, metavar="N", help=f"points to press (default {DEFAULT_POINTS})")
    p.add_argument("--rings", type=rings_arg(("auto",)), default=None, metavar="{K,auto}", help="rings of each local region, or auto: each point's sized to --tol-mm as almsdm palpate --rings auto sizes it (default: the scene's)")
    p.add_argument("--tol-mm", type=number_arg("> 0"), default=None, metavar="MM", help="--rings auto: the displacement tolerance [mm] (default: the scene's, else 0.1)")
    p.add_argument("--depth-mm", "--depth", dest="depth_mm", type=number_arg("> 0"), default=None, metavar="MM", help="press depth [mm] (default: the scene's)")
    p.add_argument("--ramp-s", type=number_arg(">= 0"), default=None, metavar="S", help="ramp time [s] (default: the scene's)")
    p.add_argument("--hold-s", type=number_arg(">= 0"), default=None, metavar="S", help="hold time [s] (default: the scene's)")
    p.add_argument("--settle-s", type=number_arg(">= 0"), default=None, metavar="S", help="settle window [s] (default: the scene's)")
    add_integrator_arg(p, batch=True)
    add_law_arg(p, "batch")
    p.add_argument("--dt-ms", type=number_arg("> 0"), default=None, metavar="MS", help="frame [ms] (default 1); the explicit integrator takes it in substeps under 0.9 x the critical step")
    p.add_argument("--scale-mm", type=number_arg("> 0"), default=None, metavar="MM", help="millimetres per mesh file unit, for a mesh file (default: guessed from its size)")
    p.add_argument("--device", default="cpu", help="cpu, cuda:0, ..., a comma list, or 'all' (every CUDA device); default cpu")
    p.add_argument("--chunk", type=count_arg, default=None, metavar="N", help="points per batch and per resumable part (default 64 on the CPU; on GPUs, four chunks a device or more, 16384..65536 points each)")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS", help="run the chunks on Ray actors (one GPU each with a CUDA --device, else one CPU; one a GPU of the cluster); ADDRESS of a cluster, or a local one")
    p.add_argument("--pipeline", action=argparse.BooleanOptionalAction, default=True, help="build and launch the next chunk while one presses, read back and write on the side (default); --no-pipeline: one chunk after another (the same numbers)")
    p.add_argument("--profile", action="store_true", help="print where the wall time went: sampling, region builds, planning, press kernels, read-back, checks, writing, gather; when the presses ran (before the first, idle between, after the last) and what the first waited for")
    p.add_argument("--png", default=None, metavar="PATH", help="also draw the organ coloured by stiffness (matplotlib)")
    p.add_argument("--max-region-steps", type=number_arg("> 0"), default=LIMITS["region_steps"], metavar="N", help=f"refuse a sweep that would take more region-steps (points x frames x substeps) than N (default {LIMITS['region_steps']:g})")
    p.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar on stderr (default: only on a terminal)")
    p.add_argument("--probe-radius-mm", type=number_arg(">= 0"), default=None, metavar="MM", help="radius of the spherical probe [mm]; 0: the paper's probe, the contact vertex driven (default: the scene's [probe] radius_mm, else 0)")
    p.add_argument("--curve-points", type=count_arg, default=None, metavar="N", help="rows for learning: the force curve, N samples along the ramp (columns force_curve_N and force_curve_depth_mm, N values a row)")
    p.add_argument("--lesion-labels", action="store_true", default=None, help="rows for learning, for a scene with a [lesion]: whether the lesion lies in the probe's footprint (lesion_in_footprint) and the contact vertex's distance to its surface (lesion_distance_mm)")
    p.add_argument("--tactile-size", type=count_arg, default=None, metavar="N", help="rows for learning, with a sphere: the contact patch's area (patch_area_mm2) and the contact pressure on an N x N grid over the sphere's footprint at the end of the hold (tactile_map_kPa, N*N values a row)")
    add_volume_arg(p)
    add_tissue_args(p)
    add_dataset_arg(p)
    p.set_defaults(func=cmd_sweep, start_devices=True, integrator=None, preload=("scipy.spatial", "scipy.sparse.linalg"))  # None: not given (a dataset's spec decides it)


def _devices(text: str) -> list[str]:
    import warp as wp

    if text == "all":
        found = [d.alias for d in wp.get_cuda_devices()]
        if not found:
            raise InputError("--device all: no CUDA device present (use --device cpu)")
        return found
    names = [t.strip() for t in text.split(",") if t.strip()]
    if not names:
        raise InputError(f"--device: no device in {text!r}")
    return list(dict.fromkeys(get_device(n).alias for n in names))


DEFAULT_POINTS = 200
"""--points when not given (None in the parser: a dataset's spec decides, and refuses it given)."""


def cmd_sweep(args) -> int:
    from ..batch.sweep_times import SweepTimes
    from ..export.writers import check_output

    if args.dataset:  # several scenes and a lesion grid: cli/dataset.py
        return cmd_dataset(args, _devices(args.device))
    args.points = DEFAULT_POINTS if args.points is None else args.points
    args.integrator = args.integrator or "explicit"
    out = Path(args.out)
    check_output(out, "table", "--out")
    if args.ray:  # before OUT.parts/ is made
        from ..batch.sweep import require_ray

        require_ray()
    if args.png:
        check_output(args.png, "image", "--png")
    quiet_warp()
    devices = _devices(args.device)
    times, t_start = SweepTimes(), time.perf_counter()
    plan, scene, rings_text, models = _plan(args, devices, times)
    parts, todo, left = _resume(out, plan)
    from ..batch.sweep_plan import table_info

    # where the format can, the table is written as the chunks come: after the last press, only what needs the whole
    args.table_info = table_info(plan, scene)  # what made the table: a Parquet table's metadata
    parts.rows_file = plan.table.rows(out, len(plan.vertices), args.table_info)
    try:
        return _run(args, plan, scene, rings_text, models, devices, parts, left, times, t_start, todo)
    except InputError:  # a write refused (a full disk): a parts folder this run made with nothing in it goes
        parts.discard_if_new()
        raise
    finally:
        if parts.rows_file is not None:
            parts.rows_file.discard()  # after finish(): nothing left to remove


def _run(args, plan, scene, rings_text, models, devices, parts, left, times, t_start, todo) -> int:
    """cmd_sweep's second half: the chunks, the table, the report."""
    from ..batch.sweep import run_local, run_ray
    from ..batch.sweep_plan import press_steps
    from ..progress import Progress
    from ..solvers.stepper import SimulationDiverged

    out, steps, t0 = Path(args.out), press_steps(plan), time.perf_counter()
    try:
        with Progress(left * steps, enabled=args.progress, label="sweep") as bar:
            if args.ray:
                run_ray(plan, parts, todo, devices[0] != "cpu", None if args.ray == "local" else args.ray, bar)
            else:
                run_local(plan, parts, todo, devices, bar, pipeline=args.pipeline, times=times, models=models)
    except KeyboardInterrupt:
        print(f"almsdm: interrupted; the chunks done are in {parts.dir}: run the same command again to resume", file=sys.stderr)
        return 130
    except SimulationDiverged as exc:  # a rerun of the same plan would diverge again: keep nothing
        parts.remove()
        raise InputError(str(exc)) from exc
    elapsed = time.perf_counter() - t0
    if plan.sampling is not None:  # behind the first chunks: its wall time, overlapped
        plan.wait()
        times.add("sampling", plan.sampling.seconds)
    with times.phase("gather"):
        columns = parts.gather()
    with times.phase("output"):
        if parts.rows_file is not None:
            parts.rows_file.finish(columns)
        else:
            plan.table.write(out, columns, args.table_info)
        parts.remove()
    _report(columns, left, steps, elapsed)
    for note in times.notes():
        print(f"note: {note}")
    if args.profile:
        print(f"where the sweep's wall time went (from loading the mesh to the written table):\n{times.table(time.perf_counter() - t_start)}")
    print(f"wrote {out}")
    if args.png:
        from ..export.sweep_png import plot_sweep

        title = f"{scene.name}: stiffness under a {plan.depth * 1e3:g} mm press, {rings_text}"
        plot_sweep(plan.mesh, columns, args.png, title=title, lesion=scene.lesion)
        print(f"wrote {args.png}")
    return 0


def _plan(args, devices, times):
    """The scene, its mesh and the sweep's plan (points, chunks, rings, step); says what will be pressed.
    Returns (plan, scene, the rings in words, the models on the devices: a Future, or None). The points
    may still be being sampled (plan.sampling), and the models made, while the caller goes on."""
    from ..batch.sampling import pressable_points, start_sampling
    from ..batch.sweep import models_behind
    from ..batch.sweep_plan import SweepPlan, check_sphere_travel, default_chunk, default_tail
    from ..protocol.palpation import check_probe_radius
    from ..batch.sweep_auto import rings_summary
    with times.phase("loading"):
        scene0, mesh = load_scene_and_mesh(args)
        mesh.adjacency  # the topology every model of the sweep shares
    scene = scene_with_tissue_args(args, scene0, mesh)
    press = scene.press
    rings = scene.rings if args.rings is None else args.rings
    tol = auto_tol(args, rings, scene)
    radius = scene.probe_radius if args.probe_radius_mm is None else args.probe_radius_mm * 1e-3
    depth = press.depth if args.depth_mm is None else args.depth_mm * 1e-3
    ramp = press.ramp if args.ramp_s is None else args.ramp_s
    hold = press.hold if args.hold_s is None else args.hold_s
    settle = press.settle if args.settle_s is None else args.settle_s
    dt = 1e-3 if args.dt_ms is None else args.dt_ms * 1e-3
    frames = check_protocol(depth, dt, ramp, hold, settle, 1, float(np.ptp(mesh.vertices, axis=0).max()))
    check_probe_radius(radius, mesh)  # before any work, as the batch checks it again
    check_sphere_travel(radius, depth, dt, ramp)
    check_limit(args.points, "points", "--points")
    scene, mesh, pressed = _tets(args, scene0, scene, mesh, radius, depth)  # the checks above hold on its tets too
    scene = check_law(scene, mesh, args.integrator, "batch")
    if tol is not None:
        check_law(scene, mesh, args.integrator, "adaptive", "--rings auto (each region sized by an adaptive press): ")
    check_ring_count(rings, mesh.vertex_count, "--rings" if args.rings is not None else "the scene's [region] rings")
    scales = scene.lesion.model_scales(mesh, scene.tissue, scene.law) if scene.lesion is not None else {}
    t0, sampling = time.perf_counter(), None
    if pressed is not None:  # the points the tets were made finest at
        points, vertices = pressed
    elif tol is None:  # (--rings auto sizes each point's region first: every point is needed at once)
        points, vertices, sampling = start_sampling(mesh, args.points, scene.fixed_below)
    else:
        points, vertices = pressable_points(mesh, args.points, scene.fixed_below)
    if sampling is None:  # else counted when it is done (its wall time, behind the first chunks)
        times.add("sampling", time.perf_counter() - t0)
    cuda = devices[0] != "cpu"
    chunk = args.chunk or default_chunk(len(vertices), devices)
    tail = 0 if args.chunk else default_tail(len(vertices), chunk, devices)
    plan = SweepPlan(mesh, scene.tissue, scales.get("edge_scale"), scales.get("anchor_scale"), 1 if tol else rings, dt, depth,
                     ramp, hold, settle, points, vertices, chunk, args.integrator, tol, radius, scene.fixed_below,
                     sampling=sampling, law=scene.law, element_scale=scales.get("element_scale"), records=_records(args, radius, ramp, dt, scene),
                     lesion=scene.lesion if args.lesion_labels else None, tail=tail)
    times.mark("plan")
    models = None if args.ray or not args.pipeline else models_behind(plan, devices)
    print(mesh.summary())
    with times.phase("set-up"):
        substeps = _substeps(plan)
    check_records(plan.records, plan.probe_radius, plan.integrator)  # the explicit integrator's fall-back: implicit
    cost = check_region_steps(len(vertices), frames, substeps, args.max_region_steps)
    if tol is not None:
        plan.rings = _size(plan, scales, tol, args.progress)
        rings_text = f"auto rings (tol {tol * 1e3:g} mm: {rings_summary(plan.rings)})"
    else:
        rings_text = words_for_rings(rings)
    lesion = f"; lesion {scene.lesion.as_dict()}" if scene.lesion is not None else ""
    distinct = "sampled while the first chunks press" if sampling is not None else f"{len(np.unique(vertices))} distinct vertices"
    where = f"Ray ({'GPU' if cuda else 'CPU'} tasks)" if args.ray else ", ".join(devices)
    print(
        f"sweep: {len(vertices)} points ({distinct}), {rings_text}, press {depth * 1e3:g} mm "
        f"(ramp {ramp:g} s, hold {hold:g} s, settle {settle:g} s), {plan.integrator}, dt {plan.dt * 1e3:g} ms, chunks of {chunk} on {where}{lesion}"
    )
    print(f"cost: {cost:.3g} region-steps ({len(vertices)} points x {frames} frames x at most {substeps} substep(s); "
          f"limit {args.max_region_steps:.3g}, --max-region-steps)")
    return plan, scene, rings_text, models


def _records(args, radius: float, ramp: float, dt: float, scene):
    """The learning records asked for (--curve-points, --tactile-size, --lesion-labels), checked before any work, or None."""
    from ..batch.records import Records
    from ..protocol.schedule import PressSchedule

    if args.curve_points is None and args.tactile_size is None and not args.lesion_labels:
        return None
    if args.lesion_labels and scene.lesion is None:
        raise InputError(f"--lesion-labels: scene {scene.name} has no [lesion] to label the presses with")
    records = Records(args.curve_points or 0, args.tactile_size or 0, bool(args.lesion_labels))
    check_records(records, radius, args.integrator)
    ramp_n = PressSchedule.from_times(dt, ramp, 0.0, 0.0).ramp_n  # frames: the substeps only add steps
    if records.curve_points > ramp_n:
        raise InputError(f"--curve-points {records.curve_points}: the ramp has only {ramp_n} frame(s) of {dt * 1e3:g} ms; "
                         f"ask for at most {ramp_n}, or a longer --ramp-s")
    return records


def check_records(records, radius: float, integrator: str) -> None:
    """InputError for learning records the sweep's press cannot make (Records.check, in the flags' names)."""
    if records is not None:
        try:
            records.check(radius, integrator, names=("--curve-points", "--tactile-size"))
        except ValueError as exc:
            raise InputError(str(exc)) from None
def _tets(args, scene0, scene, mesh, radius: float, depth: float):
    """--volume auto or --wall tets (or the scene's keys): (scene, its tets, (points, vertices) pressed on them),
    the points sampled on the surface and the tets made finest at each (scene/volume.py); else (scene, mesh, None)."""
    from dataclasses import replace

    from ..scene.volume import snap_to, sweep_tets
    from .args import print_notes

    kind = tets_for(args, scene, mesh)
    if kind is None:
        return scene, mesh, None
    tets, points = sweep_tets(kind, replace(scene, probe_radius=radius), mesh, args.points, depth)
    print_notes(tets)
    scene = scene_with_tissue_args(args, scene0, tets)
    return scene, tets, snap_to(tets, points, scene.fixed_below)


def _substeps(plan) -> int:
    """The explicit substeps a frame of the plan takes at most (the whole mesh's critical step bounds
    every region's), or 1 after switching the plan to the implicit fall-back (solvers.stepper.plan_substeps)."""
    from ..solvers.stepper import plan_substeps

    steps = plan_substeps(plan.integrator, plan.dt, plan.critical_dt, None, "the sweep")
    if steps.note:
        print(f"note: {steps.note}")
        plan.integrator = steps.integrator
    return steps.substeps


def _resume(out: Path, plan):
    """The chunks already written beside `out` (OUT.parts/): (parts, chunks to do, points left)."""
    from ..batch.sweep_store import Parts

    parts = Parts(out, plan)
    done = parts.open()
    if parts.dropped:
        print(f"note: the chunks in {parts.dir} {parts.dropped}: pressed again", file=sys.stderr)
    if parts.damaged:
        print(f"note: {len(parts.damaged)} chunk(s) in {parts.dir} did not match their checksum (damaged): pressed again", file=sys.stderr)
    done = set(done)
    todo = [i for i in range(len(plan.chunks)) if i not in done]
    if done:
        print(f"resuming: {len(done)} of {len(plan.chunks)} chunks already in {parts.dir}")
    left = sum(e - b for i, (b, e) in enumerate(plan.chunks) if i not in done)
    return parts, todo, left


def _report(columns, left: int, steps: int, elapsed: float) -> None:
    """One line: the rate, the range of peak forces and the stiffest point."""
    stiff = columns["stiffness_N_per_mm"]
    k = int(np.nanargmax(stiff)) if np.isfinite(stiff).any() else 0
    print(
        f"pressed {left} points in {elapsed:.2f} s ({left * steps / max(elapsed, 1e-9):,.0f} region-steps/s, with start-up); "
        f"peak force {np.nanmin(columns['peak_force_N']):.3f}..{np.nanmax(columns['peak_force_N']):.3f} N; "
        f"stiffest at vertex {columns['vertex'][k]} {np.round([columns['x_mm'][k], columns['y_mm'][k], columns['z_mm'][k]], 1).tolist()} mm "
        f"({stiff[k]:.4f} N/mm)"
    )


def _size(plan, scales, tol, progress):
    """--rings auto: the ring count of each point (sweep_auto.size_regions, on the CPU), timed and said."""
    from ..solvers.stepper import SimulationDiverged
    from ..progress import Progress
    from ..batch.sweep_auto import rings_summary, size_regions

    distinct = len(np.unique(plan.vertices))
    t0 = time.perf_counter()
    try:
        with Progress(distinct, enabled=progress, label="sizing regions") as bar:
            rings = size_regions(plan.mesh, plan.tissue, plan.vertices, tol, depth=plan.depth, ramp=plan.ramp, hold=plan.hold,
                                 integrator=plan.integrator, dt=plan.dt, on_point=bar.advance, probe_radius=plan.probe_radius,
                                 fixed_below=plan.fixed_below, law=plan.law, **scales)
    except (SimulationDiverged, ValueError) as exc:  # user-chosen parameters: one line, exit 2
        raise InputError(str(exc)) from exc
    print(f"auto rings: {distinct} contacts sized to {tol * 1e3:g} mm in {time.perf_counter() - t0:.2f} s "
          f"(an adaptive press each, CPU): {rings_summary(rings)}")
    return rings
