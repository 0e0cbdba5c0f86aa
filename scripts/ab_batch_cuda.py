"""The default batch kernel of another checkout against this one's, timed alternately (A/B).

    python scripts/ab_batch_cuda.py OLD_CHECKOUT [--device cuda:0] [--batch 100000] [--rings 4]
        [--alternations 5] [--repeats 3] [--mesh scenes/stomach.obj] [--json out.json]
        [--probe-radius-mm 5] [--youngs-modulus-kpa 5] [--scene stomach] [--scene-rings K] [--threads T]

OLD_CHECKOUT is the root of another source checkout of this project (e.g. made by
`git worktree add /tmp/old <commit>`). Each alternation runs one subprocess on the old checkout,
then one on this one (each imports its own almsdm_warp); a subprocess builds B regions of
`rings` rings on the stomach scene with the device's default kernel, runs the usual press once
to compile and load, then times `repeats` presses (10 mm over 0.1 s, held 0.2 s, settled 1 s,
dt from the mesh's critical step, the same for both), each between device synchronizations, and
reports the median region-steps/s. The summary gives each side's median over the alternations
and their ratio. A benchmark, not a test; on the CPU, `--device cpu --batch 200` runs it small.

Then, in the same run, the sphere and the material on this checkout alone (the old one may have
neither): a probe of `--probe-radius-mm` (default 5; 0 skips this part) on a membrane of Young's
modulus `--youngs-modulus-kpa` (default 5; thickness 3 mm on a 1 kPa/mm foundation, damping ratio
0.5; 0: the scene's per-spring constants) over its own supports-free regions, `alternations` runs
of it, its dt from that model's critical step; the summary gives its median and its ratio to
this checkout's paper-probe figure.

Then the shipped scene `--scene` (default stomach; "none" skips it) as it is, on this checkout alone:
its mesh, tissue, probe, supports, rings and press, its dt the scene's model's critical step as
`almsdm bench` takes it, contacts on the surface vertices its support leaves free; with the
median and largest region (vertices, springs) and the fast kernel's plan, so that the new tissue
model's figure stands beside the paper probe's in one run. `--scene-rings` overrides the scene's
ring count (to compare two counts); `--threads` sets the fast kernel's threads a block for the
sphere and scene runs (default: the batch's plan), `--max-registers` its register cap a thread
(default: the kernel's MAX_REGISTERS, SPHERE_MAX_REGISTERS with a sphere); `--ab-all` runs the sphere and scene cases on
the old checkout too, alternated with this one's (an A/B of the sphere's kernel).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESS = (0.01, 0.1, 0.2, 1.0)  # depth [m], ramp, hold, settle [s]
MEMBRANE = dict(thickness=0.003, foundation=1e6, damping_ratio=0.5)
"""The material of the sphere case beside Young's modulus: 3 mm thick, on a 1 kPa/mm foundation [SI]."""


def tissue_of(youngs_modulus_kpa: float):
    """The material of the sphere case (None: the scene's per-spring constants)."""
    if not youngs_modulus_kpa:
        return None
    from almsdm_warp.tissue.material import Material

    return Material(youngs_modulus=youngs_modulus_kpa * 1e3, **MEMBRANE)


