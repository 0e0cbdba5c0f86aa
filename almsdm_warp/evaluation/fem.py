"""An independent continuum reference: small-strain linear elasticity on tetrahedra (NumPy/SciPy).

It shares no code with the mass-spring model: stiffness from Young's modulus and Poisson's ratio,
linear (P1, 4-node) or quadratic (P2, 10-node) tetrahedra, a clamped support and a rigid
frictionless sphere pressed into the top. SI units throughout.

P1 tets lock in bending and near incompressibility (at nu = 0.45 they are 15-45 % too stiff
at practical sizes); P2 converges quickly and is the reference. Toward nu = 1/2 (0.49-0.499) P2
stiffens too; `mixed=True` (P2 displacements, a pressure constant on each tet, condensed) does not
lock. Large deformation (neo-Hookean): fem_nonlinear.py. Contact is node-to-rigid-sphere
with the gap and its normal taken along z: for a shallow press (depth << sphere radius, contact
radius a << R) the sphere's normal at the contact edge tilts by a/R only, and z is the direction
Hertz's linear theory uses too.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

# local edges of a tet, in the order of the P2 edge nodes 4..9
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])
# 4-point rule on a tet, exact for quadratics (P2 stiffness on straight tets): barycentric points
_A, _B = 0.5854101966249685, 0.1381966011250105
_QUAD_POINTS = np.full((4, 4), _B) + np.eye(4) * (_A - _B)


def lame(young: float, poisson: float) -> tuple[float, float]:
    """Lame parameters (lambda, mu) [Pa] from E [Pa] and nu."""
    if young <= 0 or not -1.0 < poisson < 0.5:
        raise ValueError(f"need E > 0 and -1 < nu < 0.5, got E={young}, nu={poisson}")
    return young * poisson / ((1 + poisson) * (1 - 2 * poisson)), young / (2 * (1 + poisson))


def p2_nodes(vertices: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic tets: (nodes [n + edges, 3], elements [t, 10]); nodes 4..9 sit mid-edge."""
    pairs = np.sort(tets[:, _TET_EDGES].reshape(-1, 2), axis=1)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    mid = 0.5 * (vertices[edges[:, 0]] + vertices[edges[:, 1]])
    elements = np.hstack([tets, len(vertices) + inverse.reshape(-1, 6)])
    return np.vstack([vertices, mid]), elements


