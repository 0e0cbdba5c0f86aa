"""The sliding sphere's force against the static equilibrium of the same model, both integrators.

    python scripts/stroke_static.py [scenes/stomach.obj] [--at 500 1500 2500]

The built-in stroke (10 mm sphere, 8 mm deep, 20 mm/s) runs with ProbeStroke (4 rings, dt 1 ms);
at the given steps of the slide its force is set against an independent answer: the global anchored
spring network (the scene's paper tissue, every vertex free) at rest with the sphere at the same
centre, found by scipy (L-BFGS on the elastic energy plus a one-sided penalty on the surface vertices
inside the sphere, the penalty stiffened to 1e6 N/m; force: the penalty's sum). At 20 mm/s the
dampers (0.1 N s/m a vertex) add about 2 mN a contact vertex: the slide should read the static force.
"""

import argparse

import numpy as np
from scipy.optimize import minimize

from almsdm_warp import load_mesh
from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke
from almsdm_warp.tissue.params import TissueParams

R = 0.01


def static_force(mesh, tissue, centre, radius):
    """The tissue's force [N] on a sphere held at `centre` [m], at the network's equilibrium."""
    V = mesh.vertices.astype(np.float64)
    E = mesh.edges
    r0 = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    ke, ka, surf = tissue.edge_stiffness, tissue.anchor_stiffness, mesh.surface_vertices

    def energy(x, kp):
        X = x.reshape(-1, 3)
        d = X[E[:, 0]] - X[E[:, 1]]
        length = np.linalg.norm(d, axis=1)
        g = ka * (X - V)
        fe = (ke * (length - r0) / length)[:, None] * d
        np.add.at(g, E[:, 0], fe)
        np.add.at(g, E[:, 1], -fe)
        rr = X[surf] - centre
        lr = np.linalg.norm(rr, axis=1)
        pen = np.maximum(radius - lr, 0.0)
        g[surf] += (-kp * pen / lr)[:, None] * rr
        e = 0.5 * ke * np.sum((length - r0) ** 2) + 0.5 * ka * np.sum((X - V) ** 2) + 0.5 * kp * np.sum(pen**2)
        return e, g.ravel()

    x = V.ravel().copy()
    for kp in (1e3, 1e4, 1e5, 1e6):
        x = minimize(energy, x, args=(kp,), jac=True, method="L-BFGS-B",
                     options=dict(maxiter=20000, gtol=1e-10, ftol=1e-16)).x
    rr = x.reshape(-1, 3)[surf] - centre
    lr = np.linalg.norm(rr, axis=1)
    pen = np.maximum(radius - lr, 0.0)
    return -np.sum((1e6 * pen / lr)[:, None] * rr, axis=0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh", nargs="?", default="scenes/stomach.obj")
    ap.add_argument("--at", type=int, nargs="*", default=[500, 1500, 2500], help="steps into the slide")
    args = ap.parse_args()
    mesh = load_mesh(args.mesh)
    path = builtin_stroke(mesh, R)
    checks = np.flatnonzero(path.phase == 1)[args.at]
    forces = {}
    for integrator in ("explicit", "implicit"):
        stroke = ProbeStroke(mesh, probe_radius=R, rings=4, integrator=integrator, device="cpu")
        for k, c in enumerate(path.centre[: checks.max() + 1]):
            f = stroke.step(c)
            if k in checks:
                forces[integrator, k] = f.copy()
    print("slide step | static |F| N | explicit |F| N (diff %) | implicit |F| N (diff %)")
    for s, k in zip(args.at, checks):
        ref = static_force(mesh, TissueParams(), path.centre[k], R)
        row = [f"{s} | {np.linalg.norm(ref):.3f}"]
        for integrator in ("explicit", "implicit"):
            f = forces[integrator, k]
            row.append(f"{np.linalg.norm(f):.3f} ({100 * np.linalg.norm(f - ref) / np.linalg.norm(ref):.2f})")
        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