def worker(args) -> None:
    """In the subprocess: time the press with the checkout on sys.path; print one JSON line."""
    import time

    import numpy as np
    import warp as wp

    import almsdm_warp

    here = Path(almsdm_warp.__file__).resolve()
    if Path(args.worker).resolve() not in here.parents:
        raise SystemExit(f"almsdm_warp imported from {here}, not from the checkout {args.worker}")
    wp.config.quiet = True
    wp.init()
    from almsdm_warp import load_mesh
    from almsdm_warp.batch.batch_palpation import BatchPalpation

    press, surface, options = PRESS, None, {}
    if args.worker_scene:  # only this checkout's run is asked for it
        scene, mesh = scene_model(args.worker_scene, args.scene_rings)
        surface = free_surface(mesh, scene.fixed_below)
        press = (scene.press.depth, scene.press.ramp, scene.press.hold, scene.press.settle)
        options = dict(tissue=scene.tissue, rings=scene.rings, probe_radius=scene.probe_radius, fixed_below=scene.fixed_below)
    else:
        mesh = load_mesh(args.mesh)
        options["rings"] = args.rings
        if args.probe_radius_mm:  # only this checkout's run is asked for it
            options.update(tissue=tissue_of(args.youngs_modulus_kpa), probe_radius=args.probe_radius_mm * 1e-3)
    if surface is None:
        surface = mesh.surface_vertices
    if args.threads and (args.worker_scene or args.probe_radius_mm):
        options["threads"] = args.threads
    if args.max_registers and (args.worker_scene or args.probe_radius_mm):
        import almsdm_warp.kernels.explicit.batch_fast as bkf

        bkf.MAX_REGISTERS = bkf.SPHERE_MAX_REGISTERS = args.max_registers  # read when the kernel is made: this process's only
    surface = np.random.default_rng(0).permutation(surface)
    vertices = np.resize(surface, args.batch).astype(np.int64)
    bp = BatchPalpation(mesh, dt=args.dt, device=args.device, **options).touch(vertices)
    bp.press(*press)  # compile and load
    times = []
    for _ in range(args.repeats):
        wp.synchronize_device(bp.device)
        t0 = time.perf_counter()
        bp.start_press(*press)
        wp.synchronize_device(bp.device)
        times.append(time.perf_counter() - t0)
    res = bp.finish_press()
    vertices_per_region = np.asarray(getattr(bp, "region_vertex_counts", [0]))
    springs_per_region = bp.regions.spring_count.numpy() if hasattr(bp.regions, "spring_count") else np.zeros(1, int)
    t = statistics.median(times)
    row = {
        "checkout": str(Path(args.worker).resolve()),
        "kernel": getattr(bp, "kernel", None),
        "batch": args.batch,
        "steps": bp.total_steps,
        "press_s_median": t,
        "region_steps_per_s": args.batch * bp.total_steps / t,
        "peak_force_N_median": float(np.median(res.peak_force)),
        "rings": getattr(bp, "rings", None),
        "region_vertices": [float(np.median(vertices_per_region)), int(vertices_per_region.max())],
        "region_springs": [float(np.median(springs_per_region)), int(springs_per_region.max())],
        "fast_plan": list(getattr(bp, "fast_plan", None) or []),
    }
    print("AB_ROW " + json.dumps(row), flush=True)


def scene_model(name: str, rings=None):
    """(scene, mesh) of a shipped scene's name or a scene file's path; `rings` overrides its ring count."""
    from almsdm_warp.scene.loader import default_scene_path, load_scene

    scene = load_scene(name if name.endswith(".toml") else default_scene_path(name))
    if rings is None and not isinstance(scene.rings, int):
        raise SystemExit(f"scene {scene.name} sizes its region during each press (rings = {scene.rings!r}): a batch needs a ring count")
    if rings is not None:
        scene = dataclasses.replace(scene, rings=int(rings))
    return scene, scene.load_mesh()


def free_surface(mesh, fixed_below):
    """The surface vertices a press can move (those above the support's plane, if any)."""
    import numpy as np

    surface = np.asarray(mesh.surface_vertices)
    return surface if fixed_below is None else surface[mesh.vertices[surface, 2] >= fixed_below]


def sizes(row: dict) -> str:
    """A worker row's region sizes and plan in a few words."""
    v, s = row["region_vertices"], row["region_springs"]
    return (f"{row['rings']} rings, region vertices median {v[0]:g} max {v[1]}, springs median {s[0]:g} max {s[1]}, "
            f"kernel {row['kernel']} plan {row['fast_plan']}")


