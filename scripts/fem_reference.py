"""Print the finite-element reference for a sphere pressed into tissue, with its convergence.

The ball case of the issue "Tissue, not triangles": a tetrahedral ball of radius 50 mm, E 10 kPa,
nu 0.45, clamped below z = -40 mm, a rigid sphere of radius 50 mm pressed 2 mm at the top; P1 and
P2 tets at several resolutions (graded x 4 toward the contact). Then Hertz's check on a large block.

    python scripts/fem_reference.py [--quick]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from almsdm_warp.evaluation import fem, hertz
from almsdm_warp.mesh import primitives

E, NU = 10e3, 0.45


def _press(vertices, tets, order, **kw):
    start = time.perf_counter()
    result = fem.sphere_press(vertices, tets, young=E, poisson=NU, order=order, **kw)
    return result, time.perf_counter() - start


def ball_table(edges_mm) -> None:
    print("ball R 50 mm, E 10 kPa, nu 0.45, clamped z < -40 mm, sphere R 50 mm, depth 2 mm")
    print(f"Hertz, two 50 mm spheres: {hertz.hertz_force(E, NU, 0.05, 0.002, 0.05):.4f} N, "
          f"a = {hertz.hertz_contact_radius(0.05, 0.002, 0.05) * 1e3:.2f} mm (the ball as a half-space near the contact, no base)")
    print("| edge [mm] | vertices | P2 nodes | P1 force [N] | P2 force [N] | P2 contact radius [mm] | P1 time [s] | P2 time [s] |")
    print("|---|---|---|---|---|---|---|---|")
    for edge in edges_mm:
        vertices, tets = primitives.tet_ball_arrays(50.0, edge, refine_top=4.0)
        kw = dict(sphere_radius=0.05, depth=0.002, fixed=lambda x: fem.clamped_below(x, -0.04))
        p1, t1 = _press(vertices, tets, 1, **kw)
        p2, t2 = _press(vertices, tets, 2, **kw)
        print(f"| {edge:g} | {len(vertices)} | {len(p2.nodes)} | {p1.force:.4f} | {p2.force:.4f} | "
              f"{p2.contact_radius * 1e3:.2f} | {t1:.2f} | {t2:.2f} |", flush=True)


def hertz_block(levels) -> None:
    radius, depth = 0.02, 0.0002
    expected = hertz.hertz_force(E, NU, radius, depth)
    a = hertz.hertz_contact_radius(radius, depth)
    print(f"\nHertz check: sphere R 20 mm, depth 0.2 mm into an 80 x 80 x 40 mm block (quarter model, "
          f"clamped base): Hertz {expected * 1e3:.3f} mN, a = {a * 1e3:.2f} mm")
    print("| grid | P2 nodes | P2 force [mN] | / Hertz | contact radius [mm] | time [s] |")
    print("|---|---|---|---|---|---|")
    for xs in levels:
        xs = np.asarray(xs, dtype=float)
        vertices, tets = primitives.tet_grid_arrays(xs, xs, -xs[::-1])
        fixed = lambda x: fem.clamped_below(x, -0.04 + 1e-9) | fem.symmetry_planes(x, "xy")  # noqa: E731
        r, t = _press(vertices, tets, 2, sphere_radius=radius, depth=depth, fixed=fixed, copies=4)
        print(f"| {len(xs)}^3 | {len(r.nodes)} | {r.force * 1e3:.3f} | {r.force / expected:.3f} | "
              f"{r.contact_radius * 1e3:.2f} | {t:.1f} |", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the coarse levels only (seconds)")
    args = parser.parse_args()
    ball_table([16, 14, 12] if args.quick else [16, 14, 12, 10, 8])
    coarse = [0, 1, 2, 3, 5, 8, 13, 20, 30, 40]
    fine = [0, 0.5, 1, 1.5, 2, 2.5, 3, 4, 6, 9, 14, 20, 30, 40]
    hertz_block([coarse] if args.quick else [coarse, fine])


if __name__ == "__main__":
    main()
