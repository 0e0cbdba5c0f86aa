"""Springs from a material: does a spring network derived by almsdm_warp.tissue.material behave like it?

Static, linear solves of the network (a sparse stiffness matrix assembled here, in SciPy, apart from
the project's kernels), against the material it was derived from:

(a) a tet box pulled along x (uniaxial stress: rollers on x = 0, y = 0, z = 0, the face x = L moved),
    structured (6 tets per cube) and Delaunay-jittered, at three resolutions: effective E and nu;
(b) a flat membrane pulled in its plane (right, equilateral and jittered triangles): effective E t, nu;
(c) the Poisson correction (law "young" or "indentation") at nu = 0.3, 0.45, 0.49: the network's
    Young's and indentation moduli, E/(1-nu^2), against the material's;
(d) a flat punch pressed into a tet block, the network against linear finite elements (P1 tets of
    almsdm_warp.evaluation.fem) on the same mesh and supports.

    python scripts/material_check.py          # the tables of docs/calibration.md, "Springs from a material"

About 40 s on 2 CPU cores.
"""

from __future__ import annotations

import itertools
import sys

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay

from almsdm_warp.evaluation import fem
from almsdm_warp.mesh.topology import tet_signed_volumes, unique_edges
from almsdm_warp.tissue.material import Material, edge_stiffness


# -- meshes ----------------------------------------------------------------------------------------
def grid_points(n, size, dim):
    """The (n+1)^dim nodes of a regular grid over [0, size[0]] x ... , shape [(n+1)^dim, dim]."""
    axes = [np.linspace(0.0, s, n + 1) for s in size[:dim]]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)


def jitter(points, size, h, amount, seed):
    """Move each node by up to `amount` x h along every axis on which it is not on the boundary."""
    rng = np.random.default_rng(seed)
    p = points + rng.uniform(-amount * h, amount * h, points.shape)
    on_face = np.isclose(points, 0.0) | np.isclose(points, np.asarray(size[: points.shape[1]]))
    p[on_face] = points[on_face]
    return p


def delaunay(points):
    """Delaunay simplices of `points`, without the flat ones, positively oriented."""
    simplices = Delaunay(points).simplices.astype(np.int64)
    p = points[simplices]
    det = np.linalg.det(p[:, 1:] - p[:, :1])
    keep = np.abs(det) > 1e-9 * np.abs(det).max()
    simplices, det = simplices[keep], det[keep]
    flip = det < 0
    simplices[flip, :2] = simplices[flip, 1::-1]
    return simplices


def tet_box(n, size=(1.0, 1.0, 1.0), kind="structured", seed=0):
    """(vertices, tets) of a box cut into n cells a side: 6 tets per cube ("structured"), or Delaunay of
    the grid's nodes jittered ("jittered"), or of its boundary nodes jittered and as many interior
    nodes drawn uniformly at random ("random": no preferred edge direction)."""
    points = grid_points(n, size, 3)
    if kind in ("jittered", "random"):
        p = jitter(points, size, min(size) / n, 0.25, seed)
        if kind == "random":
            inside = np.all((points > 1e-9) & (points < np.asarray(size) - 1e-9), axis=1)
            rng = np.random.default_rng(seed + 1)
            p[inside] = rng.uniform(0.0, 1.0, (inside.sum(), 3)) * np.asarray(size)
        return p, delaunay(p)
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    tets = []
    for perm in itertools.permutations(range(3)):
        corner = np.zeros(3, dtype=int)
        path = [corner.copy()]
        for axis in perm:
            corner[axis] = 1
            path.append(corner.copy())
        tets.append(np.stack([idx[c[0]: n + c[0], c[1]: n + c[1], c[2]: n + c[2]].ravel() for c in path], axis=1))
    tets = np.concatenate(tets)
    vol = tet_signed_volumes(points, tets)
    tets[vol < 0, :2] = tets[vol < 0, 1::-1]
    return points, tets


