"""Which springs match the continuum under a real probe: static presses of the spring network.

The network derived by almsdm_warp.tissue.material (a sparse stiffness matrix assembled here, in
SciPy, apart from the project's kernels) is pressed by a rigid frictionless sphere with the same
supports and the same contact (surface nodes, one-sided along z, active set: `fem.solve_contact`) as
the finite-element reference of almsdm_warp.evaluation.fem:

(a) the ball of the issue "Tissue, not triangles": a tet ball of radius 50 mm, E 10 kPa, nu 0.45,
    vertices below z = -40 mm fixed, a sphere of radius 50 mm pressed 2 mm at the top, at four
    resolutions (graded x 4 toward the contact): the network's force with the laws "indentation" and
    "young", linearised and with large-strain springs (Newton), against quadratic (P2) elements on
    the same mesh;
(b) an icosphere of radius 50 mm (a vertex at the top pole), subdivisions 4, 5, 6, a sphere of
    radius 10 mm pressed 5 mm: a membrane (E t) on a Winkler foundation (kappa), the force at each
    subdivision, and the foundation alone against its closed form.

    python scripts/spring_vs_fem.py [--quick]

About 12 minutes on 2 CPU cores, most of it the large-strain membrane at subdivision 5 (--quick:
the coarse levels, about 30 s). Subdivision 6 is solved for the foundation alone.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.integrate import quad

from almsdm_warp.evaluation import fem
from almsdm_warp.evaluation.continuum import pole_icosphere
from almsdm_warp.mesh import primitives
from almsdm_warp.mesh.topology import unique_edges
from almsdm_warp.tissue.material import Material, anchor_stiffness, edge_stiffness

sys.path.insert(0, str(Path(__file__).resolve().parent))
from material_check import edge_block_matrix  # noqa: E402

NO_TRIANGLES = np.zeros((0, 3), dtype=np.int64)


# -- the spring network, linearised and large-strain -------------------------------------------------
def spring_forces(x, rest, edges, k):
    """Internal forces dE/dx [n, 3] of springs k (|x_ij| - l0) along each edge (eq. (4)), x [n, 3]."""
    d = x[edges[:, 1]] - x[edges[:, 0]]
    length = np.linalg.norm(d, axis=1)
    rest_length = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1)
    t = (k * (length - rest_length) / length)[:, None] * d
    f = np.zeros_like(x)
    np.add.at(f, edges[:, 1], t)
    np.add.at(f, edges[:, 0], -t)
    return f


def spring_tangent(x, rest, edges, k):
    """Tangent stiffness [3n, 3n] of those springs: per edge k [(1 - l0/l) I + (l0/l) n n^T]."""
    d = x[edges[:, 1]] - x[edges[:, 0]]
    length = np.linalg.norm(d, axis=1)
    ratio = np.linalg.norm(rest[edges[:, 1]] - rest[edges[:, 0]], axis=1) / length
    n = d / length[:, None]
    blocks = (k * (1.0 - ratio))[:, None, None] * np.eye(3) + (k * ratio)[:, None, None] * n[:, :, None] * n[:, None, :]
    return edge_block_matrix(edges, blocks, len(x))


def network_press(points, edges, k, anchors, fixed_dofs, surface, gap, *, large_strain=False, tol=1e-12,
                  max_newton=30):
    """A rigid sphere's press on a spring network with anchors k_i to rest: (u [n, 3], p [n], Newton steps).

    Linearised: one contact solve with K = sum k_ij n n^T blocks + diag(k_i). Large strain: Newton on
    the nonlinear spring forces, each step a contact solve on the tangent with the remaining gap.
    """
    anchor = sp.diags(np.repeat(anchors, 3))
    u, p, _ = fem.solve_contact(spring_tangent(points, points, edges, k) + anchor, fixed_dofs, surface, gap, tol=tol)
    if not large_strain:
        return u, p, 0
    for step in range(1, max_newton + 1):
        x = points + u
        residual = spring_forces(x, points, edges, k) + anchors[:, None] * u
        remaining = gap - u[:, 2]
        first = np.union1d(np.flatnonzero(p > 0.0), surface[remaining[surface] < 0.0])
        du, p, _ = fem.solve_contact(spring_tangent(x, points, edges, k) + anchor, fixed_dofs, surface, remaining,
                                     tol=tol, load=-residual.ravel(), first=first)
        u = u + du
        if np.abs(du).max() < 1e-9 * np.abs(u).max():
            return u, p, step
    raise RuntimeError(f"Newton did not converge in {max_newton} steps (last step {np.abs(du).max():.3g} m)")


# -- (a) the tet ball ------------------------------------------------------------------------------------
BALL = dict(radius_mm=50.0, young=10e3, poisson=0.45, z_fix=-0.04, sphere_radius=0.05, depth=0.002, refine_top=4.0)


def ball_network_force(vertices, tets, law, large_strain=False, case=BALL):
    """The network's contact force [N] on the ball case (module docstring (a)), and the contact radius [m]."""
    material = Material(youngs_modulus=case["young"], poisson_ratio=case["poisson"])
    edges = unique_edges(NO_TRIANGLES, tets).astype(np.int64)
    k = edge_stiffness(material, vertices, edges, None, tets, law=law)
    fixed = fem.clamped_below(vertices, case["z_fix"]).ravel()
    surface = fem.surface_nodes(tets)
    surface = surface[~fixed[3 * surface + 2]]
    gap = fem.sphere_gap(vertices, case["sphere_radius"], case["depth"], (0.0, 0.0))
    u, p, _ = network_press(vertices, edges, k, np.zeros(len(vertices)), fixed, surface, gap,
                            large_strain=large_strain, tol=1e-9 * case["depth"])
    result = fem.press_result(vertices, u, p, 0)
    return result.force, result.contact_radius


