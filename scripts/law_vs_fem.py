"""Each tissue law against a neo-Hookean finite-element solve of the same tets: a sphere pressed deep,
and tissue over bone.

    python scripts/law_vs_fem.py [--radius-mm 25] [--edge-mm 4] [--refine 2] [--sphere-mm 10]
        [--depths-mm 2 5 10] [--poisson 0.45] [--json out.json]
    python scripts/law_vs_fem.py --slab --edges-mm 2 1.4 1 [--sphere-mm 5] [--depths-mm 2]
    python scripts/law_vs_fem.py --lesion [--depths-mm 5]

Ball (default): a tet ball (mesh.primitives.tet_ball, graded finer at the top) resting on a support
(vertices below -0.6 R fixed), a rigid frictionless sphere pressed along -z at the top vertex.
--slab: tissue over bone, a slab 10 mm thick on a rigid base (its bottom fixed), 30 x 30 mm, its
tets of `--edges-mm` under the probe (graded to 3x that at its sides), the sphere pressed at the
top face's centre: one row per resolution. --lesion: the ball with a lesion 5x as stiff, radius 10 mm,
its centre 15 mm below the top; the force with it over the force without, each law's against the
FEM's (a modulus a tet: its centroid inside the lesion or not). E 10 kPa throughout. Reference:
evaluation/fem_nonlinear.solve (P1 tets, the classic compressible neo-Hookean energy, augmented-Lagrangian
contact, static; shares no code with the product). Product: the global model of each law (implicit,
damped, 2 ms frames), the force at the end of the hold (a static answer). Prints force / FEM per law
and depth, and the tets each law leaves inverted. An evaluation, not a test.
"""

import argparse
import json
import time

import numpy as np

E = 10e3
"""Young's modulus [Pa] of every case."""


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius-mm", type=float, default=25.0)
    ap.add_argument("--edge-mm", type=float, default=4.0)
    ap.add_argument("--refine", type=float, default=2.0)
    ap.add_argument("--sphere-mm", type=float, default=10.0)
    ap.add_argument("--depths-mm", type=float, nargs="+", default=[2.0, 5.0, 10.0])
    ap.add_argument("--poisson", type=float, default=0.45)
    ap.add_argument("--json", default=None)
    ap.add_argument("--slab", action="store_true", help="tissue over bone: a 10 mm slab on a rigid base")
    ap.add_argument("--edges-mm", type=float, nargs="+", default=[2.0, 1.4, 1.0], help="--slab: its edges under the probe")
    ap.add_argument("--lesion", action="store_true", help="the ball with a stiff lesion: each law's force ratio against the FEM's")
    args = ap.parse_args(argv)
    if args.slab:
        return slab_rows(args)
    from almsdm_warp.warp_init import init_warp

    init_warp()
    from almsdm_warp.mesh.primitives import tet_ball

    R = args.radius_mm * 1e-3
    mesh = tet_ball(args.radius_mm, args.edge_mm, refine_top=args.refine)
    top = int(np.argmax(mesh.vertices[:, 2]))
    z_fix = -0.6 * R
    print(f"{mesh.summary()}; support below z = {z_fix * 1e3:g} mm; sphere {args.sphere_mm:g} mm at vertex {top}; "
          f"E {E / 1e3:g} kPa, nu {args.poisson}")
    rows = []
    for d in args.depths_mm:
        row = dict(press(mesh, top, z_fix, d * 1e-3, args), depth_mm=d)
        if args.lesion:
            from almsdm_warp.tissue.lesion import Lesion

            lesion = Lesion(tuple(mesh.vertices[top] - np.array([0.0, 0.0, 15e-3])), 10e-3, 5.0)
            stiff = press(mesh, top, z_fix, d * 1e-3, args, lesion)
            row["ratio"] = {k: stiff[f"{k}_N"] / row[f"{k}_N"] for k in ("fem", *LAWS_OF())}
            print(f"lesion 5x, 10 mm, 15 mm below: force ratio FEM {row['ratio']['fem']:.3f}; "
                  + ", ".join(f"{k} {v:.3f} ({v / row['ratio']['fem']:.3f} of FEM's)" for k, v in row["ratio"].items() if k != "fem"),
                  flush=True)
        rows.append(row)
    finish(args, mesh, rows)


