"""Stable neo-Hookean linear tetrahedra: a volumetric law for tet meshes (Smith, de Goes & Kim 2018).

Energy density of a tet with deformation gradient F = D_s D_m^-1 (D_s, D_m: its edge vectors from
corner 0, deformed and at rest):

    Psi(F) = mu / 2 (tr(F^T F) - 3) + lambda / 2 (J - alpha)^2,    J = det F,   alpha = 1 + mu / lambda

defined through inversion (J <= 0: no log, no division), at rest stress-free. Linearized at rest it
is linear elasticity of Lame parameters (mu, lambda - mu), so the model stores lambda = lambda_0 +
mu_0 for a material's (mu_0, lambda_0) (almsdm_warp.tissue.laws). First Piola stress
P = mu F + lambda (J - alpha) dJ/dF, dJ/dF = [f1 x f2, f2 x f0, f0 x f1] (f_i the columns of F); the
tet's force on corner c is -V_0 P b_c, b_c the gradient of c's barycentric coordinate at rest (the
rows of D_m^-1 for corners 1..3, minus their sum for corner 0), which each entry keeps.

The law's entries are a vertex's incident tets (vertex-to-tet incidence, CSR): entry k holds the
tet's four vertex ids (`ENTRY_TOPOLOGY`) and its rest data with the vertex's corner (`TetEntry`).
`vertex_force` gathers them as the springs law gathers its springs: each tet's force is computed
by each of its free corners (no atomics: the same bits on every run).

`implicit_row` assembles a vertex's row of the implicit step with the Gauss-Newton part of each
tet's Hessian, K_ab = V_0 (mu (b_a . b_b) I + lambda (dJ b_a)(dJ b_b)^T) (b_c: the gradient of
corner c's barycentric coordinate at rest): positive semi-definite in every state, inverted tets
included. It leaves out lambda (J - alpha) times J's curvature, which is indefinite (at rest it is
mu (b_b b_a^T - b_a b_b^T), the rotation-free part of linear elasticity's shear block); the forces
are exact, so a held press settles to the same static state.
"""

from typing import Any

import warp as wp

from .springs import anchor_force, anchor_row, row_unknown

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.struct
class TetEntry:
    """One (tet, corner) incidence: the tet's rest data and which of its corners the vertex is."""

    dm_inv: wp.mat33
    """D_m^-1, the inverse of the rest edge matrix [1/m]."""
    volume: float
    """Rest volume V_0 [m^3]."""
    mu: float
    """mu [Pa]."""
    lam: float
    """lambda [Pa] (the material's lambda_0 + mu_0: see the module's docstring)."""
    corner: int
    """The vertex's corner in the tet, 0..3."""
    gradient: wp.vec3
    """b: the gradient of that corner's barycentric coordinate at rest [1/m] (a row of D_m^-1; corner 0:
    minus their sum), so that the tet's force on the corner is -V_0 P b."""


VOLUMETRIC = True
"""The law's entries are a vertex's incident tets (a batch builds them as local tets)."""

ENTRY_TOPOLOGY = wp.array(dtype=wp.vec4i)
"""Entry k: the four vertex ids of its tet."""
ENTRY_PARAMS = wp.array(dtype=TetEntry)
"""Entry k: its tet's rest data and corner."""


@wp.struct
class Entries:
    """The law's entries as one kernel argument (Model.entries): CSR offsets, topology, parameters."""

    offsets: wp.array(dtype=wp.int32)
    topology: ENTRY_TOPOLOGY
    params: ENTRY_PARAMS


@wp.func
def column(m: wp.mat33, c: int):
    return wp.vec3(m[0, c], m[1, c], m[2, c])


@wp.func
def tet_state(q: Any, t: wp.vec4i, p: TetEntry):
    # the tet's deformation gradient F = D_s D_m^-1 and dJ/dF = [f1 x f2, f2 x f0, f0 x f1]
    x0 = q[t[0]]
    F = wp.matrix_from_cols(q[t[1]] - x0, q[t[2]] - x0, q[t[3]] - x0) * p.dm_inv
    f0 = column(F, 0)
    f1 = column(F, 1)
    f2 = column(F, 2)
    return F, wp.matrix_from_cols(wp.cross(f1, f2), wp.cross(f2, f0), wp.cross(f0, f1))


@wp.func
def tet_corner_force(F: wp.mat33, dJ: wp.mat33, p: TetEntry):
    # the tet's elastic force on its corner: -dE/dx = -V_0 P b with E = V_0 Psi(F), P = mu F + lambda (J - alpha) dJ
    J = wp.dot(column(F, 0), column(dJ, 0))
    alpha = 1.0 + p.mu / p.lam
    return (-p.volume) * (p.mu * (F * p.gradient) + (p.lam * (J - alpha)) * (dJ * p.gradient))