def ball_fem(vertices, tets, case=BALL):
    """Quadratic-element (P2) solve of the same press on the same mesh: fem.PressResult."""
    return fem.sphere_press(vertices, tets, young=case["young"], poisson=case["poisson"], order=2,
                            sphere_radius=case["sphere_radius"], depth=case["depth"],
                            fixed=lambda x: fem.clamped_below(x, case["z_fix"]))


def ball_table(edges_mm):
    print("(a) tet ball R 50 mm, E 10 kPa, nu 0.45, fixed below z = -40 mm, sphere R 50 mm pressed 2 mm")
    print("network force over P2 FEM on the same mesh (linearised springs | large-strain springs)\n")
    print("| edge [mm] | top edge [mm] | vertices | P2 FEM [N] | indentation lin. | indentation large | "
          "young lin. | young large | contact radius P2 / network [mm] |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for edge in edges_mm:
        vertices, tets = primitives.tet_ball_arrays(BALL["radius_mm"], edge, refine_top=BALL["refine_top"])
        reference = ball_fem(vertices, tets)
        forces = {}
        for law in ("indentation", "young"):
            for large in (False, True):
                forces[law, large] = ball_network_force(vertices, tets, law, large)
        ratios = [forces[key][0] / reference.force for key in
                  (("indentation", False), ("indentation", True), ("young", False), ("young", True))]
        rows.append((edge, reference.force, forces))
        print(f"| {edge:g} | {edge / BALL['refine_top']:g} | {len(vertices)} | {reference.force:.4f} | "
              + " | ".join(f"{r:.3f}" for r in ratios)
              + f" | {reference.contact_radius * 1e3:.2f} / {forces['indentation', False][1] * 1e3:.2f} |", flush=True)
    converged = rows[-1][1]
    print(f"\nagainst the finest P2 force ({converged:.4f} N): " + ", ".join(
        f"edge {edge:g}: indentation lin. {f['indentation', False][0] / converged:.3f}, "
        f"large {f['indentation', True][0] / converged:.3f}" for edge, _, f in rows))


# -- (b) a membrane on a Winkler foundation ----------------------------------------------------------------
def shell_press(vertices, triangles, material, sphere_radius, depth, *, membrane=True, large_strain=True):
    """Force [N] of a sphere pressed `depth` [m] into a membrane (E t) on a foundation (kappa), free body."""
    edges = unique_edges(triangles).astype(np.int64)
    k = edge_stiffness(material, vertices, edges, triangles) if membrane else np.zeros(len(edges))
    anchors = anchor_stiffness(material, vertices, triangles)
    gap = fem.sphere_gap(vertices, sphere_radius, depth, (0.0, 0.0))
    fixed = np.zeros(3 * len(vertices), dtype=bool)
    surface = np.flatnonzero(np.isfinite(gap))
    u, p, _ = network_press(vertices, edges, k, anchors, fixed, surface, gap, large_strain=large_strain and membrane,
                            tol=1e-9 * depth)
    return float(p.sum())


def winkler_force_flat(kappa, sphere_radius, depth):
    """A rigid sphere pressed `depth` into a flat Winkler foundation: kappa x the cap's volume [N]."""
    return kappa * np.pi * depth**2 * (sphere_radius - depth / 3.0)


def winkler_force_on_sphere(kappa, body_radius, sphere_radius, depth):
    """The same on a spherical body's top: kappa x the integral over its surface of the vertical overlap [N].

    Body z_b(r) = sqrt(Rb^2 - r^2) (area element Rb / z_b 2 pi r dr), probe bottom z_p(r) = Rb - d +
    Rs - sqrt(Rs^2 - r^2), overlap z_b - z_p where positive: the anchors' reaction to a push along z."""
    def overlap(r):
        zb = np.sqrt(body_radius**2 - r**2)
        return max(zb - (body_radius - depth + sphere_radius - np.sqrt(sphere_radius**2 - r**2)), 0.0)

    edge = sphere_radius * (1.0 - 1e-12)
    value, _ = quad(lambda r: overlap(r) * body_radius / np.sqrt(body_radius**2 - r**2) * 2.0 * np.pi * r, 0.0, edge,
                    limit=200, points=[np.sqrt(depth * (2 * sphere_radius - depth))])
    return kappa * value


SHELL_MATERIALS = (
    ("E 10 kPa, t 2 mm, kappa 1 kPa/mm", Material(10e3, thickness=2e-3, foundation=1e6)),
    ("E 10 kPa, t 5 mm, kappa 0.2 kPa/mm", Material(10e3, thickness=5e-3, foundation=0.2e6)),
    ("E 30 kPa, t 5 mm, kappa 0.1 kPa/mm", Material(30e3, thickness=5e-3, foundation=0.1e6)),
)


def shell_table(subdivisions, sphere_radius=0.01, depth=0.005, network_max=5):
    print("\n(b) icosphere R 50 mm, sphere R 10 mm pressed 5 mm: membrane E t on a Winkler foundation kappa")
    kappa = SHELL_MATERIALS[0][1].foundation
    print(f"foundation alone, kappa {kappa * 1e-6:g} kPa/mm: flat closed form kappa pi d^2 (R - d/3) = "
          f"{winkler_force_flat(kappa, sphere_radius, depth):.4f} N; on the R 50 mm sphere (quadrature) "
          f"{winkler_force_on_sphere(kappa, 0.05, sphere_radius, depth):.4f} N\n")
    print("| material | subdivisions | vertices | edge [mm] | foundation only [N] | membrane + foundation, "
          "linearised [N] | large strain [N] | membrane share (large) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, material in SHELL_MATERIALS:
        for s in subdivisions:
            v, t = pole_icosphere(50.0, s)
            e = unique_edges(t)
            edge = np.linalg.norm(v[e[:, 1]] - v[e[:, 0]], axis=1).mean() * 1e3
            alone = shell_press(v, t, material, sphere_radius, depth, membrane=False)
            if s > network_max:  # the dense contact compliance of ~1500 nodes: minutes per Newton step
                print(f"| {name} | {s} | {len(v)} | {edge:.2f} | {alone:.4f} | - | - | - |", flush=True)
                continue
            linear = shell_press(v, t, material, sphere_radius, depth, large_strain=False)
            large = shell_press(v, t, material, sphere_radius, depth)
            print(f"| {name} | {s} | {len(v)} | {edge:.2f} | {alone:.4f} | {linear:.4f} | {large:.4f} | "
                  f"{1 - alone / large:.2f} |", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the coarse levels only")
    args = parser.parse_args(argv)
    ball_table([16, 12] if args.quick else [16, 12, 10, 8])
    shell_table([4, 5] if args.quick else [4, 5, 6])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
