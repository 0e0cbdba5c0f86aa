"""One palpation's step rate: explicit and implicit, rings 1..4 and the global model.

    python scripts/bench_palpation.py [MESH] [--device cpu] [--rings 1 2 3 4] [--blocks 30]

Each configuration: touch a surface vertex, hold the probe 5 mm in (displacement control), warm
up, then time blocks of 2000 `Palpation.step()` calls, each replaying the captured graph and
reading the feedback force through the host view. Reports the median and the best block (this
machine is shared and noisy: the best block is the code's cost, the median what a run sees).
A benchmark, not a test.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]


def default_mesh():
    shared = ROOT.parent / "shared" / "meshes" / "gca_stomach_1002v.obj"
    return shared if shared.exists() else ROOT / "scenes" / "stomach.obj"


def measure(mesh, rings, integrator, device, blocks, steps=2000):
    """One configuration's timing: moved to almsdm_warp.evaluation.bench (shared with `almsdm bench`)."""
    from almsdm_warp.evaluation.bench import measure as _measure

    return _measure(mesh, rings, integrator, device, blocks, steps)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", type=Path, default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--rings", nargs="*", default=["1", "2", "3", "4", "global"])
    ap.add_argument("--integrators", nargs="*", default=["explicit", "implicit"])
    ap.add_argument("--blocks", type=int, default=30)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    from almsdm_warp import load_mesh
    from almsdm_warp.warp_init import init_warp

    init_warp()
    path = args.mesh or default_mesh()
    mesh = load_mesh(path)
    print(f"{mesh.summary()}; device {args.device}; dt 1 ms; probe held 5 mm in; force read every step")
    print("| model | integrator | region vertices (free) | step us median | best | steps/s (median) | CG iterations |")
    print("|---|---|---|---|---|---|---|")
    rows = []
    for integrator in args.integrators:
        for r in args.rings:
            rings = r if r in ("global", "global-free") else int(r)
            row = measure(mesh, rings, integrator, args.device, args.blocks)
            rows.append(row)
            print(
                f"| {rings} | {integrator} | {row['region_vertices']} ({row['free_vertices']}) | {row['step_us_median']:.2f} "
                f"| {row['step_us_best']:.2f} | {row['steps_per_s']:,.0f} | {row['cg_iterations'] or '-'} |"
            )
    if args.json:
        args.json.write_text(json.dumps({"mesh": str(path), "device": args.device, "single": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
