"""Each tissue law against locking-free quadratic finite elements (P2/P0, linear, exact frictionless
sphere contact: evaluation/fem.py, which shares no code with the product) where strains are small,
over Poisson's ratios and resolutions: the near-incompressibility and mesh-independence targets.

    python scripts/law_vs_p2.py --case ball [--poisson 0.3 0.45 0.49] [--edges-mm 8]
    python scripts/law_vs_p2.py --case slab [--poisson 0.45 0.49] [--edges-mm 2 1.4 1] [--depth-mm 0.5]

ball: the issue-13 ball (evaluation/continuum.py BALL: R 50 mm graded x 4 toward the top, fixed below
-40 mm, a 50 mm sphere pressed 2 mm). slab: tissue over bone (scripts/law_vs_fem.py --slab: 30 x 30 x
10 mm on a rigid base, a 5 mm sphere at the top's centre). Product: each law's global model, implicit,
damped, the force at the end of the hold (a static answer). Prints force / P2-P0 per law, P2's own
(plain, which locks as nu -> 1/2) for scale. An evaluation, not a test.
"""

import argparse
import time

import numpy as np

E = 10e3


def product_force(mesh, law, poisson, top, z_fix, sphere, depth):
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.material import Material

    material = Material(youngs_modulus=E, poisson_ratio=poisson, density=1000.0, rayleigh_alpha=100.0)
    pal = Palpation(mesh, material, rings="global", law=law, integrator="implicit", dt=2e-3, device="cpu",
                    fixed_below=z_fix, probe_radius=sphere)
    pal.touch(top, depth)
    result = pal.press(depth, ramp=0.2, hold=0.6, settle=0.02)
    return float(result.force[result.release_step - 1])


def case_meshes(args):
    """(label, mesh, top vertex, z_fix [m], sphere radius [m], depth [m]) per resolution."""
    from almsdm_warp.evaluation.continuum import BALL
    from almsdm_warp.mesh.primitives import tet_ball, tet_grid_arrays
    from almsdm_warp.mesh.tissue_mesh import TissueMesh

    for h in args.edges_mm:
        if args.case == "ball":
            mesh = tet_ball(BALL["radius_mm"], h, refine_top=BALL["refine_top"])
            top = int(np.argmax(mesh.vertices[:, 2]))
            yield f"ball {h:g} mm", mesh, top, BALL["z_fix"], BALL["sphere"], (args.depth_mm or 2.0) * 1e-3
        else:
            from almsdm_warp.evaluation.depth_layers import graded  # the slab's grading, one copy

            zs = np.linspace(0.0, 10.0, max(int(round(10.0 / h)), 2) + 1)
            vertices, tets = tet_grid_arrays(graded(h, 15.0), graded(h, 15.0), zs)
            mesh = TissueMesh.from_arrays(vertices * 1e3, tetrahedra=tets)
            top = int(np.argmin(np.linalg.norm(mesh.vertices - np.array([0.0, 0.0, 10e-3]), axis=1)))
            yield f"slab {h:g} mm", mesh, top, 1e-5, 5e-3, (args.depth_mm or 0.5) * 1e-3


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=("ball", "slab"), default="ball")
    ap.add_argument("--poisson", type=float, nargs="+", default=[0.3, 0.45, 0.49])
    ap.add_argument("--edges-mm", type=float, nargs="+", default=None)
    ap.add_argument("--depth-mm", type=float, default=None)
    args = ap.parse_args(argv)
    args.edges_mm = args.edges_mm or ([8.0] if args.case == "ball" else [2.0, 1.4, 1.0])
    from almsdm_warp.evaluation import fem
    from almsdm_warp.tissue.laws import LAWS
    from almsdm_warp.warp_init import init_warp

    init_warp()
    for label, mesh, top, z_fix, sphere, depth in case_meshes(args):
        x, tets = mesh.vertices, mesh.tetrahedra.astype(np.int64)
        centre = tuple(x[top, :2])
        for nu in args.poisson:
            t0 = time.perf_counter()
            kw = dict(young=E, poisson=nu, sphere_radius=sphere, depth=depth, centre_xy=centre, fixed=lambda n: fem.clamped_below(n, z_fix))
            mixed = fem.sphere_press(x, tets, mixed=True, **kw).force
            plain = fem.sphere_press(x, tets, **kw).force
            t_fem = time.perf_counter() - t0
            laws = {law: product_force(mesh, law, nu, top, z_fix, sphere, depth) / mixed for law in LAWS}
            print(f"{label} ({mesh.vertex_count} vertices), nu {nu}: P2/P0 {mixed:.4f} N (P2 {plain / mixed:.3f} of it; {t_fem:.0f} s); "
                  + ", ".join(f"{law} {r:.3f}" for law, r in laws.items()), flush=True)


if __name__ == "__main__":
    main()
