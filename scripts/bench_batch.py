"""Batched palpation throughput: region-steps/s against B and threads, the 10,000-point sweep, and
step time at fixed rings as the mesh grows (subdivided spheres).

    python scripts/bench_batch.py [MESH] --device cuda:0 [--batch 1000 10000 100000] [--threads 32 64]
        [--sweep-points 10000] [--spheres 3 4 5 6 7 8] [--json out.json]

A benchmark, not a test: every figure is a median after a warm-up launch (compilation excluded),
timed between device synchronizations.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def default_mesh():
    shared = ROOT.parent / "shared" / "meshes" / "gca_stomach_1002v.obj"
    return shared if shared.exists() else ROOT / "scenes" / "stomach.obj"


def sweep_time(mesh, points, device, rings=4, repeats=3, dt=1e-3):
    """The sweep's presses (10 mm, ramp 0.1 s, hold 0.2 s, settle 1 s, steps of dt): region
    build, all steps, read-back; points chosen before the clock starts."""
    import warp as wp

    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sampling import sample_points

    t0 = time.perf_counter()
    _, vertices = sample_points(mesh, points)
    sample_s = time.perf_counter() - t0
    bp = BatchPalpation(mesh, rings=rings, device=device, dt=dt)
    bp.touch(vertices[:64]).press(0.01, 0.1, 0.2, 1.0)  # compile and load
    times = []
    for _ in range(repeats):
        wp.synchronize_device(bp.device)
        t0 = time.perf_counter()
        bp.touch(vertices)
        res = bp.press(0.01, 0.1, 0.2, 1.0)
        times.append(time.perf_counter() - t0)
    steps = bp.total_steps
    return {
        "points": points,
        "steps": steps,
        "sweep_s_median": statistics.median(times),
        "sweep_s_best": min(times),
        "sampling_s": sample_s,
        "region_steps_per_s": points * steps / statistics.median(times),
        "peak_force_N_median": float(np.median(res.peak_force)),
        "recovery_error_mm_max": float(np.max(res.recovery_error) * 1e3),
        "threads": bp.threads,
        "kernel": bp.kernel,
    }


def sphere(subdivisions, stomach_mean_mass):
    """An icosphere of radius 50 mm, tissue thickness set so its vertices weigh what the stomach's do
    (so the explicit step stays stable at 1 ms on every size)."""
    import trimesh

    from almsdm_warp.mesh.tissue_mesh import TissueMesh
    from almsdm_warp.tissue.params import TissueParams

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=50.0)
    mesh = TissueMesh.from_arrays(np.asarray(s.vertices), np.asarray(s.faces))
    t = TissueParams()
    mean = mesh.vertex_masses(t.density, t.thickness).mean()
    return mesh, TissueParams(thickness=t.thickness * stomach_mean_mass / mean)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", type=Path, default=None)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--batch", type=int, nargs="*", default=[1000, 10000, 100000])
    ap.add_argument("--threads", type=int, nargs="*", default=[None])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--sweep-points", type=int, default=10000)
    ap.add_argument("--spheres", type=int, nargs="*", default=[])
    ap.add_argument("--sphere-batch", type=int, default=10000)
    ap.add_argument("--dt-ms", type=float, default=None, help="default: 1 ms, or less where the mesh's critical step asks")
    ap.add_argument("--kernels", nargs="*", default=[None], help="fast, exact (default: the device's default)")
    ap.add_argument("--implicit-batch", type=int, nargs="*", default=[], help="batch sizes for the implicit integrator")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    from almsdm_warp import load_mesh
    from almsdm_warp.evaluation.bench import measure_batch
    from almsdm_warp.tissue.params import TissueParams
    from almsdm_warp.warp_init import init_warp

    init_warp()
    mesh = load_mesh(args.mesh or default_mesh())
    from almsdm_warp.sim.model import Model
    from almsdm_warp.batch.sweep_plan import auto_dt

    dt = args.dt_ms * 1e-3 if args.dt_ms else auto_dt(Model(mesh, None, "cpu"))
    print(f"{mesh.summary()}; device {args.device}; {args.rings} rings; dt {dt * 1e3:g} ms")
    out = {"device": args.device, "mesh": str(mesh.path), "dt": dt, "batch": [], "sweep": None, "spheres": []}
    print("| B | kernel | threads | region vertices max | build ms | step us | region-steps/s | finite |")
    print("|---|---|---|---|---|---|---|---|")
    for b in args.batch:
        for kernel in args.kernels:
            for threads in args.threads:
                try:
                    row = measure_batch(mesh, args.rings, b, args.device, steps=args.steps, threads=threads, dt=dt, kernel=kernel)
                except ValueError as exc:  # a thread count too small for the regions
                    print(f"| {b} | {kernel} | {threads} | skipped: {exc} |")
                    continue
                out["batch"].append(row)
                print(
                    f"| {b} | {row['kernel']} | {row['threads']} | {row['region_vertices_max']} | {row['build_ms']:.1f} | "
                    f"{row['step_us_median']:.2f} | {row['region_steps_per_s']:.3e} | {row['finite']} |",
                    flush=True,
                )
    for b in args.implicit_batch:
        from almsdm_warp.batch.batch_palpation import BatchPalpation
        from almsdm_warp.evaluation.bench import spread_vertices

        bp = BatchPalpation(mesh, rings=args.rings, dt=1e-3, device=args.device, integrator="implicit").touch(spread_vertices(mesh, b))
        bp.press(0.01, 0.01, 0.0, 0.01)  # compile and load
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            res = bp.press(0.01, 0.05, 0.05, 0.1)  # 200 steps, the force read back at the end
            times.append(time.perf_counter() - t0)
        row = {"batch": b, "integrator": "implicit", "steps": bp.total_steps, "region_steps_per_s": b * bp.total_steps / statistics.median(times)}
        out.setdefault("implicit", []).append(row)
        print(f"implicit batch {b}: {row['region_steps_per_s']:.3e} region-steps/s ({bp.total_steps} steps, one launch a step; median peak force {np.median(res.peak_force):.3f} N)", flush=True)
    if args.sweep_points:
        row = sweep_time(mesh, args.sweep_points, args.device, args.rings, dt=dt)
        out["sweep"] = row
        print(f"sweep of {row['points']} points x {row['steps']} steps: {row['sweep_s_median']:.3f} s median, {row['sweep_s_best']:.3f} s best "
              f"({row['region_steps_per_s']:.3e} region-steps/s; point sampling {row['sampling_s']:.2f} s apart); median peak force "
              f"{row['peak_force_N_median']:.3f} N, max recovery error {row['recovery_error_mm_max']:.4f} mm", flush=True)
    if args.spheres:
        t = TissueParams()
        stomach_mass = mesh.vertex_masses(t.density, t.thickness).mean()
        print("| sphere vertices | single explicit step us (median) | batch region-steps/s |")
        print("|---|---|---|")
        from almsdm_warp.sim.model import Model
        from almsdm_warp.protocol.palpation import Palpation

        for k in args.spheres:
            s_mesh, tissue = sphere(k, stomach_mass)
            pal = Palpation(s_mesh, tissue, rings=args.rings, device=args.device)
            pal.touch(0)
            pal.set_probe(1, pal.rest_position() + pal.inward_normal() * 0.005)
            for _ in range(500):
                pal.step()
            blocks = []
            for _ in range(5):
                t0 = time.perf_counter()
                for _ in range(2000):
                    pal.step()
                blocks.append((time.perf_counter() - t0) / 2000 * 1e6)
            model = Model(s_mesh, tissue, args.device)
            row_b = measure_batch(s_mesh, args.rings, args.sphere_batch, args.device, steps=args.steps, model=model)
            row = {
                "vertices": s_mesh.vertex_count,
                "single_step_us_median": statistics.median(blocks),
                "batch_region_steps_per_s": row_b["region_steps_per_s"],
                "finite": row_b["finite"],
            }
            out["spheres"].append(row)
            print(f"| {row['vertices']} | {row['single_step_us_median']:.2f} | {row['batch_region_steps_per_s']:.3e} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