def run_side(checkout: Path, args, dt: float, sphere: bool = False, scene: str | None = None) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [
        sys.executable, str(Path(__file__).resolve()), str(checkout), "--worker", str(checkout), "--device", args.device,
        "--batch", str(args.batch), "--rings", str(args.rings), "--repeats", str(args.repeats), "--mesh", str(args.mesh),
        "--dt", repr(dt),
    ]
    cmd += ["--probe-radius-mm", repr(args.probe_radius_mm) if sphere else "0", "--youngs-modulus-kpa", repr(args.youngs_modulus_kpa)]
    if scene:
        cmd += ["--worker-scene", scene]
        if args.scene_rings is not None:
            cmd += ["--scene-rings", str(args.scene_rings)]
    if args.threads:
        cmd += ["--threads", str(args.threads)]
    if args.max_registers:
        cmd += ["--max-registers", str(args.max_registers)]
    out = subprocess.run(cmd, cwd=checkout, env=env, capture_output=True, text=True)
    rows = [json.loads(line[len("AB_ROW "):]) for line in out.stdout.splitlines() if line.startswith("AB_ROW ")]
    if out.returncode != 0 or not rows:
        raise SystemExit(f"the run on {checkout} failed (exit {out.returncode}):\n{out.stdout[-2000:]}\n{out.stderr[-4000:]}")
    return rows[0]


def alternate(args, old: Path, dt: float, **side) -> dict:
    """`alternations` runs of one case on this checkout (B), and on the old one (A) first with --ab-all;
    prints a row each and returns {"A": rows, "B": rows}."""
    rows = {"A": [], "B": []}
    for i in range(args.alternations):
        if args.ab_all:
            rows["A"].append(run_side(old, args, dt, **side))
        rows["B"].append(run_side(ROOT, args, dt, **side))
        a = f"{rows['A'][-1]['region_steps_per_s']:.4e}" if args.ab_all else ""
        ratio = f"{rows['B'][-1]['region_steps_per_s'] / rows['A'][-1]['region_steps_per_s']:.4f}" if args.ab_all else ""
        print(f"| {i + 1} | {a} | {rows['B'][-1]['region_steps_per_s']:.4e} | {ratio} |", flush=True)
    return rows


def summary(name: str, rows: dict, med: dict) -> None:
    """Print a case's medians (B, and B / A with --ab-all), its ratio to B's paper probe and its sizes; adds B's median to `med`."""
    b = med[f"B_{name}"] = statistics.median(r["region_steps_per_s"] for r in rows["B"])
    ab = ""
    if rows["A"]:
        a = med[f"A_{name}"] = statistics.median(r["region_steps_per_s"] for r in rows["A"])
        ab = f"A {a:.4e}, B / A {b / a:.4f}; "
    print(f"median region-steps/s: B {name} {b:.4e} ({rows['B'][0]['kernel']}), {ab}{b / med['B']:.4f} x B's paper probe; "
          f"median peak force {rows['B'][0]['peak_force_N_median']:.6f} N")
    print(f"{name}: {sizes(rows['B'][0])}", flush=True)


def measure_sphere(args, old: Path, med: dict) -> dict:
    """The sphere case (`--probe-radius-mm` on a membrane of `--youngs-modulus-kpa`) on the stomach mesh."""
    from almsdm_warp import load_mesh
    from almsdm_warp.batch.sweep_plan import auto_dt
    from almsdm_warp.sim.model import Model

    dt = args.dt if args.dt is not None else auto_dt(Model(load_mesh(args.mesh), tissue_of(args.youngs_modulus_kpa), "cpu"))
    print(f"with a {args.probe_radius_mm:g} mm sphere, E {args.youngs_modulus_kpa:g} kPa, dt {dt * 1e3:g} ms:", flush=True)
    rows = alternate(args, old, dt, sphere=True)
    summary("sphere", rows, med)
    return {"dt_sphere": dt, "runs_sphere": rows}


