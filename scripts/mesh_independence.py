"""The same press on the same shape at several resolutions: does the force follow the tissue or the triangles?

Hold forces of a rigid sphere pressed into meshes the project makes itself (implicit integrator, held
until steady), for the material model (Material, a real probe radius) and, before/after, the paper's
constants (TissueParams(), the driven vertex, R = 0):

(a) icosphere R 50 mm, subdivisions 4-6, pole on a vertex every level keeps; E 10 kPa, nu 0.45,
    t 2 mm, foundation 1 kPa/mm; a sphere R 10 mm pressed 5 mm at the top; global and local models.
(b) tet ball R 50 mm at three edge lengths (graded x 4 toward the top), E 10 kPa, nu 0.45, vertices
    below z = -40 mm fixed; a sphere R 50 mm pressed 2 mm; global model.
(c) the paper's constants on the same meshes and presses.
(d) the two stomach meshes (if present) at 5 common points: the ratio per point.

Run: python scripts/mesh_independence.py [--quick] [--meshes DIR]. docs/calibration.md holds the table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from almsdm_warp.mesh.io import load_mesh
from almsdm_warp.mesh import primitives
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.params import TissueParams

sys.path.insert(0, str(Path(__file__).resolve().parent))
from spring_vs_fem import pole_icosphere  # noqa: E402  (a script beside this one)

SURFACE = Material(10e3, 0.45, 1000.0, thickness=2e-3, foundation=1e6, damping_ratio=1.0)
"""The icosphere's and stomach's tissue: E 10 kPa, nu 0.45, t 2 mm, kappa 1 kPa/mm, each damper critical."""
SOLID = Material(10e3, 0.45, 1000.0, rayleigh_beta=0.01)
"""The tet ball's tissue: E 10 kPa, nu 0.45; Rayleigh d = 0.01 s x k (its slowest mode near critical)."""
STEADY = 1e-3
"""A hold is steady when its force changed less than this fraction over the hold's last 10%."""


def pole_icosphere_mesh(radius_mm: float, subdivisions: int) -> TissueMesh:
    """The icosphere with a vertex kept by every subdivision on the top pole, as a TissueMesh."""
    vertices, triangles = pole_icosphere(radius_mm, subdivisions)
    return TissueMesh.from_arrays(vertices * 1e3, triangles=triangles, scale=1.0)