@wp.func
def corner_gradient(dm_inv: wp.mat33, c: int):
    # b_c: the gradient of corner c's barycentric coordinate at rest (rows of D_m^-1; corner 0 minus their sum)
    if c == 0:
        return -wp.vec3(dm_inv[0, 0] + dm_inv[1, 0] + dm_inv[2, 0], dm_inv[0, 1] + dm_inv[1, 1] + dm_inv[2, 1],
                        dm_inv[0, 2] + dm_inv[1, 2] + dm_inv[2, 2])
    return wp.vec3(dm_inv[c - 1, 0], dm_inv[c - 1, 1], dm_inv[c - 1, 2])


@wp.func
def vertex_force(
    x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float,
    begin: int, end: int, topology: Any, params: Any, shift: int, q: Any, qd: Any,
):
    # the internal force on a vertex at x with velocity u: its anchor and damper (scaled by `scale`),
    # eq. (3), then the elastic forces of its incident tets, entries begin..end (tet topology[k], rest
    # data params[k + shift]; corner positions from q)
    f = anchor_force(x, u, x_rest, ka, kda, scale)
    for k in range(begin, end):
        p = params[k + shift]
        F, dJ = tet_state(q, topology[k], p)
        f += tet_corner_force(F, dJ, p)
    return f


@wp.func
def implicit_row(
    x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float, m: float, dt: float,
    begin: int, end: int, topology: Any, params: Any, shift: int, row_begin: int, row_end: int, row_neighbour: Any,
    q: Any, qd: Any, local_of: Any, by_local: int, self_id: int, driven: int, dv_driven: wp.vec3, free_count: int,
    csr_block: Any, csr_local: Any, out_shift: int,
):
    # one vertex's row of (M + dt C + dt^2 K) dv = dt (f0 - dt K v0) - A_ic dv_c (the springs law's
    # implicit_row says what each argument is): the anchor's terms, then each incident tet's force
    # and Gauss-Newton blocks (this module's docstring), the blocks of its other corners added into
    # the row's CSR entries (row_begin..row_end of row_neighbour), which start from zero.
    f, D, Kv = anchor_row(x, u, x_rest, ka, kda, scale, m, dt)
    correction = wp.vec3(0.0)
    for k in range(row_begin, row_end):
        csr_block[k + out_shift] = wp.mat33(0.0)
        csr_local[k + out_shift] = row_unknown(row_neighbour[k], local_of, by_local, self_id, driven, free_count)
    for k in range(begin, end):
        t = topology[k]
        p = params[k + shift]
        F, dJ = tet_state(q, t, p)
        f += tet_corner_force(F, dJ, p)
        b_a = p.gradient
        g_a = dJ * b_a
        for c in range(4):
            b_c = corner_gradient(p.dm_inv, c)
            K = p.volume * (p.mu * wp.dot(b_a, b_c) * wp.identity(n=3, dtype=float) + p.lam * wp.outer(g_a, dJ * b_c))
            vc = t[c]
            Kv += K * qd[vc]
            if c == p.corner:
                D += dt * dt * K
            else:
                for e in range(row_begin, row_end):
                    if row_neighbour[e] == vc:
                        csr_block[e + out_shift] = csr_block[e + out_shift] - dt * dt * K
                if vc == driven:
                    correction -= dt * dt * K * dv_driven
    return f, D, Kv, correction


@wp.func
def static_row(x: wp.vec3, x_rest: wp.vec3, ka: float, begin: int, end: int, topology: Any, params: Any, shift: int, q: Any):
    # the static equilibrium at a vertex whose neighbours are held where they are (velocities zero):
    # its force (anchor and incident tets) and its diagonal stiffness block (the anchor's and the
    # tets' Gauss-Newton blocks, as implicit_row's)
    zero = wp.vec3(0.0)
    f = anchor_force(x, zero, x_rest, ka, 0.0, 1.0)
    D = ka * wp.identity(n=3, dtype=float)
    for k in range(begin, end):
        p = params[k + shift]
        F, dJ = tet_state(q, topology[k], p)
        f += tet_corner_force(F, dJ, p)
        b_a = p.gradient
        g_a = dJ * b_a
        D += p.volume * (p.mu * wp.dot(b_a, b_a) * wp.identity(n=3, dtype=float) + p.lam * wp.outer(g_a, g_a))
    return f, D
