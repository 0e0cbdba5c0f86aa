"""`almsdm trace`: move the probe sphere along a path over a scene and write the force trace.

The path is the sphere centre's, read from a CSV (t_s, x_mm, y_mm, z_mm) or, without --path, the
built-in stroke on the scene (touch down, press, slide across the surface, lift). It is sampled at
each step of the simulation (linear interpolation in time) and the region follows the contact.
With a virtual coupling (--coupling-stiffness-n-per-mm), the path is the haptic device's and the
tool follows it through a spring-damper (protocol/coupling.py); the trace then holds the tool's
position and the force sent to the device.

Step k moves the probe to the path's point at time t_k and advances the tissue by dt; its row
holds t_k, that point and the force at the end of the step (a haptic loop's order: read the
device, step, send the force). The USD stage's time code k is the state after step k.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import math
import time
from pathlib import Path

import numpy as np

from ..checks import check_ring_count
from ..errors import InputError
from ..export.tables import TableLayout, millimetres
from ..mesh.validate import MAX_COORDINATE_M
from .args import add_command, add_integrator_arg, add_law_arg, add_probe_radius_arg, add_tissue_args, check_law, count_arg
from .volume_arg import add_volume_arg
from .args import auto_tol, get_device, load_scene_and_mesh, number_arg, path_arg, quiet_warp, rings_arg, rings_text, scene_with_tissue_args

PATH_COLUMNS = ("t_s", "x_mm", "y_mm", "z_mm")
"""The columns of a path file, in this order, after a header line that names them."""
COLUMNS = ("t_s", "probe_x_mm", "probe_y_mm", "probe_z_mm", "force_x_N", "force_y_N", "force_z_N",
           "region_vertices", "relocations")
"""The columns of the trace, one row per reported step."""
DEVICE_COLUMNS = ("device_x_mm", "device_y_mm", "device_z_mm")
"""With a coupling: the device's position, after COLUMNS (the probe columns are then the tool's)."""
INT_COLUMNS = ("region_vertices", "relocations")
TRACE_TABLE = TableLayout("trace", {c: "int64" if c in INT_COLUMNS else "float64" for c in (*COLUMNS, *DEVICE_COLUMNS)},
                          optional=DEVICE_COLUMNS)
"""The trace (export/tables.py): .csv (a header, then rows, floats as repr reads them back) or .npz (one array a column) or .parquet."""
DEFAULT_PROBE_RADIUS_MM = 10.0
"""The sphere's radius [mm] where neither --probe-radius-mm nor the scene gives one (a fingertip; larger than the
built-in stroke's 8 mm press: a sphere pressed deeper than its radius pokes between the vertices)."""
BUILTIN_STROKE_S = 3.9
"""The built-in stroke's duration [s]: 8 mm down, 60 mm across and 10 mm up at 20 mm/s."""
MAX_PATH_STEPS = 10_000_000
"""Steps a path may take at dt (about 3 hours at 1 kHz); beyond, its times or dt are a mistake."""
MAX_PATH_ROWS = 1_000_000
"""Rows a path file may hold (17 minutes of a 1 kHz haptic device's log; the path is interpolated between them)."""
MAX_PATH_BYTES = 64 * 1024**2
"""Bytes a path file may have (a million rows of four numbers take about 40 MB)."""


COUPLING_FLAGS = (
    ("--coupling-stiffness-n-per-mm", "--coupling-stiffness-N-per-mm", "coupling_k", "> 0", None, "K", "coupling spring k_c [N/mm]"),
    ("--coupling-damping-ns-per-m", "--coupling-damping-Ns-per-m", "coupling_b", ">= 0", 0.0, "B", "coupling damper b_c [N s/m] (default 0)"),
    ("--device-damping-ns-per-m", "--device-damping-Ns-per-m", "device_b", ">= 0", None, "B",
     "the haptic device's physical damping b [N s/m]; the coupling must meet b > k_c T / 2 + |b_c| (T = dt)"),
)
"""The virtual coupling's flags, lower case as every flag: (flag, its old spelling, still taken but not listed,
dest, rule, default, metavar, help)."""