def measure_scene(args, old: Path, scene, med: dict) -> dict:
    """The shipped scene as it is: its mesh, tissue, probe, supports, rings and press."""
    from almsdm_warp.batch.sweep_plan import auto_dt
    from almsdm_warp.sim.model import Model

    mesh = scene.load_mesh()
    dt = args.dt if args.dt is not None else auto_dt(Model(mesh, scene.tissue, "cpu", fixed_below=scene.fixed_below))
    print(f"the {scene.summary()}; probe R {scene.probe_radius * 1e3:g} mm, dt {dt * 1e3:g} ms:", flush=True)
    rows = alternate(args, old, dt, scene=str(scene.path))
    summary("scene", rows, med)
    return {"scene": str(scene.path), "dt_scene": dt, "runs_scene": rows}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path, help="root of the other checkout (A)")
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--batch", type=int, default=100_000)
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--alternations", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mesh", type=Path, default=ROOT / "scenes" / "stomach.obj")
    ap.add_argument("--dt", type=float, default=None, help="step [s] (default: the mesh's critical step, as a sweep takes it)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--probe-radius-mm", type=float, default=5.0, help="the sphere case's probe [mm] on this checkout (0: none)")
    ap.add_argument("--youngs-modulus-kpa", type=float, default=5.0, help="the sphere case's material [kPa] (0: per-spring constants)")
    ap.add_argument("--scene", default="stomach", help="a shipped scene's name or a scene file, measured as it is on this checkout (none: skip)")
    ap.add_argument("--scene-rings", type=int, default=None, help="rings for the scene run (default: the scene's [region] rings)")
    ap.add_argument("--threads", type=int, default=None, help="the fast kernel's threads a block in the sphere and scene runs (default: the batch's plan)")
    ap.add_argument("--max-registers", type=int, default=None, help="the fast kernel's register cap a thread in the sphere and scene runs (default: MAX_REGISTERS)")
    ap.add_argument("--ab-all", action="store_true", help="run the sphere and scene cases on the old checkout too, alternated (it must hold them)")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--worker-scene", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    args.mesh = args.mesh.resolve()
    if args.worker:
        worker(args)
        return
    old = args.old.resolve()
    if not (old / "almsdm_warp" / "__init__.py").exists():
        raise SystemExit(f"{old} is not a checkout of this project (no almsdm_warp/__init__.py)")
    sys.path.insert(0, str(ROOT))
    from almsdm_warp import load_mesh
    from almsdm_warp.batch.sweep_plan import auto_dt
    from almsdm_warp.sim.model import Model
    from almsdm_warp.warp_init import init_warp

    init_warp()
    dt = args.dt if args.dt is not None else auto_dt(Model(load_mesh(args.mesh), None, "cpu"))
    scene = None if args.scene.lower() == "none" else scene_model(args.scene, args.scene_rings)[0]
    print(f"A: {old}\nB: {ROOT}\n{args.mesh.name}, {args.rings} rings, B = {args.batch}, dt {dt * 1e3:g} ms, device {args.device}", flush=True)
    print("| alternation | A region-steps/s | B region-steps/s | B / A |")
    print("|---|---|---|---|")
    rows = {"A": [], "B": []}
    for i in range(args.alternations):
        a = run_side(old, args, dt)
        b = run_side(ROOT, args, dt)
        rows["A"].append(a)
        rows["B"].append(b)
        print(f"| {i + 1} | {a['region_steps_per_s']:.4e} | {b['region_steps_per_s']:.4e} | {b['region_steps_per_s'] / a['region_steps_per_s']:.4f} |", flush=True)
    med = {k: statistics.median(r["region_steps_per_s"] for r in v) for k, v in rows.items()}
    print(
        f"median region-steps/s: A {med['A']:.4e} ({rows['A'][0]['kernel']}), B {med['B']:.4e} ({rows['B'][0]['kernel']}); "
        f"B / A {med['B'] / med['A']:.4f}; median peak force A {rows['A'][0]['peak_force_N_median']:.6f} N, B {rows['B'][0]['peak_force_N_median']:.6f} N"
    )
    print(f"paper probe: {sizes(rows['B'][0])}")
    out = {"dt": dt, "median": med, "runs": rows}
    if args.probe_radius_mm:
        out.update(measure_sphere(args, old, med))
    if scene is not None:
        out.update(measure_scene(args, old, scene, med))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
