"""Stable neo-Hookean linear tetrahedra with average nodal pressure: a volumetric law for tet meshes
that does not lock as tissue nears incompressibility (Smith, de Goes & Kim 2018; Bonet & Burton 1998).

The energy is a sum over tets and a sum over vertices:

    E = sum_t V_t Psi_e(F_t) + sum_a V_a kappa_a / 2 (J_a - 1)^2

- per tet, of deformation gradient F = D_s D_m^-1 (D_s, D_m: its edge vectors from corner 0, deformed
  and at rest), a stable neo-Hookean energy with its own Lame parameters (mu, mu):
  Psi_e = mu / 2 (tr(F^T F) - 3) + mu / 2 (J - 2)^2, J = det F: defined through inversion (no log,
  no division), stress-free at rest, and at rest linear elasticity of Lame parameters (mu, 0): the
  shear, and a bulk modulus of only 2 mu / 3, so that a linear tet has nothing to lock with;
- per vertex a, the volumetric energy of the material's lambda_0 on its nodal volume change
  J_a = sum_t v_t / sum_t V_t over its incident tets (v_t = V_t J_t the deformed volume), with
  kappa_a the volume-weighted mean of their lambda_0 (a lesion's tets are stiffer). Averaging the
  volume change over a vertex's tets is Bonet & Burton's average nodal pressure tet, the locking-free
  linear tet Joldes et al. (2009) use for surgical simulation: a tet mesh has about five times as
  many tets as vertices, so one volume constraint a tet over-constrains it (volumetric locking) and
  one a vertex does not.
At rest the two together are linear elasticity of Lame parameters (mu_0, lambda_0) (bulk modulus
lambda_0 + 2 mu_0 / 3). The nodal pressure p_a = kappa_a (J_a - 1) is a pass of its own before the
forces (`nodal_pressure`, over the region's vertices: free and fixed ring, whose tets outside the
region are at rest); a tet's force on corner c is then

    f_c = -V_t (mu F b_c + (mu (J - 2) + p_t) dJ/dF b_c),   p_t = (p_0 + p_1 + p_2 + p_3) / 4,

dJ/dF = [f1 x f2, f2 x f0, f0 x f1] (f_i the columns of F), b_c the gradient of c's barycentric
coordinate at rest (the rows of D_m^-1 for corners 1..3, minus their sum for corner 0): the exact
gradient of E, so that a held press settles to E's minimum.

The law's entries are a vertex's incident tets (vertex-to-tet incidence, CSR): entry k holds the
tet's four vertex ids (`ENTRY_TOPOLOGY`) and its rest data with the vertex's corner (`TetEntry`).
`vertex_force` gathers them as the springs law gathers its springs: each tet's force is computed
by each of its free corners (no atomics: the same bits on every run). On the CPU the explicit step
instead computes each of the region's tets once (`tet_forces`, all four corners; kernels/region/
volumes.py) and each free vertex sums its tets' forces in entry order: the same forces, rounded once
a tet.

`implicit_row` assembles a vertex's row of the implicit step with a positive semi-definite part of
each tet's Hessian, K_ab = V_0 (mu (b_a . b_b) I + (mu + lambda_0) (dJ b_a)(dJ b_b)^T) (Gauss-Newton):
it leaves out (mu (J - 2) + p_t) times J's curvature, which is indefinite, and puts the nodal
volumetric term on each tet as if its volume change were its own, an upper bound of the nodal
term's stiffness (by Jensen's inequality: sum_a V_a (dJ_a)^2 <= sum_t V_t dJ_t^2), so the step
over-damps the volumetric modes rather than under-damping them. The forces are exact: a held press
settles to the same static state as the explicit step's.
"""

from typing import Any

import warp as wp

from ..index import nonneg
from .tets import ENTRY_PARAMS, ENTRY_TOPOLOGY, VOLUMETRIC, Entries, TetEntry, TetRest, column, nodal_pressure, tet_law  # noqa: F401

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def stress(F: wp.mat33, dJ: wp.mat33, mu: float, pressure: float):
    # the first Piola-Kirchhoff stress P = mu F + (mu (J - 2) + p_t) dJ (the module's docstring), p_t
    # the mean of the tet's corners' nodal pressures
    J = wp.dot(column(F, 0), column(dJ, 0))
    return mu * F + (mu * (J - 2.0) + pressure) * dJ


@wp.func
def entry_force(x: wp.vec3, t: wp.vec4i, p: TetEntry, q: Any, pressure: Any):
    # -V_0 P b_a on the entry's vertex at x written without F (a third of the arithmetic), the tet
    # seen as (i, a, j, k), the vertex a (TetEntry): -V_0 mu F b_a = -(shear . edges from x_i) and
    # -V_0 dJ b_a = -(x_j - x_i) x (x_k - x_i) / 6, the gradient of the deformed volume
    xi = q[nonneg(t[0])]
    eia = x - xi
    eij = q[nonneg(t[2])] - xi
    eik = q[nonneg(t[3])] - xi
    n6 = wp.cross(eij, eik)
    v6 = wp.dot(n6, eia)
    s = p.shear
    pt = 0.25 * ((pressure[nonneg(t[0])] + pressure[nonneg(t[1])]) + (pressure[nonneg(t[2])] + pressure[nonneg(t[3])]))
    return -((s[0] * eia + s[1] * eij + s[2] * eik) + ((p.mu_v6 * v6 - 2.0 * p.mu + pt) * (1.0 / 6.0)) * n6)


@wp.func
def tet_forces(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, x3: wp.vec3, r: TetRest, pressure: float):
    # the forces on the tet's four corners as entry_force writes one: with E the edges from x_0 as
    # columns, -V_0 mu F b_c = -(E r.shear)_c and -V_0 dJ b_c = -(the deformed volume's gradient at x_c)
    # for c = 1..3; corner 0's minus their sum (the forces of a tet sum to zero)
    e1 = x1 - x0
    e2 = x2 - x0
    e3 = x3 - x0
    n1 = wp.cross(e2, e3)
    n2 = wp.cross(e3, e1)
    n3 = wp.cross(e1, e2)
    s = (r.mu_v6 * wp.dot(e1, n1) - 2.0 * r.mu + pressure) * (1.0 / 6.0)
    G = wp.matrix_from_cols(e1, e2, e3) * r.shear
    h1 = -(column(G, 0) + s * n1)
    h2 = -(column(G, 1) + s * n2)
    h3 = -(column(G, 2) + s * n3)
    return -(h1 + h2 + h3), h1, h2, h3


vertex_force, implicit_row, static_row, tet_forces = tet_law(stress, shear=1.0, element_bulk=1.0, entry_force=entry_force,
                                                             tet_forces=tet_forces)
"""The step kernels' functions (kernels/laws/tets.py): the explicit gather from entry_force; Gauss-Newton
blocks V_0 (mu (b_a . b_b) I + (mu + lambda_0) (dJ b_a)(dJ b_b)^T)."""
