"""`almsdm bench`: one palpation's step rate, a batch's region-steps/s and the global model's, in one run."""

from __future__ import annotations

from pathlib import Path

from ..checks import check_limit, check_ring_count, rings_text
from .args import add_command, count_arg, get_device, int_list, quiet_warp


def add_parser(sub) -> None:
    p = add_command(
        sub,
        "bench",
        "benchmark: one palpation (rings 1..4, both integrators), batches, the global model; JSON",
        "One-palpation steps/s (rings 1..4, explicit and implicit, the force read every step), batch region-steps/s "
        "for several batch sizes, the global model's steps/s, and newton's spring solver when installed.",
    )
    p.add_argument("mesh", nargs="?", default=None, metavar="MESH", help="mesh file or scene (default: the stomach scene)")
    p.add_argument("--json", default=None, metavar="PATH", help="write the results as JSON here")
    p.add_argument("--rings", type=count_arg, default=4, metavar="K", help="rings of the batch benchmark (default 4)")
    p.add_argument("--batch", type=int_list, default=None, metavar="B1,B2,...", help="batch sizes (default 16,64 on the CPU; 1000,10000,100000 on CUDA)")
    p.add_argument("--blocks", type=count_arg, default=10, metavar="N", help="timed blocks of 2000 steps per single-palpation case (default 10)")
    p.add_argument("--quick", action="store_true", help="fewer and shorter blocks (a smoke run)")
    p.set_defaults(func=cmd_bench)


def cmd_bench(args) -> int:
    from ..evaluation.bench import measure, measure_batch, measure_newton
    from ..export.writers import check_output, write_output
    from ..scene.loader import resolve_scene_or_mesh

    if args.json:
        check_output(args.json, "record", "--json")
    quiet_warp()
    device = get_device(args.device)
    scene = resolve_scene_or_mesh(args.mesh)
    mesh = scene.load_mesh()
    check_ring_count(args.rings, mesh.vertex_count, "--rings")
    sizes = args.batch or ([16, 64] if device.is_cpu else [1000, 10000, 100000])
    check_limit(max(sizes), "batch", "--batch")
    print(f"{mesh.summary()}; device {device.alias}")
    blocks, steps = (2, 200) if args.quick else (args.blocks, 2000)
    single = []
    print("single palpation (probe held 5 mm in, force read every step):")
    from ..solvers import INTEGRATORS

    for integrator in INTEGRATORS:
        for rings in sorted({1, 2, 3, 4, args.rings}):  # --rings: the batch's, also single for the ratio
            row = measure(mesh, rings, integrator, device.alias, blocks, steps)
            single.append({k: row[k] for k in ("rings", "integrator", "steps_per_s", "step_us_median")})
            print(f"  {rings_text(rings)} {integrator}: {row['step_us_median']:.2f} us/step, {row['steps_per_s']:,.0f} steps/s")
    glob = []
    for integrator in INTEGRATORS:
        row = measure(mesh, "global", integrator, device.alias, max(blocks // 5, 1), max(steps // 10, 20))
        glob.append({"integrator": integrator, "steps_per_s": row["steps_per_s"]})
        print(f"  global {integrator}: {row['step_us_median']:.1f} us/step, {row['steps_per_s']:,.0f} steps/s")
    from ..sim.model import Model
    from ..batch.sweep_plan import auto_dt

    dt = auto_dt(Model(mesh, scene.tissue, "cpu"))  # 1 ms unless the mesh's critical step is shorter
    batch = []
    for b in sizes:
        row = measure_batch(mesh, args.rings, b, device.alias, steps=(100 if device.is_cpu or args.quick else 1000), repeats=3, dt=dt)
        batch.append({"rings": row["rings"], "batch": b, "region_steps_per_s": row["region_steps_per_s"]})
        print(f"  batch {b} x {rings_text(args.rings)}: {row['region_steps_per_s']:,.0f} region-steps/s (kernel {row['kernel']}, {row['threads']} threads per block, dt {dt * 1e3:g} ms)")
    one = next(r for r in single if r["rings"] == args.rings and r["integrator"] == "explicit")["steps_per_s"]
    ratios = {
        "batch_best_over_single_explicit": max(r["region_steps_per_s"] for r in batch) / one,
        "single_explicit_over_global_explicit": one / glob[0]["steps_per_s"],
    }
    print("ratios: " + ", ".join(f"{k} {v:,.1f}" for k, v in ratios.items()))
    newton = measure_newton(mesh, device.alias)
    if "skipped" in newton:
        print(f"newton: {newton['skipped']}")
    else:
        print(f"newton: {newton['steps_per_s']:,.0f} steps/s (global, semi-implicit, springs alone: no anchors, no particle contact)")
    if args.json:
        write_output(
            args.json,
            {"device": device.alias, "mesh": str(Path(mesh.path)) if mesh.path else None, "single": single, "batch": batch, "global": glob, "ratios": ratios, "newton": newton},
            "record",
        )
        print(f"wrote {args.json}")
    return 0