def LAWS_OF():
    from almsdm_warp.tissue.laws import LAWS

    return tuple(LAWS)


def press(mesh, top, z_fix, depth, args, lesion=None) -> dict:
    """One press at vertex `top` [depth m] of the reference and of every law: forces [N], inverted tets, seconds."""
    from almsdm_warp.evaluation import fem_nonlinear as fnl
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.laws import LAWS
    from almsdm_warp.tissue.material import Material

    x, tets = mesh.vertices, mesh.tetrahedra.astype(np.int64)
    material = Material(youngs_modulus=E, poisson_ratio=args.poisson, density=1000.0, rayleigh_alpha=100.0)
    t0 = time.perf_counter()
    fixed = np.zeros((len(x), 3), dtype=bool)
    fixed[x[:, 2] < z_fix] = True
    young = E if lesion is None else E * lesion.element_factor(x, tets)
    ref = fnl.solve(x, tets, young=young, poisson=args.poisson, fixed=fixed,
                    sphere=fnl.Sphere(args.sphere_mm * 1e-3, depth, tuple(x[top, :2])), steps=max(4, int(depth * 2e3)))
    row = {"fem_N": ref.force, "fem_s": time.perf_counter() - t0}
    for law in LAWS:
        t0 = time.perf_counter()
        scales = {} if lesion is None else lesion.model_scales(mesh, material, law)
        pal = Palpation(mesh, material, rings="global", law=law, integrator="implicit", dt=2e-3, device="cpu",
                        fixed_below=z_fix, probe_radius=args.sphere_mm * 1e-3, **scales)
        pal.touch(top, depth)
        result = pal.press(depth, ramp=0.2, hold=0.6, settle=0.02)
        row[f"{law}_N"] = float(result.force[result.release_step - 1])
        row[f"{law}_inverted"] = result.inverted_tets  # at the end of the hold
        row[f"{law}_s"] = time.perf_counter() - t0
    laws = ", ".join(f"{law} {row[f'{law}_N'] / ref.force:.3f} ({row[f'{law}_inverted']} inverted)" for law in LAWS)
    print(f"depth {depth * 1e3:g} mm, {mesh.vertex_count} vertices: FEM {ref.force:.4f} N; force / FEM: {laws}", flush=True)
    return row


def graded(h: float, half: float) -> np.ndarray:
    """Coordinates [mm] from -half to half: steps of h within 3 h of 0, growing by 1.25 a step to at most 3 h."""
    side, x, step = [0.0], 0.0, h
    while x < half - 1e-9:
        if x >= 3 * h:
            step = min(step * 1.25, 3 * h)
        x = min(x + step, half)
        side.append(x)
    side = np.array(side)
    return np.concatenate([-side[:0:-1], side])


def slab_rows(args) -> None:
    """Tissue over bone at each of --edges-mm: a 30 x 30 x 10 mm slab, its bottom fixed."""
    from almsdm_warp.mesh.primitives import tet_grid_arrays
    from almsdm_warp.mesh.tissue_mesh import TissueMesh

    rows = []
    for h in args.edges_mm:
        zs = np.linspace(0.0, 10.0, max(int(round(10.0 / h)), 2) + 1)
        vertices, tets = tet_grid_arrays(graded(h, 15.0), graded(h, 15.0), zs)
        mesh = TissueMesh.from_arrays(vertices * 1e3, tetrahedra=tets)
        centre = np.array([0.0, 0.0, 10e-3])
        top = int(np.argmin(np.linalg.norm(mesh.vertices - centre, axis=1)))
        for d in args.depths_mm:
            rows.append(dict(press(mesh, top, 1e-5, d * 1e-3, args), edge_mm=h, depth_mm=d, vertices=mesh.vertex_count))
    finish(args, None, rows)


def finish(args, mesh, rows) -> None:
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"mesh": mesh.summary() if mesh is not None else "slab", "rows": rows}, f, indent=1)


if __name__ == "__main__":
    main()
