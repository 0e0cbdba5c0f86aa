"""The default batch kernel of another checkout against this one's, timed alternately (A/B).

    python scripts/ab_batch_cuda.py OLD_CHECKOUT [--device cuda:0] [--batch 100000] [--rings 4]
        [--alternations 5] [--repeats 3] [--mesh scenes/stomach.obj] [--json out.json]

OLD_CHECKOUT is the root of another source checkout of this project (e.g. made by
`git worktree add /tmp/old <commit>`). Each alternation runs one subprocess on the old checkout,
then one on this one (each imports its own almsdm_warp); a subprocess builds B regions of
`rings` rings on the stomach scene with the device's default kernel, runs the usual press once
to compile and load, then times `repeats` presses (10 mm over 0.1 s, held 0.2 s, settled 1 s,
dt from the mesh's critical step, the same for both), each between device synchronizations, and
reports the median region-steps/s. The summary gives each side's median over the alternations
and their ratio. A benchmark, not a test; on the CPU, `--device cpu --batch 200` runs it small.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESS = (0.01, 0.1, 0.2, 1.0)  # depth [m], ramp, hold, settle [s]


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

    mesh = load_mesh(args.mesh)
    surface = np.random.default_rng(0).permutation(mesh.surface_vertices)
    vertices = np.resize(surface, args.batch).astype(np.int64)
    bp = BatchPalpation(mesh, rings=args.rings, dt=args.dt, device=args.device).touch(vertices)
    bp.press(*PRESS)  # compile and load
    times = []
    for _ in range(args.repeats):
        wp.synchronize_device(bp.device)
        t0 = time.perf_counter()
        bp.start_press(*PRESS)
        wp.synchronize_device(bp.device)
        times.append(time.perf_counter() - t0)
    res = bp.finish_press()
    t = statistics.median(times)
    row = {
        "checkout": str(Path(args.worker).resolve()),
        "kernel": getattr(bp, "kernel", None),
        "batch": args.batch,
        "steps": bp.total_steps,
        "press_s_median": t,
        "region_steps_per_s": args.batch * bp.total_steps / t,
        "peak_force_N_median": float(np.median(res.peak_force)),
    }
    print("AB_ROW " + json.dumps(row), flush=True)


def run_side(checkout: Path, args, dt: float) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    cmd = [
        sys.executable, str(Path(__file__).resolve()), str(checkout), "--worker", str(checkout), "--device", args.device,
        "--batch", str(args.batch), "--rings", str(args.rings), "--repeats", str(args.repeats), "--mesh", str(args.mesh),
        "--dt", repr(dt),
    ]
    out = subprocess.run(cmd, cwd=checkout, env=env, capture_output=True, text=True)
    rows = [json.loads(line[len("AB_ROW "):]) for line in out.stdout.splitlines() if line.startswith("AB_ROW ")]
    if out.returncode != 0 or not rows:
        raise SystemExit(f"the run on {checkout} failed (exit {out.returncode}):\n{out.stdout[-2000:]}\n{out.stderr[-4000:]}")
    return rows[0]


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
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    args.mesh = args.mesh.resolve()
    if args.worker:
        worker(args)
        return
    old = args.old.resolve()
    if not (old / "almsdm_warp" / "__init__.py").exists():
        raise SystemExit(f"{old} is not a checkout of this project (no almsdm_warp/__init__.py)")
    dt = args.dt
    if dt is None:
        sys.path.insert(0, str(ROOT))
        from almsdm_warp import load_mesh
        from almsdm_warp.batch.sweep import auto_dt
        from almsdm_warp.sim.model import Model
        from almsdm_warp.warp_init import init_warp

        init_warp()
        dt = auto_dt(Model(load_mesh(args.mesh), None, "cpu"))
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
    if args.json:
        args.json.write_text(json.dumps({"dt": dt, "median": med, "runs": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
