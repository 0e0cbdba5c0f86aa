"""The liver stroke's step with each way of the explicit step over a tet law's tets ("tets": each tet
once; "vertices": each vertex's; SolverExplicit.tet_pass), interleaved in one process on one core.

    python scripts/ab_tet_pass.py [--core 1] [--runs 3] [--scene liver]

The scene's ProbeStroke (its law, rings, support) along the built-in stroke, as `almsdm trace` steps
it: one warm-up run each, then `--runs` runs of each in alternation on fresh strokes, each step
timed (perf_counter and this thread's CPU time) with the garbage collector frozen. Prints p50 / p99 /
max of each and the largest force difference between the two. A benchmark, not a test.
"""

import argparse
import gc
import os
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--core", type=int, default=1)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--scene", default="liver")
    args = ap.parse_args(argv)
    os.sched_setaffinity(0, {args.core})
    from almsdm_warp.warp_init import init_warp

    init_warp()
    from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke
    from almsdm_warp.scene.loader import default_scene_path, load_scene

    scene = load_scene(default_scene_path(args.scene))
    mesh = scene.load_mesh()
    radius = scene.probe_radius or 10e-3  # almsdm trace's default
    path = builtin_stroke(mesh, radius, dt=1e-3)

    def run(kind):
        s = ProbeStroke(mesh, scene.tissue, probe_radius=radius, rings=scene.rings, integrator="explicit", dt=1e-3,
                        device="cpu", fixed_below=scene.fixed_below, law=scene.law)
        s.solver.tet_pass = kind
        wall, cpu, force = [], [], []
        gc.collect()
        gc.freeze()
        try:
            for c in path.centre:
                t0, c0 = time.perf_counter(), time.thread_time()
                f = s.step(c)
                wall.append(time.perf_counter() - t0)
                cpu.append(time.thread_time() - c0)
                force.append(np.array(f, dtype=np.float64).ravel())
        finally:
            gc.unfreeze()
        return np.array(wall[1:]) * 1e6, np.array(cpu[1:]) * 1e6, np.array(force)

    kinds = ("vertices", "tets")
    for k in kinds:
        run(k)
    got = {k: [] for k in kinds}
    forces = {}
    for _ in range(args.runs):
        for k in kinds:
            w, c, f = run(k)
            got[k].append((w, c))
            forces[k] = f
    print(f"{args.scene}: {len(path.centre)} steps, {args.runs} runs each, core {args.core}")
    for k in kinds:
        for w, c in got[k]:
            print(f"{k:9s} wall p50 {np.percentile(w, 50):6.1f} p99 {np.percentile(w, 99):6.1f} max {w.max():6.1f} us | "
                  f"cpu p50 {np.percentile(c, 50):6.1f} p99 {np.percentile(c, 99):6.1f} us")
    a, b = forces["vertices"], forces["tets"]
    print(f"largest force difference {np.abs(a - b).max():.3g} N of {np.abs(a).max():.3g} N")


if __name__ == "__main__":
    main()