def barycentric_gradients(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of the 4 barycentric coordinates [t, 4, 3] and the volumes [t] of tets [t, 4, 3]."""
    jac = np.transpose(corners[:, 1:] - corners[:, :1], (0, 2, 1))  # columns x_k - x_0
    inv = np.linalg.inv(jac)  # rows: gradients of L_1..L_3
    grads = np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)
    return grads, np.linalg.det(jac) / 6.0


def _shape_gradients(grad_l: np.ndarray, order: int) -> list[tuple[float, np.ndarray]]:
    """(weight, shape-function gradients [t, nodes, 3]) at each quadrature point."""
    if order == 1:
        return [(1.0, grad_l)]
    points = []
    for bary in _QUAD_POINTS:
        vertex = (4.0 * bary - 1.0)[None, :, None] * grad_l  # N_i = L_i (2 L_i - 1)
        i, j = _TET_EDGES[:, 0], _TET_EDGES[:, 1]  # N_ij = 4 L_i L_j
        edge = 4.0 * (bary[i][None, :, None] * grad_l[:, j] + bary[j][None, :, None] * grad_l[:, i])
        points.append((0.25, np.concatenate([vertex, edge], axis=1)))
    return points


def stiffness(nodes: np.ndarray, elements: np.ndarray, young: float, poisson: float, *,
              mixed: bool = False) -> sp.csr_matrix:
    """Global stiffness [N/m], shape [3n, 3n] (dof 3 i + c), of P1 ([t, 4]) or P2 ([t, 10]) tets.

    mixed (P2 only): the locking-free P2/P0 element for nearly incompressible bodies (nu -> 1/2):
    an independent pressure constant on each tet, p_e = lambda (1/V_e) int_e div u, condensed
    statically, so the volumetric term is lambda / V_e b_e b_e^T with b_e = int_e grad N (the tet's
    divergence row) in place of lambda int div u div v (the mean-dilatation form of the u-p
    element). Each tet keeps one volume constraint, against about 4 displacement dofs a tet (P1:
    about 0.5, which is why P1 locks); plain P2 keeps four (its quadrature points) and stiffens as
    nu -> 1/2. P2/P0 is a standard Stokes pair (Boffi, Brezzi & Fortin 2013, Mixed Finite Element
    Methods); tests/test_fem_nonlinear.py checks that it does not lock here (Hertz at nu = 0.499).
    """
    lam, mu = lame(young, poisson)
    order = {4: 1, 10: 2}[elements.shape[1]]
    if mixed and order != 2:
        raise ValueError("the mixed (P2/P0) element needs P2 elements [t, 10]; P1/P0 locks like P1")
    grad_l, volume = barycentric_gradients(nodes[elements[:, :4]])
    if (volume <= 0).any():
        raise ValueError(f"tet {int(np.argmin(volume))} has volume {volume.min():.3g} m^3 (needs > 0)")
    k = elements.shape[1]
    ke = np.zeros((len(elements), k, 3, k, 3))
    divergence = np.zeros((len(elements), k, 3))
    eye = np.eye(3)
    for weight, g in _shape_gradients(grad_l, order):
        w = (weight * volume)[:, None, None, None, None]
        # K_aibj = int lambda dN_a/dx_i dN_b/dx_j + mu (dN_a . dN_b delta_ij + dN_a/dx_j dN_b/dx_i)
        if not mixed:
            ke += w * lam * np.einsum("tai,tbj->taibj", g, g)
        ke += w * mu * np.einsum("tak,tbk,ij->taibj", g, g, eye)
        ke += w * mu * np.einsum("taj,tbi->taibj", g, g)
        divergence += (weight * volume)[:, None, None] * g
    if mixed:
        ke += (lam / volume)[:, None, None, None, None] * np.einsum("tai,tbj->taibj", divergence, divergence)
    dofs = (3 * elements[:, :, None] + np.arange(3)).reshape(len(elements), -1)
    rows = np.repeat(dofs, 3 * k, axis=1).ravel()
    cols = np.tile(dofs, (1, 3 * k)).ravel()
    n = 3 * len(nodes)
    return sp.csr_matrix((ke.reshape(-1), (rows, cols)), shape=(n, n))


def factor_spd(matrix: sp.spmatrix):
    """Sparse LU of a symmetric positive definite matrix, pivoting on the diagonal only.

    SPD needs no row pivoting; SuperLU's default partial pivoting swaps rows once lambda >> mu
    (nu near 1/2: the volumetric terms dwarf the rest) and then fills in about 6 x more and
    takes 50-70 x longer (P2, 9030 dofs at nu = 0.499: 60-90 s against 1.2 s).
    """
    return spla.splu(sp.csc_matrix(matrix), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                     options=dict(SymmetricMode=True))


def solve_dirichlet(stiff: sp.spmatrix, fixed: np.ndarray, values: np.ndarray, load=None):
    """Solve K u = f + r with u[fixed] = values: (u [3n], reactions r [3n], zero on free dofs)."""
    fixed = np.asarray(fixed, dtype=bool).ravel()
    u = np.where(fixed, np.asarray(values, dtype=np.float64).ravel(), 0.0)
    f = np.zeros(stiff.shape[0]) if load is None else np.asarray(load, dtype=np.float64).ravel()
    free = ~fixed
    stiff = sp.csr_matrix(stiff)
    rhs = f[free] - stiff[free][:, fixed] @ u[fixed]
    u[free] = factor_spd(stiff[free][:, free]).solve(rhs)
    reactions = stiff @ u - f
    reactions[free] = 0.0
    return u, reactions


@dataclasses.dataclass
class PressResult:
    """A rigid sphere pressed into an elastic body, solved by finite elements."""

    force: float
    """Total contact force [N] on the whole body (a symmetric part's force times its copies)."""
    contact_radius: float
    """Largest distance [m] from the press axis of a node in contact."""
    contact_nodes: np.ndarray
    """Ids of the nodes in contact, int."""
    nodes: np.ndarray
    """Node positions [m], shape [n, 3] (P2: vertices then edge midpoints)."""
    displacement: np.ndarray
    """Nodal displacements [m], shape [n, 3]."""
    iterations: int
    """Active-set iterations to a fixed contact set."""


def clamped_below(nodes: np.ndarray, z_fix: float) -> np.ndarray:
    """Fixed-dof mask [n, 3]: every node with z < z_fix fully fixed (a clamped base)."""
    return np.repeat((nodes[:, 2] < z_fix)[:, None], 3, axis=1)


def symmetry_planes(nodes: np.ndarray, axes: str, centre_xy=(0.0, 0.0), tol: float = 1e-12) -> np.ndarray:
    """Fixed-dof mask [n, 3]: normal displacement fixed on the planes x = cx ('x') and y = cy ('y')."""
    mask = np.zeros((len(nodes), 3), dtype=bool)
    for axis in axes:
        c = {"x": 0, "y": 1}[axis]
        mask[:, c] |= np.abs(nodes[:, c] - centre_xy[c]) <= tol
    return mask


def sphere_gap(nodes: np.ndarray, radius: float, depth: float, centre_xy) -> np.ndarray:
    """Vertical gap [m] from each node up to the sphere's lower surface (negative: overlap).

    The sphere is lowered along z until it first touches a node, then `depth` further.
    Nodes outside the sphere's footprint get an infinite gap.
    """
    r2 = (nodes[:, 0] - centre_xy[0]) ** 2 + (nodes[:, 1] - centre_xy[1]) ** 2
    inside = r2 < radius * radius
    lift = radius - np.sqrt(np.clip(radius * radius - r2, 0.0, None))  # sphere surface above its lowest point
    touch = (nodes[inside, 2] - lift[inside]).max()
    return np.where(inside, touch - depth + lift - nodes[:, 2], np.inf)


# the three corners and three edge nodes of each face of a 10-node tet (the face opposite corner k)
_P2_FACES = np.array([[1, 2, 3, 7, 8, 9], [0, 2, 3, 5, 6, 9], [0, 1, 3, 4, 6, 8], [0, 1, 2, 4, 5, 7]])


def surface_nodes(elements: np.ndarray) -> np.ndarray:
    """Ids of the nodes on boundary faces (faces of one element only) of P1 or P2 tets."""
    width = 3 if elements.shape[1] == 4 else 6
    faces = elements[:, _P2_FACES[:, :width]].reshape(-1, width)
    key = np.sort(faces[:, :3], axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return np.unique(faces[counts[inverse.ravel()] == 1])


def _compliance(lu, rows: np.ndarray, n_free: int, chunk: int = 64) -> np.ndarray:
    """C[i, j] = (K_ff^-1)[rows[i], rows[j]]: displacement at row i per unit force at row j."""
    m = len(rows)
    c = np.empty((m, m))
    for start in range(0, m, chunk):
        stop = min(m, start + chunk)
        rhs = np.zeros((n_free, stop - start))
        rhs[rows[start:stop], np.arange(stop - start)] = 1.0
        c[:, start:stop] = lu.solve(rhs)[rows]
    return c


def _active_set(compliance: np.ndarray, gap: np.ndarray, tol: float, max_iter: int = 200):
    """Contact forces p >= 0 with u = -C p <= gap and p (gap - u) = 0: (p, iterations).

    Start from the overlapping nodes; each step releases the nodes whose reaction pulls (p < 0)
    and adds those that penetrate, until the set is fixed.
    """
    active = gap < 0.0
    for iteration in range(1, max_iter + 1):
        p = np.zeros(len(gap))
        idx = np.flatnonzero(active)
        if len(idx):
            p[idx] = np.linalg.solve(compliance[np.ix_(idx, idx)], -gap[idx])
        u = -compliance @ p
        release = active & (p < 0.0)
        add = ~active & (u > gap + tol)
        if not release.any() and not add.any():
            return p, iteration
        # release first: adding while others pull can cycle
        active = active & ~release if release.any() else active | add
    raise RuntimeError(f"the contact set did not settle in {max_iter} iterations")


def solve_contact(stiff, fixed_dofs, surface, gap, *, tol, load=None, first=None):
    """Frictionless one-sided contact along z on `surface` nodes of any linear(ised) stiffness matrix.

    Solves K u = f - sum_c p_c e_z(c), u[fixed] = 0, u_z(c) <= gap(c), p >= 0, p (gap - u_z) = 0.
    stiff [3n, 3n] (dof 3 i + c), fixed_dofs: mask [3n]; surface: node ids that may touch (none
    fixed along z); gap [n] [m] (inf where no contact can be); load f [3n] (default zero); first:
    the nodes tried first (default: those with gap < 0.5 x the deepest overlap). The candidate set
    grows until no surface node outside it penetrates. Returns (u [n, 3], p [n] (>= 0 on the nodes
    in contact, 0 elsewhere), active-set iterations of the last pass).
    """
    n = stiff.shape[0] // 3
    fixed_dofs = np.asarray(fixed_dofs, dtype=bool).ravel()
    free = np.flatnonzero(~fixed_dofs)
    position = np.full(3 * n, -1)
    position[free] = np.arange(len(free))
    stiff = sp.csr_matrix(stiff)
    lu = factor_spd(stiff[free][:, free])
    preload = np.zeros(3 * n)
    if load is not None:
        preload[free] = lu.solve(np.asarray(load, dtype=np.float64).ravel()[free])
    surface = np.asarray(surface, dtype=np.int64)
    if first is None:
        first = surface[gap[surface] < 0.5 * max(-gap[surface].min(), 0.0)]
    candidates = np.asarray(first, dtype=np.int64)
    for _ in range(10):
        rows = position[3 * candidates + 2]
        p, iterations = _active_set(_compliance(lu, rows, len(free)), gap[candidates] - preload[3 * candidates + 2], tol)
        rhs = np.zeros(len(free))
        rhs[rows] = -p
        u = preload.copy()
        u[free] += lu.solve(rhs)
        uz = u[2::3]
        missed = np.setdiff1d(surface[uz[surface] > gap[surface] + tol], candidates)
        if not len(missed):
            break
        candidates = np.union1d(candidates, missed)
    else:
        raise RuntimeError("the contact zone kept growing past the candidate nodes")
    pressure = np.zeros(n)
    pressure[candidates] = p
    return u.reshape(-1, 3), pressure, iterations


def sphere_press(vertices, tets, *, young, poisson, sphere_radius, depth, fixed, order=2, centre_xy=(0.0, 0.0),
                 copies=1, mixed=False) -> PressResult:
    """A rigid frictionless sphere pressed `depth` [m] (from first touch) into the top, along -z.

    vertices [m], tets [t, 4]; `fixed`: a function of the node positions [n, 3] that returns the
    fixed-dof mask [n, 3] (for example ``lambda x: clamped_below(x, -0.04)``); `copies`: how many
    copies of this part the whole body is (4 for a quarter model with two symmetry planes); mixed:
    the locking-free P2/P0 element (order 2; see `stiffness`) for nu near 1/2.
    Contact nodes: surface nodes, constrained along z only (frictionless, shallow press).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    nodes, elements = (vertices, tets) if order == 1 else p2_nodes(vertices, tets)
    stiff = stiffness(nodes, elements, young, poisson, mixed=mixed)
    fixed_dofs = np.asarray(fixed(nodes), dtype=bool).ravel()
    gap = sphere_gap(nodes, sphere_radius, depth, centre_xy)
    surface = surface_nodes(elements)
    surface = surface[~fixed_dofs[3 * surface + 2]]
    u, p, iterations = solve_contact(stiff, fixed_dofs, surface, gap, tol=1e-9 * depth,
                                     first=surface[gap[surface] < 0.5 * depth])
    return press_result(nodes, u, p, iterations, centre_xy, copies)


def press_result(nodes, u, p, iterations, centre_xy=(0.0, 0.0), copies=1) -> PressResult:
    """PressResult of a contact solve: total force, contact radius about the press axis, contact nodes."""
    touching = np.flatnonzero(p > 0.0)
    radial = np.hypot(nodes[touching, 0] - centre_xy[0], nodes[touching, 1] - centre_xy[1])
    return PressResult(
        force=float(p.sum()) * copies,
        contact_radius=float(radial.max()) if len(radial) else 0.0,
        contact_nodes=touching,
        nodes=nodes,
        displacement=np.asarray(u).reshape(-1, 3),
        iterations=iterations,
    )
