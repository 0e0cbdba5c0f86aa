"""A sweep's results on CUDA against the CPU's, per kernel, and run to run on CUDA.

    python scripts/check_fast_sweep.py MESH --points 10000 --kernels fast exact

The sweep's press (10 mm, ramp 0.1 s, hold 0.2 s, settle 1 s, dt from the mesh's critical step)
at `points` farthest-point samples snapped to vertices; the CPU reference is the default CPU
batch (equal to Palpation bit for bit) on the distinct vertices. Prints, per kernel, the largest
relative difference of peak and hold forces, recovery errors (relative and absolute), and
whether two CUDA runs gave the same bits.
"""

import time

import numpy as np
from batch_args import batch_parser, load_batch_mesh


def main(argv=None):
    ap = batch_parser(__doc__, "--points", 10000, kernel=False)
    ap.add_argument("--kernels", nargs="*", default=["fast", "exact"])
    args = ap.parse_args(argv)
    import warp as wp

    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sampling import sample_points
    from almsdm_warp.batch.sweep_plan import auto_dt
    from almsdm_warp.sim.model import Model

    mesh = load_batch_mesh(args.mesh)
    dt = auto_dt(Model(mesh, None, "cpu"))
    _, vertices = sample_points(mesh, args.points)
    press = (0.01, 0.1, 0.2, 1.0)
    uniq, inverse = np.unique(vertices, return_inverse=True)
    t0 = time.perf_counter()
    cpu = BatchPalpation(mesh, rings=args.rings, dt=dt, device="cpu").touch(uniq).press(*press)
    print(f"CPU reference (default CPU kernel): {len(uniq)} distinct vertices of {len(vertices)} points, {time.perf_counter() - t0:.1f} s")
    ref_peak, ref_hold, ref_rec = cpu.peak_force[inverse], cpu.hold_force[inverse], cpu.recovery_error[inverse]
    for kernel in args.kernels:
        runs = []
        for _ in range(2):
            bp = BatchPalpation(mesh, rings=args.rings, dt=dt, device=args.device, kernel=kernel).touch(vertices)
            runs.append(bp.press(*press))
            wp.synchronize_device(bp.device)
        a, b = runs
        same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("peak_force", "hold_force", "recovery_error"))
        rel = lambda x, y: float(np.max(np.abs(x - y) / np.abs(y)))
        big = ref_rec > 1e-7  # recovery errors above 0.1 um: relative differences mean something there
        print(
            f"{kernel}: peak force max rel diff {rel(a.peak_force, ref_peak):.3g}, hold force {rel(a.hold_force, ref_hold):.3g}; "
            f"recovery error max abs diff {np.max(np.abs(a.recovery_error - ref_rec)) * 1e3:.3g} mm (max {ref_rec.max() * 1e3:.3g} mm), "
            f"max rel diff where > 0.1 um {rel(a.recovery_error[big], ref_rec[big]) if big.any() else float('nan'):.3g} ({int(big.sum())} points); "
            f"two CUDA runs same bits: {same}",
            flush=True,
        )


if __name__ == "__main__":
    main()
