"""Cost of one frame's normal update, per strategy: rings 1..4 and the global surface model on a
surface mesh, and the 4-ring model on a tet mesh (the paper's Table 2, normals only).

    python scripts/bench_normals.py [--surface MESH] [--volume MESH] [--device cpu] [--blocks 15] [--json out.json]

Each case calls almsdm_warp.sim.normals.benchmark_strategies: the update of each strategy captured in
a Warp graph and replayed (median and best per frame over blocks), and one uncaptured update
(Python and the launch included). The region is built around the highest surface vertex. A
benchmark, not a test: the machine is shared, so read medians, and compare strategies within a run.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# as tests/conftest.py: ../shared/meshes beside the checkout, or where ALMSDM_SHARED_MESHES points
SHARED = Path(os.environ.get("ALMSDM_SHARED_MESHES", ROOT.parent / "shared" / "meshes"))


def default(name, fallback):
    p = SHARED / name
    return p if p.exists() else ROOT / "scenes" / fallback


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--surface", type=Path, default=default("gca_stomach_1002v.obj", "stomach.obj"))
    ap.add_argument("--volume", type=Path, default=ROOT / "scenes" / "liver.vtu")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--frames", type=int, default=200, help="graph replays per block")
    ap.add_argument("--blocks", type=int, default=15)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)

    from almsdm_warp import load_mesh
    from almsdm_warp.sim.normals import STRATEGIES, benchmark_strategies
    from almsdm_warp.warp_init import init_warp

    init_warp()
    surface, volume = load_mesh(args.surface), load_mesh(args.volume)
    cases = [(surface, r, f"{r} ring{'s' if r > 1 else ''}") for r in (1, 2, 3, 4)]
    cases += [(surface, "global", "global surface"), (volume, 4, "4-ring volume")]
    print(f"surface {surface.summary()}; volume {volume.summary()}; device {args.device}")
    head = " | ".join(f"{s} us (launch us)" for s in STRATEGIES)
    print(f"| model | vertices updated (on the surface) | {head} |")
    print("|---|---|" + "---|" * len(STRATEGIES))
    rows = []
    for mesh, rings, label in cases:
        r = benchmark_strategies(mesh, rings, args.device, frames=args.frames, blocks=args.blocks)
        r["model"] = label
        rows.append(r)
        cells = " | ".join(
            f"{r['strategies'][s]['frame_us_median']:.2f} ({r['strategies'][s]['launch_us_median']:.1f})" for s in STRATEGIES
        )
        print(f"| {label} | {r['vertices_updated']} ({r['surface_vertices_updated']}) | {cells} |", flush=True)
    if args.json:
        args.json.write_text(json.dumps({"device": args.device, "cases": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
