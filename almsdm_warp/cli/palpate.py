"""`almsdm palpate`: press a scene or mesh with the probe and report force, recovery and speed."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from .main import _device, _mesh_json, _quiet_warp
from ..errors import InputError

GLOBAL_RINGS = ("global", "global-free")
AUTO_TOL_MM = 0.1
"""--tol-mm when --rings auto is given without it [mm]."""
TIMING_STEPS = 2000
"""Steps timed after the presses, in batches (fewer when a step is slow: about 1 s in all)."""
MAX_STEPS = 10_000_000
"""Steps one run may take (every press together): a hundred minutes at a few us a step; more is a
typo (a dt in seconds given to --dt-ms, a hold in ms given to --hold-s), not a run to wait for."""


def rings_arg(words=("auto", *GLOBAL_RINGS)):
    """An argparse type for --rings: an integer >= 1 or one of `words`."""
    items = ["an integer >= 1", *(repr(w) for w in words)]
    allowed = ", ".join(items[:-1]) + " or " + items[-1]

    def parse(text):
        if text in words:
            return text
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"unknown value {text!r} (allowed: {allowed})") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"must be >= 1 (ring 0 is the contact vertex alone; allowed: {allowed}), got {value}")
        return value

    return parse


_rings_arg = rings_arg()


def _number_arg(rule):
    """An argparse type: a finite float that is "> 0" or ">= 0"."""

    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if (rule == "> 0" and not value > 0) or (rule == ">= 0" and not value >= 0):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return value

    parse.__name__ = "number"
    return parse


def _count_arg(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _finite(value):
    """A float for JSON, or None where it is not finite (JSON has no inf or nan)."""
    value = float(value)
    return value if math.isfinite(value) else None


def probe_position(probe_mm, flag="--probe-mm"):
    """--probe-mm X Y Z -> metres, finite and within the +-1 km that meshes are held to."""
    from ..mesh.validate import MAX_COORDINATE_M

    probe = np.asarray(probe_mm, dtype=np.float64) * 1e-3
    if not np.all(np.isfinite(probe)):
        raise InputError(f"{flag} must be finite, got {list(probe_mm)}")
    if np.abs(probe).max() > MAX_COORDINATE_M:
        raise InputError(f"{flag} {list(probe_mm)} is more than {MAX_COORDINATE_M * 1e3:g} mm from the origin, "
                         f"beyond any mesh the simulator holds")
    return probe


def check_contact(contact, probe, mesh):
    """A contact that found no surface vertex is an InputError, not a vertex id of -1."""
    if int(contact.vertex) < 0 or int(contact.face) < 0:
        raise InputError(f"the probe at {np.round(probe * 1e3, 3).tolist()} mm finds no surface of {mesh.name} "
                         f"(it is too far from the mesh)")


def check_protocol(depth, dt, ramp, hold, settle, presses, mesh):
    """A press the simulator can run: depth within the organ, dt no longer than the ramp or the
    settle window, and no more than MAX_STEPS steps in all (floats first: 1e300 / 1e-300 is inf)."""
    if not dt > 0:
        raise InputError(f"dt must be > 0, got {dt!r} s (--dt-ms underflows)")
    size = float(np.ptp(mesh.vertices, axis=0).max())
    if depth > size:
        raise InputError(f"press depth {depth * 1e3:g} mm is more than the mesh's extent ({size * 1e3:.4g} mm): "
                         f"the probe would go through the organ")
    for name, value, flag in (("ramp", ramp, "--ramp-s"), ("settle window", settle, "--settle-s")):
        if value > 0 and dt > value:
            raise InputError(f"dt {dt * 1e3:g} ms is longer than the {name} ({value:g} s): the press would not be "
                             f"resolved; use a smaller --dt-ms or a longer {flag}")
    steps = presses * (max(ramp / dt, 1.0) + hold / dt + max(settle / dt, 1.0))
    if not steps <= MAX_STEPS:
        raise InputError(f"the run would take {steps:.3g} steps ({presses} x (ramp {ramp:g} s + hold {hold:g} s + "
                         f"settle {settle:g} s) at dt {dt * 1e3:g} ms), more than the {MAX_STEPS:,} a run may take; "
                         f"use a larger --dt-ms or shorter times")


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


def _press_steps(dt, ramp, hold, settle):
    """Steps of one press, counted as Palpation.press counts them (for the progress bar only)."""
    return max(int(round(ramp / dt)), 1) + int(round(hold / dt)) + max(int(round(settle / dt)), 1)


def cmd_palpate(args) -> int:
    """Press the probe into a scene or mesh, report force, recovery and speed."""
    from ..export.output import check_writable, write_json
    from ..progress import Progress
    from ..protocol.timing import time_palpation
    from ..scene.loader import resolve_scene_or_mesh
    from ..sim.model import PROBE_OFF

    from .record import Recording, check_record_args

    if args.json:
        check_writable(args.json)
    check_record_args(args)
    _quiet_warp()
    device = _device(args.device)
    scene = resolve_scene_or_mesh(args.scene, scale_mm=1.0 if args.scale_mm is None else args.scale_mm)
    if args.scale_mm is not None and scene.path is not None:
        raise InputError(f"--scale-mm is for a mesh file; the scene {scene.name!r} sets its own ([mesh] scale_mm)")
    mesh = scene.load_mesh()
    for note in mesh.notes:
        print(f"note: {note}", file=sys.stderr)

    from ..protocol.palpation import Palpation, SimulationDiverged

    rings = scene.rings if args.rings is None else args.rings
    if isinstance(rings, int) and rings > mesh.vertex_count:  # (not "global", "global-free")
        # more rings than vertices can only repeat the whole component (and 1e20 overflows the ring table)
        where = "--rings" if args.rings is not None else "the scene's [region] rings"
        raise InputError(f"{where} {rings} is more than the mesh's {mesh.vertex_count} vertices; "
                         f"a region that large is the whole mesh: use --rings global")
    p = scene.press
    depth = p.depth if args.depth_mm is None else args.depth_mm * 1e-3
    ramp = p.ramp if args.ramp_s is None else args.ramp_s
    hold = p.hold if args.hold_s is None else args.hold_s
    settle = p.settle if args.settle_s is None else args.settle_s
    dt = args.dt_ms * 1e-3
    check_protocol(depth, dt, ramp, hold, settle, args.presses, mesh)
    vertex, point, contact_extra = _contact(args, mesh, device)
    tol = _auto_tol(args, rings, scene)

    print(mesh.summary())
    if scene.lesion is not None:
        les = scene.lesion.as_dict()
        print(f"lesion: {les['stiffness_factor']:g}x stiffer within {les['radius_mm']:g} mm of {[round(c, 2) for c in les['center_mm']]} mm")
    print(
        f"contact: vertex {vertex} at {np.round(point * 1e3, 2).tolist()} mm; press {depth * 1e3:g} mm "
        f"(ramp {ramp:g} s, hold {hold:g} s, settle {settle:g} s) x {args.presses}"
    )
    scales = scene.lesion.scales(mesh) if scene.lesion is not None else (None, None)
    lesion = dict(zip(("edge_scale", "anchor_scale"), scales))
    try:
        if tol is not None:
            from ..protocol.adaptive import AdaptivePalpation

            pal = AdaptivePalpation(mesh, scene.tissue, tol=tol, integrator=args.integrator, dt=dt, device=device, **lesion)
        else:
            pal = Palpation(mesh, scene.tissue, rings=rings, integrator=args.integrator, dt=dt, device=device, **lesion)
        pal.touch(vertex)
    except ValueError as exc:  # a parameter Palpation rejects (an InputError passes through unchanged)
        raise InputError(str(exc)) from exc
    anchored = rings != "global-free"
    free = pal.region.vertices()[: pal.region.free_count] if pal.region is not None else None
    critical = pal.model.critical_dt(free, anchors=anchored)
    free_count = len(free) if free is not None else pal.region_vertices
    if tol is not None:
        what = (
            f"auto rings (tol {tol * 1e3:g} mm) around vertex {vertex}, grown from "
            f"{pal.region.outer_ring} ring(s) of {pal.region_vertices} vertices"
        )
    elif pal.region is not None:
        what = f"{rings} rings around vertex {vertex}, {pal.region_vertices} vertices ({free_count} free)"
    else:
        kind = "anchored" if anchored else "free, no anchors"
        what = f"{rings} ({kind}), all {pal.region_vertices} vertices free"
    beyond = ", at the start" if tol is not None else ""
    beyond += ", dt exceeds it" if args.integrator == "explicit" and dt > critical else ""
    print(
        f"model: {what}, {pal.region_springs} springs; {args.integrator} integrator, dt {dt * 1e3:g} ms "
        f"(explicit critical step {critical * 1e3:.3g} ms{beyond}), device {device}"
    )

    press_steps = _press_steps(dt, ramp, hold, settle)
    presses = []
    original_step = pal.step
    deepest = _press_steps(dt, ramp, hold, 0) - 1  # the end of the first hold
    label = f"{mesh.name}, {rings} {'rings' if pal.region is not None else 'model'}, {depth * 1e3:g} mm press"
    recording = Recording(args, pal, args.presses, press_steps, deepest, label)
    with recording, Progress(args.presses * press_steps, enabled=args.progress) as bar:

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
                    result = pal.press(depth, ramp, hold, settle, **recording.press_kwargs())
                except (SimulationDiverged, ValueError) as exc:  # user-chosen parameters: one line, exit 2
                    raise InputError(str(exc)) from exc
                bar.done = (i + 1) * press_steps
                presses.append(result)
                auto = f", {pal.rings_chosen} rings ({pal.auto_reason})" if tol is not None else ""
                rt = result.recovery_time_s
                rt_text = f"{rt:.3f} s" if math.isfinite(rt) else f"not within the {settle:g} s settle window"
                bar.close()
                print(
                    f"press {i + 1}: peak force {result.peak_force_N:.3f} N, "
                    f"recovery error {result.recovery_error_mm:.3f} mm, recovery time {rt_text}{auto}"
                )
        finally:
            del pal.step  # back to the class's step, uncounted
        for line in recording.finish():
            print(line)
    if tol is not None:  # time the region as the presses grew it, not a retired one
        pal.rebuild(max(r["rings"] for r in pal.press_log), retire=False)
        critical = pal.model.critical_dt(pal.region.vertices()[: pal.region.free_count])
        free_count = pal.region.free_count
    try:
        pal.set_probe(PROBE_OFF)
        times = time_palpation(pal, 20, warmup=5, budget_s=1.0, max_steps=TIMING_STEPS // 20)  # about 1 s at most: no bar
        step_s, timed = times.median, times.steps
    except SimulationDiverged as exc:
        raise InputError(str(exc)) from exc
    step_us = step_s * 1e6
    steps_per_s = 1.0 / step_s if step_s > 0 else math.inf
    print(f"speed: {step_us:.1f} us per step (median of 20 batches, {timed} steps), {steps_per_s:,.0f} steps/s")

    if args.json:
        write_json(
            args.json,
            {
                "scene": str(scene.path) if scene.path else None,
                "mesh": _mesh_json(mesh),
                "device": str(device),
                "contact": {"vertex": int(vertex), "point_mm": (np.asarray(point) * 1e3).tolist(), **contact_extra},
                "press": {"depth_mm": depth * 1e3, "ramp_s": ramp, "hold_s": hold, "settle_s": settle},
                "model": {
                    "rings": rings,
                    **(_auto_json(pal, tol) if tol is not None else {}),
                    "region_vertices": int(pal.region_vertices),
                    "region_springs": int(pal.region_springs),
                    "free_vertices": int(free_count),
                    "integrator": args.integrator,
                    "dt_s": dt,
                    "critical_dt_s": _finite(critical),
                },
                "presses": [
                    {
                        "peak_force_N": _finite(r.peak_force_N),
                        "recovery_error_mm": _finite(r.recovery_error_mm),
                        "recovery_time_s": _finite(r.recovery_time_s),
                        **({"rings_chosen": log["rings"]} if tol is not None else {}),
                    }
                    for r, log in zip(presses, pal.press_log if tol is not None else [None] * len(presses))
                ],
                "step_us_median": _finite(step_us),
                "steps_per_s": _finite(steps_per_s),
                "timing_steps": int(timed),
            },
        )
        print(f"wrote {args.json}")
    return 0


def _auto_tol(args, rings, scene=None):
    """The tolerance [m] of rings "auto" (--tol-mm, else the scene's [region] tol_mm, else AUTO_TOL_MM),
    None for the others; --tol-mm with a fixed ring count is an error."""
    if rings != "auto":
        if args.tol_mm is not None:
            where = f"--rings {rings}" if args.rings is not None else f"the scene's [region] rings = {rings}"
            raise InputError(f"--tol-mm is for --rings auto (the region sized to a tolerance), not {where}")
        return None
    if args.tol_mm is not None:
        return args.tol_mm * 1e-3
    tol = getattr(scene, "tol", None)
    return tol if tol is not None else AUTO_TOL_MM * 1e-3


def _auto_json(pal, tol):
    """The adaptive region's keys of the JSON's model: what it chose, why, and how it grew."""
    chosen = max(r["rings"] for r in pal.press_log)
    return {
        "tol_mm": tol * 1e3,
        "rings_chosen": int(chosen),
        "auto_reason": pal.press_log[-1]["reason"],
        "auto_events": [r["events"] for r in pal.press_log],
    }
