"""The adaptive region's force-error estimate against the true force error of fixed rings (docs/adaptive.md).

For each model, a quasi-static press at the top vertex (implicit, dt 5 ms, ramp 0.1 s, hold 0.5 s, the
paper's probe): the global model's peak force, then N fixed rings' peak force, and the ring-motion
kernel's sum f . u_J over the fixed ring at the end of the hold. Prints the ratio (true error) /
(S / (F delta)), the fixed ring's size n_B and its anchors' share s of the stiffness.

    python scripts/adaptive_force_estimate.py      # the two scenes (paper's constants) and local_vs_global's cases
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import warp as wp

from almsdm_warp.evaluation.adaptive_accuracy import hold_press
from almsdm_warp.kernels.region.ring_motion import eval_region_motion
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import resolve_scene_or_mesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
import local_vs_global  # noqa: E402  (a script beside this one)


def anchor_share(model, mesh, boundary) -> float:
    """sum k_a / (sum k_a + sum of the springs' k) over the fixed ring's vertices."""
    ke = model.spring_ke.numpy().astype(np.float64)
    ka = model.anchor_ke.numpy().astype(np.float64)
    ks = np.zeros(len(ka))
    np.add.at(ks, mesh.edges[:, 0], ke)
    np.add.at(ks, mesh.edges[:, 1], ke)
    return float(ka[boundary].sum() / (ka[boundary].sum() + ks[boundary].sum()))


def run(label, mesh, tissue, fixed_below, depth, ring_counts):
    v = int(np.argmax(mesh.vertices[:, 2]))
    kw = dict(integrator="implicit", dt=5e-3, device="cpu", fixed_below=fixed_below)
    glob = Palpation(mesh, tissue, rings="global", **kw)
    glob.touch(v)
    reference = hold_press(glob, depth, 0.1, 0.5)[0]
    for rings in ring_counts:
        pal = Palpation(mesh, tissue, rings=rings, **kw)
        pal.touch(v)
        force = hold_press(pal, depth, 0.1, 0.5)[0]
        motion = wp.zeros(rings + 3, dtype=wp.float32, device="cpu")
        eval_region_motion(pal.model, pal.region, pal.state, motion)
        m = motion.numpy()
        estimate = float(m[-1]) / (float(np.linalg.norm(pal.feedback_force)) * float(m[1]))
        error = force / reference - 1.0
        b = pal.region.boundary()
        print(f"| {label} | {rings} | {error:+.5f} | {estimate:.5f} | {error / estimate:.2f} | {len(b)} | "
              f"{anchor_share(pal.model, mesh, b):.3f} |", flush=True)


def main() -> int:
    print("| model | rings | true force error | S / (F delta) | ratio | n_B | share s |")
    print("|---|---|---|---|---|---|---|")
    for name in ("stomach", "liver"):
        scene = resolve_scene_or_mesh(name)
        run(f"paper's {name}", scene.load_mesh(), scene.tissue, None, 0.01, [1, 2, 3, 4])
    for name, case in local_vs_global.CASES.items():
        run(name, case["mesh"](), case["tissue"], case["fixed_below"], case["depth"], [1, 2, 3, 5])
    return 0


if __name__ == "__main__":
    sys.exit(main())
