"""What the adaptive region costs per step: AdaptivePalpation against Palpation at the same rings.

    python scripts/bench_adaptive.py [MESH] [--device cpu] [--rings 2 3 4] [--blocks 30]

For each ring count: a fixed Palpation and an AdaptivePalpation rebuilt at that ring count
(retirement off, so both step the same region), the probe held 5 mm in; blocks of 2000 `step()`
calls, alternating between the two so that the machine's load hits both alike. The adaptive
one also runs its ring check every 10 steps (dt 1 ms, check every 10 ms). Also the check alone
(`ring_motion()` plus the estimate). Reports medians and best blocks. A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", type=Path, default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--rings", type=int, nargs="*", default=[2, 3, 4])
    ap.add_argument("--integrator", default="explicit")
    ap.add_argument("--blocks", type=int, default=30)
    args = ap.parse_args(argv)
    from almsdm_warp import load_mesh
    from almsdm_warp.protocol.adaptive import AdaptivePalpation
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.warp_init import init_warp

    init_warp()
    shared = ROOT.parent / "shared" / "meshes" / "gca_stomach_1002v.obj"
    mesh = load_mesh(args.mesh or (shared if shared.exists() else ROOT / "scenes" / "stomach.obj"))
    vertex = int(mesh.surface_vertices[np.argmax(mesh.vertices[mesh.surface_vertices, 2])])
    print(f"{mesh.summary()}; device {args.device}; {args.integrator}, dt 1 ms; probe held 5 mm in")
    print("| rings | region vertices | fixed: step us median (best) | auto: step us median (best) | auto - fixed (median) | check us median (best) |")
    print("|---|---|---|---|---|---|")
    for rings in args.rings:
        fixed = Palpation(mesh, None, rings=rings, integrator=args.integrator, dt=1e-3, device=args.device)
        fixed.touch(vertex)
        auto = AdaptivePalpation(mesh, None, tol=1.0, integrator=args.integrator, dt=1e-3, device=args.device, retire=False, force_tol=1e9)
        auto.touch(vertex)
        auto.rebuild(rings)  # tol 1 m, no force criterion: the check runs every 10 steps, never grows
        for pal in (fixed, auto):
            pal.set_probe(1, pal.rest_position() + pal.inward_normal() * 0.005)
            for _ in range(500):
                pal.step()
        times = {id(fixed): [], id(auto): []}
        steps = 2000
        for _ in range(args.blocks):
            for pal in (fixed, auto):
                t0 = time.perf_counter()
                for _ in range(steps):
                    pal.step()
                times[id(pal)].append((time.perf_counter() - t0) / steps * 1e6)
        assert auto.region.outer_ring == rings
        checks = []
        for _ in range(args.blocks):
            t0 = time.perf_counter()
            for _ in range(200):
                auto.estimate()
            checks.append((time.perf_counter() - t0) / 200 * 1e6)
        f, a = times[id(fixed)], times[id(auto)]
        print(
            f"| {rings} | {fixed.region_vertices} | {statistics.median(f):.2f} ({min(f):.2f}) | "
            f"{statistics.median(a):.2f} ({min(a):.2f}) | {statistics.median(a) - statistics.median(f):+.2f} | "
            f"{statistics.median(checks):.2f} ({min(checks):.2f}) |"
        )


if __name__ == "__main__":
    main()
