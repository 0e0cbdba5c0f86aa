"""Sweeps at --rings auto against the global anchored model: peak force per point (docs/adaptive.md).

For each scene and tolerance: the sweep's points (sweep.sample_points), each sized by
sweep_auto.size_regions and pressed in batches of its ring count (as `almsdm sweep --rings auto`),
a sweep at a fixed ring count `--reference-rings`, and the global anchored model (Palpation
rings="global") at each point under the same press (explicit at the sweep's dt, sweep.auto_dt: 1 ms on the stomach, 0.2 ms on the liver; 10 mm, ramp 0.1 s,
hold 0.2 s).

    python scripts/sweep_auto_accuracy.py --points 48 --tol-mm 0.03 0.1 0.3 1
"""

import argparse
import time

import numpy as np

from almsdm_warp.evaluation.adaptive_accuracy import hold_press
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import resolve_scene_or_mesh
from almsdm_warp.sim.model import Model
from almsdm_warp.batch.sampling import sample_points
from almsdm_warp.batch.sweep_lanes import RingBatches, press_chunk
from almsdm_warp.batch.sweep_plan import SweepPlan, auto_dt
from almsdm_warp.batch.sweep_auto import rings_summary, size_regions
from almsdm_warp.warp_init import init_warp

DEPTH, RAMP, HOLD, SETTLE = 0.01, 0.1, 0.2, 0.01


def sweep(mesh, tissue, rings, points, vertices, dt):
    plan = SweepPlan(mesh, tissue, None, None, rings, dt, DEPTH, RAMP, HOLD, SETTLE, points, vertices, len(vertices))
    t0 = time.perf_counter()
    cols = press_chunk(RingBatches(plan, plan.model("cpu")), plan, 0, len(vertices))()
    return cols["peak_force_N"], time.perf_counter() - t0


def global_peaks(mesh, tissue, vertices, dt):
    pal = Palpation(mesh, tissue, rings="global", dt=dt, device="cpu")
    peaks = []
    for v in vertices:
        pal.touch(int(v))
        peaks.append(hold_press(pal, DEPTH, RAMP, HOLD)[0])
        for s in pal.states:  # the next press from rest
            s.particle_q.assign(pal.model.particle_q_rest)
            s.particle_qd.zero_()
    return np.asarray(peaks)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*", default=["stomach", "liver"])
    ap.add_argument("--points", type=int, default=48)
    ap.add_argument("--tol-mm", type=float, nargs="+", default=[0.03, 0.1, 0.3, 1.0])
    ap.add_argument("--reference-rings", type=int, default=8)
    args = ap.parse_args()
    init_warp()
    print("| scene | tol (mm) | rings per point | sizing (s) | batch (s) | auto vs global: force error max | "
          f"{args.reference_rings} rings vs global | {args.reference_rings} rings batch (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for name in args.scenes:
        scene = resolve_scene_or_mesh(name)
        mesh = scene.load_mesh()
        points, vertices = sample_points(mesh, args.points)
        dt = auto_dt(Model(mesh, scene.tissue, "cpu"))
        ref = global_peaks(mesh, scene.tissue, vertices, dt)
        fixed, t_fixed = sweep(mesh, scene.tissue, args.reference_rings, points, vertices, dt)
        e_fixed = np.abs(fixed / ref - 1).max()
        for tol_mm in args.tol_mm:
            t0 = time.perf_counter()
            rings = size_regions(mesh, scene.tissue, vertices, tol_mm * 1e-3, depth=DEPTH, ramp=RAMP, hold=HOLD, dt=dt)
            sizing = time.perf_counter() - t0
            auto, t_auto = sweep(mesh, scene.tissue, rings, points, vertices, dt)
            e_auto = np.abs(auto / ref - 1).max()
            print(f"| {name} | {tol_mm:g} | {rings_summary(rings)[6:]} | {sizing:.2f} | {t_auto:.2f} | {e_auto:.3%} | "
                  f"{e_fixed:.5%} | {t_fixed:.2f} |", flush=True)


if __name__ == "__main__":
    main()
