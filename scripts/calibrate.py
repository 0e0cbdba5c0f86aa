"""Check (or redo) a scene's calibration: the 4-ring feedback force at 10 mm and the critical step.

    python scripts/calibrate.py [SCENE ...] [--seeds 12] [--target-N 2.4]

For each scene: a 10 mm displacement-controlled press (the scene's protocol, implicit, dt 1 ms)
at contact vertices spread over the surface; the hold-end force's median and range; the global
anchored model's at the same vertices; the critical step of semi-implicit Euler for the whole mesh
and for a typical 4-ring region; and the stiffness scale that would put the median on the target
(the static force of a displacement-controlled press scales linearly with a common factor on
every stiffness). Prints a Markdown table.
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=["paper_stomach", "paper_liver"])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--target-N", type=float, nargs="*", default=None, help="target force per scene [N]")
    args = ap.parse_args(argv)
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.scene.loader import resolve_scene_or_mesh
    from almsdm_warp.warp_init import init_warp

    init_warp()
    targets = args.target_N or [{"paper_stomach": 2.402, "paper_liver": 2.312}.get(s, 2.4) for s in args.scenes]
    print("| scene | rings | hold-end force median [min-max] (N) | global (N) | target (N) | stiffness scale to target | critical dt whole mesh / 4-ring region (ms) |")
    print("|---|---|---|---|---|---|---|")
    for name, target in zip(args.scenes, targets):
        scene = resolve_scene_or_mesh(name)
        mesh = scene.load_mesh()
        pr = scene.press
        sv = mesh.surface_vertices
        seeds = sv[np.linspace(0, len(sv) - 1, args.seeds).astype(int)]
        local = Palpation(mesh, scene.tissue, rings=scene.rings, integrator="implicit", dt=1e-3)
        glob = Palpation(mesh, scene.tissue, rings="global", integrator="implicit", dt=1e-3)
        hold_end = int(round((pr.ramp + pr.hold) / 1e-3)) - 1
        f_local, f_global, crit_region = [], [], []
        for v in seeds:
            for pal, out in ((local, f_local), (glob, f_global)):
                pal.touch(int(v))
                out.append(pal.press(pr.depth, pr.ramp, pr.hold, 0.01).force[hold_end])
            free = local.region.vertices()[: local.region.free_count]
            crit_region.append(local.model.critical_dt(free))
        med = float(np.median(f_local))
        print(
            f"| {name} | {scene.rings} | {med:.3f} [{min(f_local):.2f}-{max(f_local):.2f}] | {np.median(f_global):.3f} "
            f"| {target:.3f} | {target / med:.3f} | {local.model.critical_dt() * 1e3:.3f} / {np.median(crit_region) * 1e3:.3f} |"
        )


if __name__ == "__main__":
    main()
