"""`almsdm palpate`: press a scene or mesh with the probe and report force, recovery and speed."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from ..checks import check_protocol, check_ring_count
from ..errors import InputError
from ..protocol.schedule import PressSchedule
from .args import (
    AUTO_TOL_MM,
    GLOBAL_RINGS,
    add_integrator_arg,
    add_law_arg,
    add_probe_radius_arg,
    add_tissue_args,
    auto_tol,
    check_contact,
    check_law,
    count_arg,
    finite,
    get_device,
    load_scene_and_mesh,
    mesh_json,
    number_arg,
    path_arg,
    print_notes,
    probe_position,
    quiet_warp,
    rings_arg,
    rings_text,
    scene_with_tissue_args,
)
from .volume_arg import add_volume_arg, on_tets, tets_for

__all__ = ["AUTO_TOL_MM", "GLOBAL_RINGS", "add_parser", "cmd_palpate"]

TIMING_STEPS = 2000
"""Steps timed after the presses, in batches (fewer when a step is slow: about 1 s in all)."""


def add_parser(sub) -> None:
    from .record import add_record_args

    palpate = sub.add_parser(
        "palpate",
        help="press the probe into a scene or mesh; print force, recovery and speed (the default command)",
        description="Press the probe into a scene or mesh (the local ALMSDM region, or the whole mesh) and print "
        "the feedback force, the recovery after release and the speed of a step. Defaults come from the scene.",
    )
    palpate.add_argument("scene", nargs="?", default=None, type=path_arg, metavar="MESH_OR_SCENE", help="scene (.toml), scene name or mesh file; default: the stomach scene")
    palpate.add_argument("--rings", type=rings_arg(), default=None, metavar="{N,auto,global,global-free}", help="rings of the local region (outermost fixed), auto (sized to --tol-mm), or a global model (default: the scene's)")
    palpate.add_argument("--tol-mm", type=number_arg("> 0"), default=None, metavar="MM", help="--rings auto: grow the region until its fixed ring would move less than this [mm] (default 0.1)")
    add_integrator_arg(palpate)
    add_law_arg(palpate, "palpation")
    palpate.add_argument("--dt-ms", type=number_arg("> 0"), default=1.0, metavar="MS", help="frame [ms], at which the force is reported (default 1); the explicit integrator takes it in substeps under 0.9 x its critical step")
    palpate.add_argument("--depth-mm", "--depth", dest="depth_mm", type=number_arg("> 0"), default=None, metavar="MM", help="press depth [mm] (default: the scene's)")
    palpate.add_argument("--ramp-s", type=number_arg(">= 0"), default=None, metavar="S", help="ramp time [s] (default: the scene's)")
    palpate.add_argument("--hold-s", type=number_arg(">= 0"), default=None, metavar="S", help="hold time [s] (default: the scene's)")
    palpate.add_argument("--settle-s", type=number_arg(">= 0"), default=None, metavar="S", help="settle window after release [s] (default: the scene's)")
    add_probe_radius_arg(palpate)
    palpate.add_argument("--presses", type=count_arg, default=1, metavar="N", help="presses at the same spot (default 1)")
    palpate.add_argument("--scale-mm", type=number_arg("> 0"), default=None, metavar="MM", help="millimetres per mesh file unit, for a mesh file (default: guessed from its size, said where not 1; 10 for cm, 1000 for m)")
    where = palpate.add_mutually_exclusive_group()
    where.add_argument("--vertex", type=int, default=None, metavar="V", help="contact vertex (a surface vertex id)")
    where.add_argument("--probe-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="probe position [mm]; the contact is its nearest surface vertex")
    palpate.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ...")
    palpate.add_argument("--json", default=None, type=path_arg, metavar="PATH", help="write the result as JSON here")
    palpate.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar on stderr (default: only on a terminal, for runs over ~2 s)")
    add_volume_arg(palpate)
    add_tissue_args(palpate)
    add_record_args(palpate)
    palpate.set_defaults(func=cmd_palpate)


def _contact(args, mesh, device):
    """(vertex, point [m], extra JSON) from --vertex, --probe-mm, or the top surface vertex."""
    if args.vertex is not None:
        v, n = args.vertex, mesh.vertex_count
        if not 0 <= v < n:
            raise InputError(f"--vertex {v} is outside the mesh, which has {n} vertices (0..{n - 1})")
        if v not in mesh.surface_vertices:
            raise InputError(f"--vertex {v} is inside the volume, not on the surface: the probe presses a surface vertex")
        return v, mesh.vertices[v], {}
    if args.probe_mm is not None:
        from ..region.contact import find_contacts

        probe = probe_position(args.probe_mm)
        c = find_contacts(mesh, probe, device=device)
        check_contact(c, probe, mesh)
        extra = {"probe_mm": (probe * 1e3).tolist(), "face": int(c.face), "distance_mm": float(c.distance * 1e3)}
        return int(c.vertex), np.asarray(c.point, dtype=np.float64), extra
    # the highest surface vertex: a press from the top
    from ..region.contact import top_vertex

    v = top_vertex(mesh)
    return v, mesh.vertices[v], {}


def _on_tets(args, scene0, kind, scene, mesh, point, depth, device):
    """--volume auto or --wall tets: the surface made tets, finest at the press, the scene's flags applied again
    on them, and the contact found again there: (scene, mesh, vertex, point, extra)."""
    radius = scene.probe_radius if args.probe_radius_mm is None else args.probe_radius_mm * 1e-3
    scene, mesh = on_tets(args, scene0, kind, scene, mesh, point, radius, depth)
    if args.vertex is None:
        return (scene, mesh, *_contact(args, mesh, device))
    surface = mesh.surface_vertices  # a volume's surface vertex ids are new (a wall keeps them): the nearest
    vertex = int(surface[np.argmin(np.linalg.norm(mesh.vertices[surface] - point, axis=1))])
    return scene, mesh, vertex, mesh.vertices[vertex], {}


@dataclass
class _Run:
    """What `palpate` resolved from its arguments and the scene (SI units)."""

    scene: object
    mesh: object
    device: object
    rings: object
    """An int, "auto", "global" or "global-free"."""
    tol: float | None
    depth: float
    ramp: float
    hold: float
    settle: float
    dt: float
    vertex: int
    point: np.ndarray
    contact_extra: dict
    probe_radius: float = 0.0
    """The spherical probe's radius [m] (0: the paper's probe)."""


def cmd_palpate(args) -> int:
    """Press the probe into a scene or mesh, report force, recovery and speed."""
    from ..export.writers import check_output, write_output
    from ..solvers.stepper import SimulationDiverged
    from .record import check_record_args

    if args.json:
        check_output(args.json, "record", "--json")
    check_record_args(args)
    run = _resolve(args)
    pal = _build(args, run)
    critical, free_count = _report_model(args, run, pal)
    presses = _press(args, run, pal)
    if run.tol is not None:  # time the region as the presses grew it, not a retired one
        pal.rebuild(max(r["rings"] for r in pal.press_log), retire=False)
        critical = pal.model.critical_dt(pal.region.vertices()[: pal.region.free_count])
        free_count = pal.region.free_count
    try:
        from ..protocol.timing import time_palpation
        from ..sim.model import PROBE_OFF

        pal.set_probe(PROBE_OFF)
        times = time_palpation(pal, 20, warmup=5, budget_s=1.0, max_steps=TIMING_STEPS // 20)  # about 1 s at most: no bar
        step_s, timed = times.median, times.steps
    except SimulationDiverged as exc:
        raise InputError(str(exc)) from exc
    step_us = step_s * 1e6
    steps_per_s = 1.0 / step_s if step_s > 0 else math.inf
    print(f"speed: {step_us:.1f} us per step (median of 20 batches, {timed} steps), {steps_per_s:,.0f} steps/s")

    if args.json:
        record = _record(args, run, pal, presses, critical, free_count)
        record.update({"step_us_median": finite(step_us), "steps_per_s": finite(steps_per_s), "timing_steps": int(timed)})
        write_output(args.json, record, "record")
        print(f"wrote {args.json}")
    return 0


def _resolve(args) -> _Run:
    """The device, scene, mesh, region, press protocol and contact that the arguments ask for."""
    quiet_warp()
    device = get_device(args.device)
    scene0, mesh = load_scene_and_mesh(args)
    scene = scene_with_tissue_args(args, scene0, mesh)

    rings = scene.rings if args.rings is None else args.rings
    # more rings than vertices can only repeat the whole component (and 1e20 overflows the ring table)
    check_ring_count(rings, mesh.vertex_count, "--rings" if args.rings is not None else "the scene's [region] rings")
    p = scene.press
    depth = p.depth if args.depth_mm is None else args.depth_mm * 1e-3
    ramp = p.ramp if args.ramp_s is None else args.ramp_s
    hold = p.hold if args.hold_s is None else args.hold_s
    settle = p.settle if args.settle_s is None else args.settle_s
    dt = args.dt_ms * 1e-3
    check_protocol(depth, dt, ramp, hold, settle, args.presses, float(np.ptp(mesh.vertices, axis=0).max()))
    vertex, point, contact_extra = _contact(args, mesh, device)
    kind = tets_for(args, scene, mesh)
    if kind is not None:
        scene, mesh, vertex, point, contact_extra = _on_tets(args, scene0, kind, scene, mesh, point, depth, device)
    scene = scene.with_support(mesh, float(mesh.vertices[vertex, 2]))  # a relative support, from this contact
    if scene.fixed_below is not None and mesh.vertices[vertex, 2] < scene.fixed_below:
        raise InputError(f"the contact vertex {vertex} (z {mesh.vertices[vertex, 2] * 1e3:.4g} mm) is supported: it lies below "
                         f"the support plane z = {scene.fixed_below * 1e3:g} mm and cannot be pressed")
    tol = auto_tol(args, rings, scene)
    scene = check_law(scene, mesh, args.integrator, "adaptive" if tol is not None else "palpation",
              "--rings auto (an adaptive region): " if tol is not None else "")
    radius = scene.probe_radius if args.probe_radius_mm is None else args.probe_radius_mm * 1e-3
    return _Run(scene, mesh, device, rings, tol, depth, ramp, hold, settle, dt, vertex, point, contact_extra, radius)


def _build(args, run: _Run):
    """Say what is pressed, then make the palpation (adaptive for rings "auto") and touch the contact."""
    from ..scene.press import build_palpation
    from ..tissue.material import holding_notes

    mesh, scene = run.mesh, run.scene
    print(mesh.summary())
    support = f"; support {scene.support_text()}" if scene.fixed_below is not None or scene.support else ""
    print(f"tissue: {scene.tissue_model} ({scene.tissue_text()}), law {scene.law}{support}")
    if scene.lesion is not None:
        les = scene.lesion.as_dict()
        print(f"lesion: {les['stiffness_factor']:g}x stiffer within {les['radius_mm']:g} mm of {[round(c, 2) for c in les['center_mm']]} mm")
    print(
        f"contact: vertex {run.vertex} at {np.round(run.point * 1e3, 2).tolist()} mm; press {run.depth * 1e3:g} mm "
        f"(ramp {run.ramp:g} s, hold {run.hold:g} s, settle {run.settle:g} s) x {args.presses}"
    )
    try:
        pal = build_palpation(scene, mesh, rings="auto" if run.tol is not None else run.rings, tol=run.tol,
                              integrator=args.integrator, dt=run.dt, device=run.device, probe_radius=run.probe_radius)
        if run.probe_radius > 0:
            pal.touch(run.vertex, run.depth)  # the region grown from the patch the sphere covers at this depth
        else:
            pal.touch(run.vertex)
    except ValueError as exc:  # a parameter Palpation rejects (an InputError passes through unchanged)
        raise InputError(str(exc)) from exc
    pal.notes[:0] = holding_notes(scene.tissue, mesh.is_volume, scene.fixed_below is not None)
    return pal


def _report_model(args, run: _Run, pal):
    """Print the model line: region, springs (or a tet law's tets), integrator and the explicit critical step; returns
    (critical step [s], free vertices)."""
    rings, tol, dt = run.rings, run.tol, run.dt
    anchored = rings != "global-free"
    critical = pal.region_critical_dt()
    free_count = pal.solver.free_count  # supported vertices are fixed too
    if tol is not None:
        what = (
            f"auto rings (tol {tol * 1e3:g} mm) around vertex {run.vertex}, grown from "
            f"{rings_text(pal.region.outer_ring)} of {pal.region_vertices} vertices"
        )
    elif pal.region is not None:
        what = f"{rings_text(rings)} around vertex {run.vertex}, {pal.region_vertices} vertices ({free_count} free)"
    else:
        kind = "anchored" if anchored else "free, no anchors"
        what = f"{rings} ({kind}), {free_count} of {pal.region_vertices} vertices free"
    if run.probe_radius > 0:
        what += f", a {run.probe_radius * 1e3:g} mm sphere"
    for note in pal.notes:
        print(f"note: {note}")
    beyond = ", at the start" if tol is not None else ""
    steps = f" in {pal.substeps} substeps of {pal.step_dt * 1e3:.3g} ms" if pal.substeps > 1 else ""
    tets = pal.region_tets
    elements = f"{pal.region_springs} springs" if tets is None else f"{tets} tets ({pal.model.law})"
    print(
        f"model: {what}, {elements}; {pal.solver.integrator} integrator, dt {dt * 1e3:g} ms{steps} "
        f"(explicit critical step {critical * 1e3:.3g} ms{beyond}), device {run.device}"
    )
    return critical, free_count


def _press(args, run: _Run, pal) -> list:
    """Run the presses with the progress bar and the recording; print and return their results."""
    from ..progress import Progress
    from ..solvers.stepper import SimulationDiverged
    from .record import Recording

    dt, ramp, hold, settle = run.dt, run.ramp, run.hold, run.settle
    per_press = PressSchedule.from_times(dt, ramp, hold, settle).total
    presses = []
    original_step = pal.step
    deepest = PressSchedule.from_times(dt, ramp, hold).release_step  # the end of the first hold
    label = f"{run.mesh.name}, {rings_text(run.rings) if pal.region is not None else f'{run.rings} model'}, {run.depth * 1e3:g} mm press"
    recording = Recording(args, pal, args.presses, per_press, deepest, label)
    with recording, Progress(args.presses * per_press, enabled=args.progress) as bar:

        def counted_step():
            # counts the steps Palpation.press takes (it calls self.step), for the bar
            out = original_step()
            bar.advance()
            return out

        pal.step = counted_step
        try:
            for i in range(args.presses):
                bar.label = f"press {i + 1}/{args.presses}"
                try:
                    result = pal.press(run.depth, ramp, hold, settle, **recording.press_kwargs())
                except (SimulationDiverged, ValueError) as exc:  # user-chosen parameters: one line, exit 2
                    raise InputError(str(exc)) from exc
                bar.done = (i + 1) * per_press
                presses.append(result)
                auto = f", {rings_text(pal.rings_chosen)} ({pal.auto_reason})" if run.tol is not None else ""
                rt = result.recovery_time_s
                rt_text = f"{rt:.3f} s" if math.isfinite(rt) else f"not within the {settle:g} s settle window"
                bar.close()
                print(
                    f"press {i + 1}: peak force {result.peak_force_N:.3f} N, hold force {result.hold_force_N:.3f} N, "
                    f"recovery error {result.recovery_error_mm:.3f} mm, recovery time {rt_text}{auto}"
                )
                if result.diverged_at:  # (an adaptive region that grew planned more substeps for itself: no note)
                    n = result.diverged_at[0]
                    then = "".join(f", then at {m}" for m in result.diverged_at[1:])
                    print(f"note: press {i + 1} diverged at {n} substep(s) of {run.dt / n * 1e3:.3g} ms (planned at "
                          f"0.9 of the critical step at rest){then} and was pressed again at {result.substeps}: these are its numbers")
                for line in press_warnings(result, run.mesh.tet_count, run.probe_radius):
                    print(f"warning: press {i + 1}: {line}", file=sys.stderr)
        finally:
            del pal.step  # back to the class's step, uncounted
        for line in recording.finish():
            print(line)
    return presses


def press_warnings(result, tet_count: int, probe_radius: float) -> list[str]:
    """What a press on tets says against itself: tets inverted, and a sphere that came near the region's fixed
    ring (within NEAR_RING of its radius, PressResult.ring_gap), which holds still tissue the press moves."""
    from ..protocol.palpation import NEAR_RING

    gap, out = result.ring_gap, []
    ring = None
    if tet_count and gap is not None and gap < NEAR_RING * probe_radius:
        where = f"came within {gap * 1e3:.3g} mm of" if gap >= 0 else f"reaches {-gap * 1e3:.3g} mm into"
        ring = (f"the sphere {where} the region's fixed ring at full depth, which holds still tissue the press moves: "
                f"its force may be far off the global model's; more --rings, or --rings auto")
    if result.inverted_tets:
        out.append(f"{result.inverted_tets} of {tet_count} tetrahedra inverted (det F <= 0) at the end of the hold: "
                   f"{ring or 'the press is too deep for these tets'}")
    elif ring is not None:
        out.append(ring)
    return out


def _record(args, run: _Run, pal, presses, critical, free_count) -> dict:
    """The JSON record of the run, but for its timing keys."""
    tol = run.tol
    return {
        "scene": str(run.scene.path) if run.scene.path else None,
        "mesh": mesh_json(run.mesh),
        "device": str(run.device),
        "contact": {"vertex": int(run.vertex), "point_mm": (np.asarray(run.point) * 1e3).tolist(), **run.contact_extra},
        **{key: run.scene.as_dict()[key] for key in ("tissue", "support")},
        "press": {"depth_mm": run.depth * 1e3, "ramp_s": run.ramp, "hold_s": run.hold, "settle_s": run.settle},
        "model": {
            "rings": run.rings,
            **(_auto_json(pal, tol) if tol is not None else {}),
            "region_vertices": int(pal.region_vertices),
            "region_springs": int(pal.region_springs),
            "region_tets": pal.region_tets,
            "free_vertices": int(free_count),
            "integrator": pal.solver.integrator,
            "law": pal.model.law,
            "probe_radius_mm": run.probe_radius * 1e3,
            "dt_s": run.dt,
            "substeps": int(pal.substeps),
            "critical_dt_s": finite(critical),
        },
        "presses": [
            {
                "peak_force_N": finite(r.peak_force_N),
                "hold_force_N": finite(r.hold_force_N),
                "inverted_tets": r.inverted_tets,
                "substeps": r.substeps,
                "pressed_again": len(r.diverged_at),
                "ring_gap_mm": None if r.ring_gap is None else finite(r.ring_gap * 1e3),
                "recovery_error_mm": finite(r.recovery_error_mm),
                "recovery_time_s": finite(r.recovery_time_s),
                **({"rings_chosen": log["rings"]} if tol is not None else {}),
            }
            for r, log in zip(presses, pal.press_log if tol is not None else [None] * len(presses))
        ],
    }


def _auto_json(pal, tol):
    """The adaptive region's keys of the JSON's model: what it chose, why, and how it grew."""
    chosen = max(r["rings"] for r in pal.press_log)
    return {
        "tol_mm": tol * 1e3,
        "rings_chosen": int(chosen),
        "auto_reason": pal.press_log[-1]["reason"],
        "auto_events": [r["events"] for r in pal.press_log],
    }
