"""How a sweep's pressed points size its volume (docs/volume.md, "Measured"): for each point count, the points a sweep
samples on the surface, the tet count estimated before fTetWild runs, the count it makes (or the refusal past
mesh.volume.MAX_TETS) and its time.

    python scripts/volume_sizes.py MESH [--scale-mm S] [--probe-radius-mm R] [--depth-mm D] [--points 1,8,64] [--estimate-only]
"""

from __future__ import annotations

import argparse
import re
import time
from dataclasses import replace

import numpy as np

from almsdm_warp.errors import InputError
from almsdm_warp.mesh import volume as mv
from almsdm_warp.mesh.io import load_mesh
from almsdm_warp.scene.loader import mesh_scene
from almsdm_warp.scene.volume import sweep_tets


def estimate(scene, surface, points: int, depth: float) -> float:
    """The estimate alone: the refusal of a limit of 0 tets says it."""
    limit, mv.MAX_TETS = mv.MAX_TETS, 0
    try:
        sweep_tets("volume", scene, surface, points, depth)
    except InputError as exc:
        return float(re.search(r"about ([\d,]+)", str(exc)).group(1).replace(",", ""))
    finally:
        mv.MAX_TETS = limit
    raise AssertionError("a limit of 0 tets was not refused")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh")
    parser.add_argument("--scale-mm", type=float, default=1.0)
    parser.add_argument("--probe-radius-mm", type=float, default=10.0)
    parser.add_argument("--depth-mm", type=float, default=10.0)
    parser.add_argument("--points", default="1,8,64")
    parser.add_argument("--estimate-only", action="store_true")
    args = parser.parse_args()
    surface = load_mesh(args.mesh, scale=args.scale_mm)
    R, d = args.probe_radius_mm * 1e-3, args.depth_mm * 1e-3
    scene = replace(mesh_scene(args.mesh, args.scale_mm), support=None, probe_radius=R)
    print(f"{surface.summary()}; extent {np.round(np.ptp(surface.vertices, axis=0) * 1e3, 1).tolist()} mm; edge where pressed "
          f"{mv.contact_edge(R, d) * 1e3:.3g} mm; limit {mv.MAX_TETS:,}")
    print("| points | estimate | tets | s |\n|---|---|---|---|")
    for n in (int(p) for p in args.points.split(",")):
        guess = estimate(scene, surface, n, d)
        if args.estimate_only:
            print(f"| {n} | {guess:,.0f} | | |", flush=True)
            continue
        t0 = time.perf_counter()
        try:
            tets, _ = sweep_tets("volume", scene, surface, n, d)
            made = f"{tets.tet_count:,}"
        except InputError:
            made = "refused"
        print(f"| {n} | {guess:,.0f} | {made} | {time.perf_counter() - t0:.1f} |", flush=True)


if __name__ == "__main__":
    main()
