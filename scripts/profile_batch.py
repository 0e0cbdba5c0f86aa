"""One launch of the batch press kernel, for a profiler: `ncu ... python scripts/profile_batch.py MESH`.

    ncu --clock-control none -k regex:press --section SpeedOfLight --section Occupancy \
        --section WarpStateStats python scripts/profile_batch.py MESH --batch 10000 --steps 200
"""

import warp as wp
from batch_args import batch_parser, load_batch_mesh


def main(argv=None):
    ap = batch_parser(__doc__, "--batch", 10000)
    ap.add_argument("--steps", type=int, default=200)
    args = ap.parse_args(argv)
    mesh = load_batch_mesh(args.mesh)
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.evaluation.bench import spread_vertices

    bp = BatchPalpation(mesh, rings=args.rings, dt=6.5e-4, device=args.device, kernel=args.kernel).touch(spread_vertices(mesh, args.batch))
    bp.depth, bp.ramp_steps, bp.press_steps = 0.01, 100, args.steps
    bp.launch_steps(0, args.steps)
    wp.synchronize_device(bp.device)
    print(f"kernel {bp.kernel}, plan {bp.fast_plan if bp.kernel == 'fast' else bp.threads}, {args.batch} palpations x {args.steps} steps")


if __name__ == "__main__":
    main()
