"""One launch of the batch press kernel, for a profiler: `ncu ... python scripts/profile_batch.py MESH`.

    ncu --clock-control none -k regex:press --section SpeedOfLight --section Occupancy \
        --section WarpStateStats python scripts/profile_batch.py MESH --batch 10000 --steps 200
"""

import argparse
from pathlib import Path

import warp as wp


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", type=Path)
    ap.add_argument("--device", default="cuda:0")
    ap.add_argument("--batch", type=int, default=10000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rings", type=int, default=4)
    ap.add_argument("--kernel", default=None, help="fast or exact (default: the device's)")
    args = ap.parse_args(argv)
    from almsdm_warp import load_mesh
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.evaluation.bench import spread_vertices
    from almsdm_warp.warp_init import init_warp

    init_warp()
    mesh = load_mesh(args.mesh)
    bp = BatchPalpation(mesh, rings=args.rings, dt=6.5e-4, device=args.device, kernel=args.kernel).touch(spread_vertices(mesh, args.batch))
    bp.depth, bp.ramp_steps, bp.press_steps = 0.01, 100, args.steps
    bp.launch_steps(0, args.steps)
    wp.synchronize_device(bp.device)
    print(f"kernel {bp.kernel}, plan {bp.fast_plan if bp.kernel == 'fast' else bp.threads}, {args.batch} palpations x {args.steps} steps")


if __name__ == "__main__":
    main()
