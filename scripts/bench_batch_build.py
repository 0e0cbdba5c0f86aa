"""A batch's region build on a shipped scene: `BatchPalpation.touch` (regions, local topology, a tet law's
local tets, the plan) timed, and its arrays saved to compare two trees bit for bit.

    python scripts/bench_batch_build.py [--scene liver] [--contacts 110] [--repeats 3] [--device cpu] [--save OUT.npz]
    python scripts/bench_batch_build.py --compare A.npz B.npz

Contacts: a seeded sample of the scene's surface vertices at least 4 mm above its support. Each array
is saved within each region's count (the buffers past it are not written). A benchmark, not a test.
"""

import argparse
import time

import numpy as np


def _within_counts(bp, host_copy) -> dict:
    rc = bp.region_vertex_counts
    out = {"region_count": rc, "free_count": bp.free_vertex_counts}
    rv, lo, ln = host_copy(bp.regions.region_vertex), host_copy(bp.regions.local_offsets), host_copy(bp.regions.local_neighbour)
    out["region_vertex"] = np.concatenate([rv[b, :n] for b, n in enumerate(rc)])
    out["local_neighbour"] = np.concatenate([ln[b, :lo[b, f]] for b, f in enumerate(bp.free_vertex_counts)])
    if getattr(bp, "element_offsets", None) is not None:
        eo, et = host_copy(bp.element_offsets), host_copy(bp.element_topology)
        out["element_offsets"] = np.concatenate([eo[b, :n + 1] for b, n in enumerate(rc)])
        out["element_topology"] = np.concatenate([et[b, :eo[b, n]] for b, n in enumerate(rc)])
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="liver")
    ap.add_argument("--contacts", type=int, default=110)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--save", default=None, help="save the built arrays (within each region's count) to this .npz")
    ap.add_argument("--compare", nargs=2, default=None, metavar=("A", "B"), help="compare two saved .npz files and exit")
    args = ap.parse_args(argv)
    if args.compare:
        a, b = (np.load(f) for f in args.compare)
        same = {k: bool(k in b.files and np.array_equal(a[k], b[k])) for k in a.files}
        print(same, "the same bits" if all(same.values()) else "DIFFERENT")
        return 0 if all(same.values()) else 1
    from almsdm_warp.warp_init import init_warp

    init_warp()
    from almsdm_warp.batch.batch_palpation import BatchPalpation, host_copy
    from almsdm_warp.scene.loader import default_scene_path, load_scene

    scene = load_scene(default_scene_path(args.scene))
    mesh = scene.load_mesh()
    surface = mesh.surface_vertices
    low = -np.inf if scene.fixed_below is None else scene.fixed_below + 0.004
    candidates = surface[mesh.vertices[surface, 2] > low]
    contacts = np.sort(np.random.default_rng(0).choice(candidates, min(args.contacts, len(candidates)), replace=False))
    bp = BatchPalpation(mesh, scene.tissue, rings=scene.rings, device=args.device, probe_radius=scene.probe_radius,
                        fixed_below=scene.fixed_below, dt=1e-4)
    bp.touch(contacts[:4])  # compiles
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        bp.touch(contacts)
        times.append(time.perf_counter() - t0)
    print(f"{args.scene}: {len(contacts)} regions ({bp.model.law}, {scene.rings} rings, {int(np.median(bp.region_vertex_counts))} "
          f"vertices median) built in {', '.join(f'{t:.3f}' for t in times)} s")
    if args.save:
        np.savez(args.save, **_within_counts(bp, host_copy))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
