"""Each tissue law against a neo-Hookean finite-element solve of the same tets: a sphere pressed deep.

    python scripts/law_vs_fem.py [--radius-mm 25] [--edge-mm 4] [--refine 2] [--sphere-mm 10]
        [--depths-mm 2 5 10] [--poisson 0.45] [--json out.json]

A tet ball (mesh.primitives.tet_ball, graded finer at the top) resting on a support (vertices below
-0.6 R fixed), E 10 kPa, a rigid frictionless sphere pressed along -z at the top vertex. Reference:
evaluation/fem_nonlinear.solve (P1 tets, the classic compressible neo-Hookean energy, augmented-Lagrangian
contact, static; shares no code with the product). Product: the global model of each law (implicit,
damped, 2 ms frames), the force at the end of the hold (a static answer). Prints force / FEM per law
and depth, and the tets each law leaves inverted. An evaluation, not a test.
"""

import argparse
import json
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius-mm", type=float, default=25.0)
    ap.add_argument("--edge-mm", type=float, default=4.0)
    ap.add_argument("--refine", type=float, default=2.0)
    ap.add_argument("--sphere-mm", type=float, default=10.0)
    ap.add_argument("--depths-mm", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    ap.add_argument("--poisson", type=float, default=0.45)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    from almsdm_warp.evaluation import fem_nonlinear as fnl
    from almsdm_warp.mesh.primitives import tet_ball
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.laws import LAWS
    from almsdm_warp.tissue.material import Material

    E, R = 10e3, args.radius_mm * 1e-3
    mesh = tet_ball(args.radius_mm, args.edge_mm, refine_top=args.refine)
    x, tets = mesh.vertices, mesh.tetrahedra.astype(np.int64)
    top = int(np.argmax(x[:, 2]))
    z_fix = -0.6 * R
    material = Material(youngs_modulus=E, poisson_ratio=args.poisson, density=1000.0, rayleigh_alpha=100.0)
    print(f"{mesh.summary()}; support below z = {z_fix * 1e3:g} mm; sphere {args.sphere_mm:g} mm at vertex {top}; "
          f"E {E / 1e3:g} kPa, nu {args.poisson}")
    rows = []
    for depth_mm in args.depths_mm:
        depth = depth_mm * 1e-3
        t0 = time.perf_counter()
        fixed = np.zeros((len(x), 3), dtype=bool)
        fixed[x[:, 2] < z_fix] = True
        ref = fnl.solve(x, tets, young=E, poisson=args.poisson, fixed=fixed,
                        sphere=fnl.Sphere(args.sphere_mm * 1e-3, depth, tuple(x[top, :2])), steps=max(4, int(depth_mm * 2)))
        row = {"depth_mm": depth_mm, "fem_N": ref.force, "fem_s": time.perf_counter() - t0}
        for law in LAWS:
            t0 = time.perf_counter()
            pal = Palpation(mesh, material, rings="global", law=law, integrator="implicit", dt=2e-3, device="cpu",
                            fixed_below=z_fix, probe_radius=args.sphere_mm * 1e-3)
            pal.touch(top, depth)
            result = pal.press(depth, ramp=0.2, hold=0.6, settle=0.02)
            row[f"{law}_N"] = float(result.force[result.release_step - 1])
            row[f"{law}_inverted"] = result.inverted_tets  # at the end of the hold
            row[f"{law}_s"] = time.perf_counter() - t0
        rows.append(row)
        laws = ", ".join(f"{law} {row[f'{law}_N'] / ref.force:.3f} ({row[f'{law}_inverted']} inverted)" for law in LAWS)
        print(f"depth {depth_mm:g} mm: FEM {ref.force:.4f} N; force / FEM: {laws}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"mesh": mesh.summary(), "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