def hold_force(mesh, tissue, vertex, depth, *, rings="global", probe_radius=0.0, fixed_below=None, dt=1e-3,
               ramp=0.05, hold=0.1):
    """(hold force [N], change over the hold's last 10% as a fraction, vertices simulated, seconds).

    Raises RuntimeError when the hold is not steady (STEADY)."""
    start = time.perf_counter()
    pal = Palpation(mesh, tissue, rings=rings, integrator="implicit", dt=dt, device="cpu",
                    probe_radius=probe_radius, fixed_below=fixed_below)
    pal.touch(vertex)
    result = pal.press(depth, ramp=ramp, hold=hold, settle=dt)
    force = result.force[: result.release_step]
    tail = force[-max(2, int(round(hold / dt)) // 10):]
    change = float((tail.max() - tail.min()) / force[-1])
    if change >= STEADY:
        raise RuntimeError(f"hold not steady: the force changed {change:.2%} over the last 10% of the hold")
    simulated = mesh.vertex_count if pal.region is None else pal.region_vertices
    return float(force[-1]), change, simulated, time.perf_counter() - start


def top_vertex(mesh) -> int:
    return int(np.argmax(mesh.vertices[:, 2]))


def spread(forces) -> float:
    return max(forces) / min(forces) - 1.0


def row(label, level, vertices, simulated, result):
    force, change, _, seconds = result
    print(f"| {label} | {level} | {vertices} | {simulated} | {force:.4f} | {change:.1e} | {seconds:.1f} |", flush=True)


def icosphere_table(levels, rings_list):
    print("\n(a, c) icosphere R 50 mm, sphere R 10 mm pressed 5 mm at the pole\n")
    print("| model | subdivisions | vertices | simulated | hold force [N] | hold change | run [s] |")
    print("|---|---|---|---|---|---|---|")
    meshes = {s: pole_icosphere_mesh(50.0, s) for s in levels}
    cases = [(f"material, {r if r == 'global' else f'{r} rings'}", dict(tissue=SURFACE, rings=r, probe_radius=0.01))
             for r in ["global", *rings_list]]
    cases.append(("paper's constants, R 0, 4 rings", dict(tissue=TissueParams(), rings=4)))
    for label, case in cases:
        forces = []
        for s, mesh in meshes.items():
            result = hold_force(mesh, case["tissue"], top_vertex(mesh), 0.005, rings=case["rings"],
                                probe_radius=case.get("probe_radius", 0.0))
            row(label, s, mesh.vertex_count, result[2], result)
            forces.append(result[0])
        print(f"| {label}: spread max/min - 1 | | | | {spread(forces):.1%} | | |", flush=True)


def ball_table(edges_mm):
    print("\n(b, c) tet ball R 50 mm (graded x 4 to the top), fixed below z = -40 mm, pressed 2 mm at the top\n")
    print("| model | edge [mm] | vertices | simulated | hold force [N] | hold change | run [s] |")
    print("|---|---|---|---|---|---|---|")
    meshes = {e: primitives.tet_ball(50.0, e, refine_top=4.0) for e in edges_mm}
    cases = (("material, sphere R 50 mm, global", dict(tissue=SOLID, probe_radius=0.05, dt=2e-3, ramp=0.1, hold=0.5)),
             ("paper's constants, R 0, global", dict(tissue=TissueParams(), dt=1e-3, ramp=0.1, hold=1.5)))
    for label, case in cases:
        forces = []
        for e, mesh in meshes.items():
            tissue = case["tissue"]
            result = hold_force(mesh, tissue, top_vertex(mesh), 0.002, fixed_below=-0.04,
                                probe_radius=case.get("probe_radius", 0.0), dt=case["dt"], ramp=case["ramp"],
                                hold=case["hold"])
            row(label, e, mesh.vertex_count, result[2], result)
            forces.append(result[0])
        print(f"| {label}: spread max/min - 1 | | | | {spread(forces):.1%} | | |", flush=True)


def common_points(coarse, fine, count=5):
    """`count` surface vertices of `coarse` spread by farthest-point sampling, and the vertices of
    `fine` nearest to each: (coarse indices, fine indices, distance between the pairs [m])."""
    surface = coarse.surface_vertices
    points = coarse.vertices[surface]
    chosen = [int(np.argmax(points[:, 2]))]
    distance = np.linalg.norm(points - points[chosen[0]], axis=1)
    while len(chosen) < count:
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[-1]], axis=1))
    a = surface[chosen]
    fine_surface = fine.surface_vertices
    gaps = np.linalg.norm(fine.vertices[fine_surface][None, :, :] - coarse.vertices[a][:, None, :], axis=2)
    b = fine_surface[np.argmin(gaps, axis=1)]
    return a, b, gaps.min(axis=1)


def stomach_table(directory: Path, rings="global"):
    paths = [directory / "gca_stomach_1002v.obj", directory / "gca_stomach_5587v.obj"]
    if not all(p.exists() for p in paths):
        print(f"\n(d) stomach pair: not found in {directory}; skipped")
        return
    coarse, fine = (load_mesh(p) for p in paths)
    a, b, gaps = common_points(coarse, fine)
    print(f"\n(d) stomach 1002 v vs 5587 v, sphere R 10 mm pressed 5 mm, {SURFACE.youngs_modulus * 1e-3:g} kPa, "
          f"t {SURFACE.thickness * 1e3:g} mm, kappa {SURFACE.foundation * 1e-6:g} kPa/mm, {rings}\n")
    print("| point | vertex 1002 / 5587 | pair gap [mm] | force 1002 [N] | force 5587 [N] | ratio 5587 / 1002 | run [s] |")
    print("|---|---|---|---|---|---|---|")
    for i, (u, w, gap) in enumerate(zip(a, b, gaps)):
        fa = hold_force(coarse, SURFACE, int(u), 0.005, rings=rings, probe_radius=0.01)
        fb = hold_force(fine, SURFACE, int(w), 0.005, rings=rings, probe_radius=0.01)
        print(f"| {i} | {u} / {w} | {gap * 1e3:.2f} | {fa[0]:.4f} | {fb[0]:.4f} | {fb[0] / fa[0]:.3f} | "
              f"{fa[3] + fb[3]:.1f} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the coarse levels only")
    parser.add_argument("--meshes", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "meshes",
                        help="folder with gca_stomach_1002v.obj and gca_stomach_5587v.obj")
    args = parser.parse_args(argv)
    icosphere_table([4, 5] if args.quick else [4, 5, 6], [4, 8])
    ball_table([12, 10] if args.quick else [12, 10, 8])
    stomach_table(args.meshes)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