def add_parser(sub) -> None:
    p = add_command(
        sub, "trace", "move the probe along a path (a CSV or the built-in stroke) and write the force trace",
        "Replay a path of the probe sphere's centre over a scene or mesh, the local region following the contact (or "
        "the global model), and write the force at each reported step: " + ", ".join(COLUMNS) + ".")
    p.add_argument("scene", nargs="?", default=None, type=path_arg, metavar="SCENE_OR_MESH", help="scene (.toml), scene name or mesh file; default: the stomach scene")
    p.add_argument("--path", dest="path_csv", default=None, type=path_arg, metavar="CSV", help="the sphere centre's path: a header t_s,x_mm,y_mm,z_mm, then rows with t_s increasing (default: the built-in stroke on the scene)")
    p.add_argument("--rings", type=rings_arg(("auto", "global")), default=None, metavar="{N,auto,global}", help="rings of the local region, auto (sized to --tol-mm by an adaptive press at the top, as palpate's), or the global model, anchored (default: the scene's)")
    p.add_argument("--tol-mm", type=number_arg("> 0"), default=None, metavar="MM", help="--rings auto: the displacement tolerance [mm] (default: the scene's, else 0.1)")
    add_integrator_arg(p)
    add_law_arg(p, "stroke")
    add_probe_radius_arg(p)
    p.add_argument("--dt-ms", type=number_arg("> 0"), default=1.0, metavar="MS", help="step [ms] at which the path is sampled (default 1: haptic rate)")
    p.add_argument("--report-every", type=count_arg, default=1, metavar="N", help="a trace row every Nth step, and the last (default 1)")
    p.add_argument("--scale-mm", type=number_arg("> 0"), default=None, metavar="MM", help="millimetres per mesh file unit, for a mesh file (default: guessed from its size)")
    p.add_argument("--out", default=None, type=path_arg, metavar="PATH", help="the trace: .csv (a header line, then one row per reported step), .npz or .parquet")
    p.add_argument("--png", default=None, type=path_arg, metavar="PATH", help="a plot of the force against time")
    p.add_argument("--usd", default=None, type=path_arg, metavar="PATH", help="record the stroke to a USD stage (.usda, .usdc, .usd): the organ, the probe, the moving region")
    p.add_argument("--usd-every", type=count_arg, default=10, metavar="N", help="a USD frame every Nth step (default 10)")
    p.add_argument("--json", default=None, type=path_arg, metavar="PATH", help="a JSON summary: path, model, peak force, relocations")
    c = p.add_argument_group("virtual coupling (a haptic device: the path is the device's, the tool follows it)")
    for flag, old, dest, rule, default, metavar, text in COUPLING_FLAGS:
        c.add_argument(flag, dest=dest, type=number_arg(rule), default=default, metavar=metavar, help=text)
        c.add_argument(old, dest=dest, type=number_arg(rule), default=default, help=argparse.SUPPRESS)
    add_volume_arg(p)
    add_tissue_args(p)
    p.set_defaults(func=cmd_trace)


