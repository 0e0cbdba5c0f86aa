"""Region sizes for rings 1..4 beside the paper's, and ring-building time per contact.

    python scripts/bench_rings.py [MESH ...] [--device cpu] [--seeds 200] [--scale 1.0]

Defaults to the shared meshes the paper's sizes are compared with (../shared/meshes/
gca_stomach_1002v.obj and sofa_liver2_tets.vtu) when present, else the project's scenes. Seeds are
surface vertices spread evenly by id. A benchmark, not a test: it synchronizes before reading the
clock and reports medians after a warm-up build.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import warp as wp

ROOT = Path(__file__).resolve().parents[1]
PAPER = {  # DESIGN.md: region size for rings 1/2/3/4 (surface), and the 4-ring volume region
    "surface": {"vertices": [7, 20, 41, 70], "springs": [12, 45, 98, 187]},
    "volume": {"vertices": [None, None, None, 119], "springs": [None, None, None, 262]},
}


def default_meshes():
    shared = ROOT.parent / "shared" / "meshes"
    picks = [shared / "gca_stomach_1002v.obj", shared / "sofa_liver2_tets.vtu"]
    if all(p.exists() for p in picks):
        return picks
    return [ROOT / "scenes" / "stomach.obj", ROOT / "scenes" / "liver.vtu"]


def measure(path, device, seeds, max_rings=4):
    from almsdm_warp import Region, load_mesh

    mesh = load_mesh(path)
    sv = mesh.surface_vertices
    chosen = sv[np.linspace(0, len(sv) - 1, min(seeds, len(sv))).astype(int)]
    region = Region(mesh, device)
    region.build(int(chosen[0]), max_rings)  # warm-up: kernels compiled and loaded
    sizes = np.zeros((len(chosen), max_rings, 2), dtype=np.int64)
    times = {k: [] for k in range(1, max_rings + 1)}
    for i, seed in enumerate(chosen):
        for k in range(1, max_rings + 1):
            wp.synchronize_device(device)
            t0 = time.perf_counter()
            region.build(int(seed), k)
            wp.synchronize_device(device)
            times[k].append(time.perf_counter() - t0)
            sizes[i, k - 1] = region.vertex_count, region.spring_count
    return mesh, sizes, {k: statistics.median(v) * 1e6 for k, v in times.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="*", type=Path)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seeds", type=int, default=200)
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    for path in args.meshes or default_meshes():
        mesh, sizes, build_us = measure(path, args.device, args.seeds)
        kind = "volume" if mesh.is_volume else "surface"
        print(f"\n{mesh.summary()} ({kind}); {len(sizes)} seeds on the surface; device {args.device}")
        print("| rings | vertices median [min-max] | paper | springs median [min-max] | paper | build us (median) |")
        print("|---|---|---|---|---|---|")
        for k in range(sizes.shape[1]):
            v, s = sizes[:, k, 0], sizes[:, k, 1]
            pv = PAPER[kind]["vertices"][k]
            ps = PAPER[kind]["springs"][k]
            print(
                f"| {k + 1} | {int(np.median(v))} [{v.min()}-{v.max()}] | {pv if pv else '-'} "
                f"| {int(np.median(s))} [{s.min()}-{s.max()}] | {ps if ps else '-'} | {build_us[k + 1]:.0f} |"
            )


if __name__ == "__main__":
    main()
