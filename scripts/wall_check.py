"""A wall of tets (tissue/wall.py) against the membrane on a foundation and finite elements, on tissue over bone.

The slab of evaluation/depth_layers.py (30 x 30 x 10 mm, its base fixed, E 10 kPa, a 5 mm sphere pressed 2 mm) made
from its top face alone: the face extruded 10 mm down into a wall of tets (layers of the face's edge), pressed by the
neo-Hookean law; the same face as a membrane 10 mm thick on a Winkler foundation of the layer's oedometric stiffness
(kappa = E (1 - nu) / ((1 + nu) (1 - 2 nu)) / t: a column of the layer compressed alone, the foundation's own
model), pressed by the springs law; the P1 neo-Hookean FEM of the wall's tets and the locking-free P2/P0 of them.

    python scripts/wall_check.py [--edges 4,3,2] [--poisson 0.45]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from almsdm_warp.evaluation import depth_layers as dl
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.wall import extrude_wall

THICKNESS_MM = 10.0


def top_face(h: float) -> TissueMesh:
    """The slab's top face (dl.graded's coordinates, z = 10 mm), two triangles a cell, wound upward."""
    xs = dl.graded(h, dl.SLAB["side_mm"] / 2)
    n = len(xs)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    points = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, THICKNESS_MM)])
    cells = [(i * n + j, (i + 1) * n + j, i * n + j + 1, (i + 1) * n + j + 1) for i in range(n - 1) for j in range(n - 1)]
    return TissueMesh.from_arrays(points, np.array([t for a, b, c, d in cells for t in ((a, b, d), (a, d, c))]))


def membrane_force(face: TissueMesh, top: int, poisson: float) -> float:
    """The membrane on its foundation, global model, implicit, the depth_layers press: its hold force [N]."""
    from almsdm_warp.protocol.palpation import Palpation

    t = THICKNESS_MM * 1e-3
    oedometric = dl.E * (1 - poisson) / ((1 + poisson) * (1 - 2 * poisson))
    material = Material(youngs_modulus=dl.E, poisson_ratio=poisson, density=1000.0, thickness=t, foundation=oedometric / t,
                        rayleigh_alpha=100.0)
    pal = Palpation(face, material, rings="global", law="springs", integrator="implicit", dt=dl.PRESS["dt"],
                    probe_radius=dl.SLAB["sphere_mm"] * 1e-3)
    depth = dl.SLAB["depth_mm"] * 1e-3
    pal.touch(top, depth)
    return pal.press(depth, ramp=dl.PRESS["ramp"], hold=dl.PRESS["hold"], settle=dl.PRESS["dt"]).hold_force_N


def row(h: float, poisson: float) -> dict:
    face = top_face(h)
    wall = extrude_wall(face, THICKNESS_MM * 1e-3, edge=h * 1e-3)
    top = int(np.argmin(np.linalg.norm(face.vertices - [0.0, 0.0, THICKNESS_MM * 1e-3], axis=1)))
    case = dl.Case("slab", f"wall {h:g} mm", wall, top, 1e-5, dl.SLAB["sphere_mm"] * 1e-3, dl.SLAB["depth_mm"] * 1e-3, poisson)
    t0 = time.perf_counter()
    out = {"edge_mm": h, "tets": wall.tet_count, **dl.fem_force(case), **dl.p2p0_force(case)}
    press = dl.law_press(case, "neo-hookean")
    out.update(wall_N=press["force_N"], inverted=press["inverted_tets"], membrane_N=membrane_force(face, top, poisson),
               seconds=time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--edges", default="4,3,2", help="the face's edges under the probe [mm], comma list")
    parser.add_argument("--poisson", type=float, default=dl.POISSON)
    args = parser.parse_args()
    print(f"slab on bone, {THICKNESS_MM:g} mm, E {dl.E * 1e-3:g} kPa, nu {args.poisson:g}, sphere R {dl.SLAB['sphere_mm']:g} mm "
          f"pressed {dl.SLAB['depth_mm']:g} mm; forces at the end of the hold [N]")
    print("| edge mm | tets | P1 FEM | P2/P0 | wall (neo-Hookean) | / P1 | / P2/P0 | membrane on foundation | / P2/P0 | inverted |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for h in (float(e) for e in args.edges.split(",")):
        r = row(h, args.poisson)
        print(f"| {h:g} | {r['tets']} | {r['fem_N']:.4f} | {r['p2p0_N']:.4f} | {r['wall_N']:.4f} | {r['wall_N'] / r['fem_N']:.3f} | "
              f"{r['wall_N'] / r['p2p0_N']:.3f} | {r['membrane_N']:.4f} | {r['membrane_N'] / r['p2p0_N']:.3f} | {r['inverted']} |",
              flush=True)


if __name__ == "__main__":
    main()