def membrane(n, size=(1.0, 1.0), kind="right", seed=0):
    """(vertices [x, y], triangles) of a rectangle: squares halved, equilateral rows, or jittered Delaunay."""
    if kind == "equilateral":
        h = size[0] / n
        rows = int(round(size[1] / (h * np.sqrt(3) / 2)))
        pts = []
        for j in range(rows + 1):
            xs = np.arange(n + 1) * h + (h / 2 if j % 2 else 0.0)
            xs = np.concatenate([[0.0], xs[xs < size[0] - 1e-9], [size[0]]]) if j % 2 else xs
            pts.append(np.column_stack([xs, np.full(len(xs), j * h * np.sqrt(3) / 2)]))
        pts = np.concatenate(pts)
        return pts, delaunay(pts)
    points = grid_points(n, size, 2)
    if kind == "jittered":
        return (p := jitter(points, size, min(size) / n, 0.25, seed)), delaunay(p)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return points, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


# -- linear statics ----------------------------------------------------------------------------------
def edge_block_matrix(edges, blocks, n_points):
    """Assemble one [dim, dim] block B per edge ij (+B at ii and jj, -B at ij and ji), CSR [dim n, dim n]."""
    dim = blocks.shape[1]
    dof = lambda v: (v[:, None] * dim + np.arange(dim)).reshape(-1, dim)  # noqa: E731
    i, j = dof(edges[:, 0]), dof(edges[:, 1])
    rows, cols, vals = [], [], []
    for a, b, sign in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
        rows.append(np.repeat(a, dim, axis=1).ravel())
        cols.append(np.tile(b, (1, dim)).ravel())
        vals.append(sign * blocks.reshape(len(edges), -1).ravel())
    n = n_points * dim
    return sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)).tocsr()


def spring_matrix(points, edges, k):
    """Stiffness matrix of linear springs on `edges`: block k n n^T, shape [dim n, dim n], CSR."""
    d = points[edges[:, 1]] - points[edges[:, 0]]
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    return edge_block_matrix(edges, k[:, None, None] * unit[:, :, None] * unit[:, None, :], len(points))


def fem_matrix(points, tets, young, nu):
    """Stiffness matrix of linear (P1) tetrahedra, shape [3 n, 3 n]: almsdm_warp.evaluation.fem's."""
    return fem.stiffness(points, np.asarray(tets, dtype=np.int64), young, nu)


def solve_fixed(K, fixed, value):
    """Displacements u with u[fixed] = value and zero force on every other dof; also the reactions K u."""
    mask = np.zeros(K.shape[0], dtype=bool)
    mask[fixed] = True
    values = np.zeros(K.shape[0])
    values[fixed] = value
    u, _ = fem.solve_dirichlet(K, mask, values)
    return u, K @ u


def uniaxial(points, K, strain=1e-3):
    """(E_eff [force / area], nu_eff) of a box [0, size] pulled along x with rollers on the faces at 0.

    For a membrane, E_eff is force per unit width (E t). The lateral strain is the mean displacement
    of the far face over the box's size (the average strain, for any field)."""
    dim = points.shape[1]
    size = points.max(axis=0)
    lo = [np.flatnonzero(np.isclose(points[:, a], 0.0)) for a in range(dim)]
    far = [np.flatnonzero(np.isclose(points[:, a], size[a])) for a in range(dim)]
    fixed = np.concatenate([lo[a] * dim + a for a in range(dim)] + [far[0] * dim])
    value = np.concatenate([np.zeros(sum(len(x) for x in lo)), np.full(len(far[0]), strain * size[0])])
    fixed, first = np.unique(fixed, return_index=True)
    u, reaction = solve_fixed(K, fixed, value[first])
    force = reaction[far[0] * dim].sum()
    area = np.prod(size[1:])
    lateral = [u[far[a] * dim + a].mean() / size[a] for a in range(1, dim)]
    return force / area / strain, -np.mean(lateral) / strain


def punch(points, K, radius, depth=1e-3):
    """Force to press a flat, frictionless punch of `radius` (centred on the top face) `depth` into a
    block whose bottom face is fixed: the top nodes within the radius move down, free sideways."""
    size = points.max(axis=0)
    bottom = np.flatnonzero(np.isclose(points[:, 2], 0.0))
    r = np.hypot(points[:, 0] - size[0] / 2, points[:, 1] - size[1] / 2)
    under = np.flatnonzero(np.isclose(points[:, 2], size[2]) & (r <= radius + 1e-9))
    fixed = np.concatenate([(bottom[:, None] * 3 + np.arange(3)).ravel(), under * 3 + 2])
    value = np.concatenate([np.zeros(3 * len(bottom)), np.full(len(under), -depth)])
    _, reaction = solve_fixed(K, fixed, value)
    return -reaction[under * 3 + 2].sum()