def read_path(path) -> tuple[np.ndarray, np.ndarray]:
    """(t [s], centre [m] [n, 3]) of a path file: the header t_s,x_mm,y_mm,z_mm, then at least two
    rows of finite numbers with t_s strictly increasing. InputError naming the file, line and value."""
    from ..mesh.io import read_bounded

    p = Path(path)
    data = read_bounded(p, str(p), what="path file", limit=MAX_PATH_BYTES)  # a regular file, bounded: no FIFO, no /dev/zero
    if data.count(b"\n") > MAX_PATH_ROWS + 1:
        raise InputError(f"{p}: more than {MAX_PATH_ROWS:,} rows (MAX_PATH_ROWS); thin the path (it is interpolated at each step)")
    try:
        lines = data.decode("utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise InputError(f"{p}: not a text file (byte {exc.start} is not UTF-8)") from None
    rows = [(k + 1, line) for k, line in enumerate(lines) if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise InputError(f"{p}: empty path file (expected a header {','.join(PATH_COLUMNS)} and rows)")
    header = tuple(w.strip() for w in rows[0][1].split(","))
    if header != PATH_COLUMNS:
        raise InputError(f"{p}: line {rows[0][0]}: the header must be {','.join(PATH_COLUMNS)}, got {rows[0][1].strip()!r}")
    values = []
    for line_no, line in rows[1:]:
        words = [w.strip() for w in line.split(",")]
        if len(words) != len(PATH_COLUMNS):
            raise InputError(f"{p}: line {line_no}: {len(words)} values, expected {len(PATH_COLUMNS)} ({','.join(PATH_COLUMNS)})")
        try:
            row = [float(w) for w in words]
        except ValueError:
            bad = next(w for w in words if not _is_float(w))
            raise InputError(f"{p}: line {line_no}: not a number: {bad!r}") from None
        if not all(math.isfinite(v) for v in row):
            col = PATH_COLUMNS[next(i for i, v in enumerate(row) if not math.isfinite(v))]
            raise InputError(f"{p}: line {line_no}: {col} must be finite, got {line.strip()!r}")
        values.append((line_no, row))
    if len(values) < 2:
        raise InputError(f"{p}: a path needs at least 2 rows, got {len(values)}")
    data = np.array([row for _, row in values], dtype=np.float64)
    far = np.flatnonzero(np.abs(data[:, 1:]).max(axis=1) > MAX_COORDINATE_M * 1e3)
    if len(far):
        raise InputError(f"{p}: line {values[far[0]][0]}: the point {data[far[0], 1:].tolist()} mm is more than "
                         f"{MAX_COORDINATE_M * 1e3:g} mm from the origin, beyond any mesh the simulator holds")
    back = np.flatnonzero(np.diff(data[:, 0]) <= 0)
    if len(back):
        i = back[0] + 1
        raise InputError(f"{p}: line {values[i][0]}: t_s must increase, got {float(data[i, 0])!r} after {float(data[i - 1, 0])!r}")
    return data[:, 0], data[:, 1:] * 1e-3


def _is_float(word) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def resample(t: np.ndarray, centre: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The path at each step: times t0, t0 + dt, ... up to the path's end (its last time too, where
    dt does not divide the duration), the centre linearly interpolated there."""
    duration = float(t[-1] - t[0])
    check_steps(duration, dt, "the path")
    n = duration / dt
    k = np.arange(int(math.floor(n + 1e-9)) + 1)
    times = t[0] + k * dt
    if times[-1] < t[-1] - 1e-9 * max(1.0, abs(t[-1])):
        times = np.append(times, t[-1])
    centres = np.column_stack([np.interp(times, t, centre[:, a]) for a in range(3)])
    return times, centres


def check_steps(duration: float, dt: float, what: str) -> None:
    """InputError for a path of `duration` [s] that takes more than MAX_PATH_STEPS steps of dt, or
    less than one."""
    n = duration / dt
    if n > MAX_PATH_STEPS:
        raise InputError(f"{what} lasts {duration:g} s: {n:.3g} steps of {dt * 1e3:g} ms, more than {MAX_PATH_STEPS:,}")
    if n < 1:
        raise InputError(f"{what} lasts {duration:g} s, less than one step of --dt-ms {dt * 1e3:g}")


def check_path_clear(stroke, times, centres) -> None:
    """InputError where the path (straight between its steps) moves the sphere its radius or more in one step
    through the organ at rest: it would pass through vertices (as a sweep's press may not), and read ~0 N.
    The stroke itself refuses a path that starts inside the organ or moves that far while touching it."""
    step = np.linalg.norm(np.diff(centres, axis=0), axis=1)
    far = np.flatnonzero(step >= stroke.radius)
    if not len(far):
        return
    n = int(math.ceil(2.0 * step[far].max() / stroke.radius)) + 1  # a sample every half radius or closer
    f = np.linspace(0.0, 1.0, n)[None, :, None]
    samples = centres[far, None, :] + f * (centres[far + 1] - centres[far])[:, None, :]
    inside = stroke.clearance(samples.reshape(-1, 3)).reshape(len(far), n).min(axis=1) < stroke.radius - stroke.guard
    if inside.any():
        k = int(far[np.argmax(inside)])
        raise InputError(f"at t = {times[k + 1]:.4g} s the path moves the sphere {step[k] * 1e3:.3g} mm in one step of "
                         f"{(times[k + 1] - times[k]) * 1e3:.3g} ms through the organ, not less than its radius "
                         f"{stroke.radius * 1e3:g} mm: it would pass through vertices; slow the path or use a smaller --dt-ms")


def cmd_trace(args) -> int:
    """Replay the path, write the trace, the plot, the stage and the summary."""
    from ..export.writers import check_output

    for flag, value, kind in (("--out", args.out, "table"), ("--png", args.png, "image"), ("--usd", args.usd, "stage"),
                              ("--json", args.json, "record")):
        if value:
            check_output(value, kind, flag)
    given = read_path(args.path_csv) if args.path_csv else None  # a bad path fails before any model is built
    dt = args.dt_ms * 1e-3
    coupling = make_coupling(args, dt)
    quiet_warp()
    device = get_device(args.device)
    scene, mesh, given = _scene(args, dt, given)
    stroke = _make_stroke(args, scene, mesh, dt, device)
    t, centre = given if given is not None else _builtin_path(stroke.mesh, stroke.radius, dt)
    times, centres = resample(t, centre, dt)
    check_path_clear(stroke, times, centres)
    src = args.path_csv or "the built-in stroke"
    print(f"path: {src}, {times[-1] - times[0]:.3g} s in {len(times)} steps of {dt * 1e3:g} ms")
    if coupling is not None:
        print(f"coupling: k_c {coupling.stiffness * 1e-3:g} N/mm, b_c {coupling.damping:g} N s/m, device damping "
              f"{coupling.device_damping:g} N s/m (passivity margin {coupling.device_damping - coupling.stiffness * dt / 2 - coupling.damping:.3g} N s/m)")
    columns, step_us = run_trace(args, stroke, times, centres, coupling)
    print(f"step: p50 {step_us['p50_us']:.1f} us, p99 {step_us['p99_us']:.1f} us, max {step_us['max_us']:.1f} us over "
          f"{step_us['steps']} steps after the first (wall clock, on {device}; the region's moves included)")
    _finish(args, scene, mesh, stroke, columns, src, step_us)
    return 0


def make_coupling(args, dt):
    """The VirtualCoupling the flags ask for (None without --coupling-stiffness-n-per-mm); InputError
    for a device damping missing or too small for it."""
    if args.coupling_k is None:
        if args.device_b is not None or args.coupling_b:
            raise InputError("--coupling-damping-ns-per-m and --device-damping-ns-per-m need --coupling-stiffness-n-per-mm")
        return None
    if args.device_b is None:
        raise InputError("--coupling-stiffness-n-per-mm needs --device-damping-ns-per-m: the haptic device's damping b, "
                         "which the passivity condition b > k_c T / 2 + |b_c| is checked with")
    from ..protocol.coupling import VirtualCoupling

    try:
        return VirtualCoupling(args.coupling_k * 1e3, args.coupling_b, dt, args.device_b)
    except ValueError as exc:
        raise InputError(f"--coupling-stiffness-n-per-mm {args.coupling_k:g}: {exc}") from None


def _scene(args, dt, given):
    """(The scene (with the tissue flags), its mesh, the path): with --volume auto or --wall tets (or the scene's
    keys), the mesh made tets finest along the path (its contacts with the surface at rest; the built-in
    stroke's path is then made on the surface, before the tets)."""
    from .volume_arg import on_tets, path_contacts, tets_for

    scene0, mesh = load_scene_and_mesh(args)
    scene = scene_with_tissue_args(args, scene0, mesh)
    kind = tets_for(args, scene, mesh)
    if kind is None:
        return scene, mesh, given
    radius = _probe_radius(args, scene)
    given = given if given is not None else _builtin_path(mesh, radius, dt)
    contacts, depth = path_contacts(mesh, given[1], radius)
    scene, mesh = on_tets(args, scene0, kind, scene, mesh, contacts, radius, depth)
    return scene, mesh, given


def _make_stroke(args, scene, mesh, dt, device):
    """The path-driven probe (protocol.stroke.ProbeStroke) on the scene, as the flags ask."""
    from ..protocol.stroke import ProbeStroke

    rings = scene.rings if args.rings is None else args.rings
    check_ring_count(rings, mesh.vertex_count, "--rings" if args.rings is not None else "the scene's [region] rings")
    scene = check_law(scene, mesh, args.integrator, "stroke")
    radius = _probe_radius(args, scene)
    scales = scene.lesion.model_scales(mesh, None, scene.law) if scene.lesion is not None else {}
    tol = auto_tol(args, rings, scene)
    if tol is not None:
        rings = _auto_rings(args, scene, mesh, tol, radius, dt, scales)
    try:
        return ProbeStroke(mesh, scene.tissue, probe_radius=radius, rings=rings, integrator=args.integrator, dt=dt,
                           device=device, fixed_below=scene.fixed_below, law=scene.law, **scales)
    except ValueError as exc:  # a parameter the stroke rejects (an InputError passes through unchanged)
        raise InputError(str(exc)) from exc


def _auto_rings(args, scene, mesh, tol, radius, dt, scales) -> int:
    """--rings auto: the rings an adaptive region grows to under the scene's press at the top of the organ
    (batch.sweep_auto.size_regions, as `almsdm palpate --rings auto` sizes it), said in one line."""
    from ..batch.sweep_auto import size_regions
    from ..region.contact import top_vertex
    from ..solvers.stepper import SimulationDiverged

    check_law(scene, mesh, args.integrator, "adaptive", "--rings auto (the region sized by an adaptive press): ")
    vertex, p = top_vertex(mesh), scene.press
    try:
        rings = int(size_regions(mesh, scene.tissue, [vertex], tol, depth=p.depth, ramp=p.ramp, hold=p.hold,
                                 integrator=args.integrator, dt=dt, probe_radius=radius, fixed_below=scene.fixed_below,
                                 law=scene.law, **scales)[0])
    except (SimulationDiverged, ValueError) as exc:  # user-chosen parameters: one line, exit 2
        raise InputError(str(exc)) from exc
    print(f"auto rings: {rings_text(rings)}, sized to {tol * 1e3:g} mm by the scene's {p.depth * 1e3:g} mm press at vertex {vertex} "
          f"(the top), as almsdm palpate --rings auto sizes it")
    return rings


def _probe_radius(args, scene) -> float:
    """The sphere's radius [m]: --probe-radius-mm, else the scene's, else DEFAULT_PROBE_RADIUS_MM."""
    if args.probe_radius_mm is not None:
        if not args.probe_radius_mm > 0:
            raise InputError(f"--probe-radius-mm must be > 0 for a stroke (a rigid sphere slides), got {args.probe_radius_mm:g}")
        return args.probe_radius_mm * 1e-3
    return scene.probe_radius if scene.probe_radius > 0 else DEFAULT_PROBE_RADIUS_MM * 1e-3


def _builtin_path(mesh, radius, dt):
    """The built-in stroke of a sphere of `radius` [m] on `mesh` (protocol.stroke.builtin_stroke: touch down, press
    8 mm, slide 60 mm at 20 mm/s, lift), starting at rest at t = 0: (t [s], centre [m])."""
    from ..protocol.stroke import builtin_stroke

    check_steps(BUILTIN_STROKE_S, dt, "the built-in stroke")  # before its arrays are made
    try:
        path = builtin_stroke(mesh, radius, dt=dt)
    except ValueError as exc:
        raise InputError(f"the built-in stroke: {exc}") from exc
    return path.t - path.t[0], path.centre


def run_trace(args, stroke, times, centres, coupling) -> dict:
    """Step the stroke at every time of `times` with the probe at `centres` [m] (through the
    coupling where there is one); the trace's columns at every `--report-every`th step and the last."""
    from ..solvers.stepper import SimulationDiverged

    n, every = len(times), args.report_every
    count = (n - 1) // every + 1 + ((n - 1) % every > 0)  # every Nth step and the last
    out = np.zeros((count, 7))
    dev = np.zeros((count, 3))
    ints = np.zeros((count, 2), dtype=np.int64)
    recorder = _recorder(args, stroke)
    force = np.zeros(3)
    step_s = np.zeros(n)  # each step's wall time, the region's relocations included
    if coupling is not None:
        coupling.reset(centres[0])
    r = 0
    with recorder if recorder is not None else contextlib.nullcontext(), frozen_heap():
        for k in range(n):
            if coupling is None:
                tool = centres[k]
            else:  # the device at centres[k]; the tool moves through the coupling against the last force
                coupling.update(centres[k], force)
                tool = coupling.tool
            try:
                t0 = time.perf_counter()
                felt_now = stroke.step(tool)
                step_s[k] = time.perf_counter() - t0
                force = np.array(felt_now, dtype=np.float64)
            except (SimulationDiverged, ValueError) as exc:
                raise InputError(f"at t = {times[k]:.4g} s: {exc}") from exc
            if recorder is not None and (k % args.usd_every == 0 or k == n - 1):
                recorder.frame(k, probe_center=tool, force=force)
            if k % every == 0 or k == n - 1:
                felt = force if coupling is None else coupling.device_force
                out[r] = (times[k], *millimetres(tool), *felt)
                dev[r] = millimetres(centres[k])
                ints[r] = (stroke.region_vertices, stroke.relocations)
                r += 1
    columns = {c: out[:, i] for i, c in enumerate(COLUMNS[:7])}
    columns.update(region_vertices=ints[:, 0], relocations=ints[:, 1])
    if coupling is not None:
        columns.update({c: dev[:, i] for i, c in enumerate(DEVICE_COLUMNS)})
    return columns, step_percentiles(step_s[1:] if n > 1 else step_s)


@contextlib.contextmanager
def frozen_heap():
    """While the loop runs, the objects made before it (the modules, Warp's, the model) are left out of
    Python's garbage collection (gc.freeze): a collection of the oldest generation otherwise walks them
    all, a step of milliseconds in a loop of microseconds. The loop's own garbage is still collected."""
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


STEP_PERCENTILES = (("p50", 50.0), ("p99", 99.0), ("max", 100.0))
"""The step-time figures a trace reports [us]: median, 99th percentile, worst."""


def step_percentiles(step_s) -> dict:
    """{"p50_us", "p99_us", "max_us", "steps"} of the step wall times `step_s` [s] (numpy's linear percentile)."""
    us = np.asarray(step_s, dtype=np.float64) * 1e6
    return {**{f"{name}_us": float(np.percentile(us, q)) for name, q in STEP_PERCENTILES}, "steps": int(len(us))}


def _recorder(args, stroke):
    """The USD recorder of --usd (time code k: the state after step k), else None."""
    if not args.usd:
        return None
    from ..export.usd import UsdRecorder

    return UsdRecorder(args.usd, stroke, every=args.usd_every, probe_radius=stroke.radius)


def _finish(args, scene, mesh, stroke, columns, src, step_us) -> None:
    """Print the summary; write the trace, the plot and the JSON."""
    f = np.column_stack([columns[f"force_{a}_N"] for a in "xyz"])
    mag = np.linalg.norm(f, axis=1)
    i = int(np.argmax(mag))
    moves = int(columns["relocations"][-1])
    print(f"force: peak {mag[i]:.3f} N at t = {columns['t_s'][i]:.3f} s; the region moved {moves} times; "
          f"{len(mag)} rows")
    if args.usd:
        print(f"wrote {args.usd}")
    if args.out:
        TRACE_TABLE.write(args.out, columns)
        print(f"wrote {args.out} ({len(mag)} rows)")
    if args.png:
        from ..export.trace_png import plot_trace

        plot_trace(columns, args.png, title=f"{mesh.name}, {rings_text(stroke.rings) if stroke.region is not None else 'global model'}")
        print(f"wrote {args.png}")
    if args.json:
        from ..export.writers import write_output
        from .args import finite, mesh_json

        record = {
            "scene": str(scene.path) if scene.path else None,
            "mesh": mesh_json(mesh),
            "path": str(src),
            "model": {"rings": stroke.rings, "integrator": args.integrator, "law": stroke.model.law, "dt_s": args.dt_ms * 1e-3,
                      "probe_radius_mm": stroke.radius * 1e3},
            "coupling": None if args.coupling_k is None else {
                "stiffness_N_per_mm": args.coupling_k, "damping_Ns_per_m": args.coupling_b, "device_damping_Ns_per_m": args.device_b},
            "rows": len(mag),
            "peak_force_N": finite(mag[i]),
            "peak_force_t_s": finite(columns["t_s"][i]),
            "relocations": moves,
            "step_us": step_us,
        }
        write_output(args.json, record, "record")
        print(f"wrote {args.json}")
