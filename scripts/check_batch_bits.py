"""Batched presses against one-palpation presses on a device: how many agree bit for bit.

    python scripts/check_batch_bits.py [MESH] --device cuda:0 --points 32

With the exact kernel every point agrees (tests/test_batch.py asserts it); the fast kernel (CUDA's
default) reports how far its approximate reciprocal square root takes it from the exact step.
"""

from pathlib import Path

import numpy as np
from batch_args import batch_parser, load_batch_mesh


def main(argv=None):
    ap = batch_parser(__doc__, "--points", 32, device="cpu", mesh_default=Path(__file__).resolve().parents[1] / "scenes" / "stomach.obj")
    args = ap.parse_args(argv)
    mesh = load_batch_mesh(args.mesh)
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sampling import sample_points
    from almsdm_warp.protocol.palpation import Palpation

    _, vertices = sample_points(mesh, args.points)
    bp = BatchPalpation(mesh, rings=args.rings, device=args.device, kernel=args.kernel).touch(vertices)
    res = bp.press()
    ref_f, ref_r = [], []
    for v in vertices:
        pal = Palpation(mesh, rings=args.rings, device=args.device)
        pal.touch(int(v))
        r = pal.press()
        ref_f.append(r.peak_force_N)
        ref_r.append(r.recovery_error_mm * 1e-3)
    ref_f, ref_r = np.array(ref_f), np.array(ref_r)
    print(
        f"{args.device}, kernel {bp.kernel}: {len(vertices)} points, {args.rings} rings; peak force equal bits {np.sum(res.peak_force == ref_f)}, "
        f"max rel diff {np.max(np.abs(res.peak_force - ref_f) / ref_f):.3g}; recovery error equal bits "
        f"{np.sum(res.recovery_error == ref_r)}, max abs diff {np.max(np.abs(res.recovery_error - ref_r)) * 1e3:.3g} mm"
    )


if __name__ == "__main__":
    main()