# -- the tables ----------------------------------------------------------------------------------------
def network_moduli(points, cells, material, law="indentation"):
    """(E_eff / E, nu_eff) of the network derived from `material` on a tet box or membrane."""
    if points.shape[1] == 3:
        edges = unique_edges(np.zeros((0, 3)), cells)
        k = edge_stiffness(material, points, edges, None, cells, law=law)
        young = material.youngs_modulus
    else:
        edges = unique_edges(cells)
        p3 = np.column_stack([points, np.zeros(len(points))])
        k = edge_stiffness(material, p3, edges, cells)
        young = material.youngs_modulus * material.thickness
    e_eff, nu_eff = uniaxial(points, spring_matrix(points, edges.astype(np.int64), k))
    return e_eff / young, nu_eff


def table_refinement(make_mesh, kinds, material, header, resolutions=(4, 8, 16)):
    """One row per mesh kind and resolution: sizes, E_net / E and nu_net (law young for tets)."""
    print(header)
    print("|---|---|---|---|---|---|")
    for kind in kinds:
        for n in resolutions:
            p, t = make_mesh(n, kind=kind)
            ratio, nu = network_moduli(p, t, material, law="young")
            print(f"| {kind} | {n} | {len(p)} | {len(t)} | {ratio:.3f} | {nu:.3f} |")


def table_poisson(n=8):
    p, t = tet_box(n, kind="jittered")
    print("| nu (material) | law | E_net / E | nu_net | indentation modulus E_net/(1-nu_net^2) over E/(1-nu^2) |")
    print("|---|---|---|---|---|")
    for nu in (0.3, 0.45, 0.49):
        for law in ("young", "indentation"):
            ratio, nu_net = network_moduli(p, t, Material(youngs_modulus=1.0, poisson_ratio=nu), law)
            print(f"| {nu} | {law} | {ratio:.3f} | {nu_net:.3f} | {ratio * (1 - nu**2) / (1 - nu_net**2):.3f} |")


def table_punch(resolutions=(6, 12, 18)):
    size = (1.0, 1.0, 0.5)
    print("| nu | cells (x) | network / FEM, law young | network / FEM, law indentation |")
    print("|---|---|---|---|")
    for nu in (0.3, 0.45):
        mat = Material(youngs_modulus=1.0, poisson_ratio=nu)
        for n in resolutions:
            p, t = tet_box(n, size=size, kind="jittered")
            edges = unique_edges(np.zeros((0, 3)), t).astype(np.int64)
            fem = punch(p, fem_matrix(p, t, 1.0, nu), radius=0.2)
            ratios = [punch(p, spring_matrix(p, edges, edge_stiffness(mat, p, edges, None, t, law=law)), 0.2) / fem
                      for law in ("young", "indentation")]
            print(f"| {nu} | {n} | {ratios[0]:.3f} | {ratios[1]:.3f} |")


def main(argv=None):
    print("(a) tet box, uniaxial stress along x, nu = 0.25, law young\n")
    table_refinement(tet_box, ("structured", "jittered", "random"), Material(youngs_modulus=1.0, poisson_ratio=0.25),
                     "| mesh | cells a side | vertices | tets | E_net / E (law young) | nu_net |")
    print("\n(b) membrane, in-plane uniaxial stress along x\n")
    table_refinement(membrane, ("right", "equilateral", "jittered"), Material(youngs_modulus=1.0, thickness=1.0),
                     "| triangles | cells a side | vertices | triangles | E_net t / (E t) | nu_net |")
    print("\n(c) Poisson correction, jittered tet box 8 cells a side\n")
    table_poisson()
    print("\n(d) flat punch (radius 0.2 on a 1 x 1 x 0.5 block, bottom fixed): network force over P1 FEM\n")
    table_punch()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
