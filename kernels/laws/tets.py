"""What every tet law shares (kernels/laws/neo_hookean.py, kernels/laws/corotational.py): a vertex's
incident tets as its entries, the nodal pressure pass, and the functions a law gives the step kernels
(vertex_force, implicit_row, static_row, tet_forces), made by `tet_law` from the law's stress.

A tet law's energy is a sum over its tets of an element energy with a small bulk modulus of its own,
plus a sum over vertices of lambda_0 on each vertex's nodal volume change (average nodal pressure:
Bonet & Burton 1998; neo_hookean.py's docstring says why and how): the element's first Piola-Kirchhoff
stress is the law's (`stress(F, dJ, mu, pressure)`, pressure the tet's mean nodal pressure p_t, added
as p_t dJ/dF), and a tet's force on its corner c is -V_0 P b_c; the rest is here, once.
"""

from typing import Any

import warp as wp

from ..index import nonneg
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
    bulk: float
    """lambda_0 [Pa], the material's first Lame parameter, which the nodal volumetric term carries."""
    corner: int
    """The vertex's corner in the tet, 0..3."""
    gradient: wp.vec3
    """b: the gradient of that corner's barycentric coordinate at rest [1/m] (a row of D_m^-1; corner 0:
    minus their sum), so that the tet's force on the corner is -V_0 P b."""
    shear: wp.vec3
    """mu V_0 (b_a . b_a, b_j . b_a, b_k . b_a) [N/m] (the tet as (i, a, j, k): the vertex a is corner 1),
    so that mu V_0 F b_a = shear[0] (x_a - x_i) + shear[1] (x_j - x_i) + shear[2] (x_k - x_i)."""
    mu_v6: float
    """mu / (6 V_0) [Pa/m^3]: mu J = mu_v6 v6, v6 six times the deformed volume."""
    nodal: wp.vec2
    """The vertex's nodal weights, the same in each of its entries: (1 / (6 S_a), kappa_a), S_a = sum V_t
    over its tets, kappa_a = sum V_t lambda_0 / S_a [Pa] (`nodal_pressure`)."""
    slots: wp.vec4i
    """Where each corner's block goes in the vertex's row of the implicit system: corner c's place in the
    vertex's CSR adjacency row (its neighbours sorted by id; the vertex's own corner -1), so that
    implicit_row adds each block into its entry without searching the row."""


@wp.struct
class TetRest:
    """One tet's rest data, for a pass over each tet once (kernels/region/volumes.py): its corners as
    oriented in tissue/laws.py (`tet_entry_tets`)."""

    dm_inv: wp.mat33
    """D_m^-1 of its corners in that order [1/m]."""
    volume: float
    """Rest volume V_0 [m^3]."""
    mu: float
    """mu [Pa]."""
    shear: wp.mat33
    """mu V_0 (b_c . b_d) for corners c, d = 1..3 [N/m], so that mu V_0 F b_c is column c of E shear (E: the
    edges from corner 0 as columns)."""
    mu_v6: float
    """mu / (6 V_0) [Pa/m^3]: mu J = mu_v6 v6, v6 six times the deformed volume."""


VOLUMETRIC = True
"""A tet law's entries are a vertex's incident tets (a batch builds them as local tets) and it has a
nodal pressure pass (`nodal_pressure`) before its forces."""

ENTRY_TOPOLOGY = wp.array(dtype=wp.vec4i)
"""Entry k: the four vertex ids of its tet, in its vertex's order (i, a, j, k): the vertex second, the
tet's orientation kept (tissue/laws.py CORNER_ORDER)."""
ENTRY_PARAMS = wp.array(dtype=TetEntry)
"""Entry k: its tet's rest data and corner."""


@wp.struct
class Entries:
    """The law's entries as one kernel argument (Model.entries): CSR offsets, topology, parameters."""

    offsets: wp.array(dtype=wp.int32)
    topology: ENTRY_TOPOLOGY
    params: ENTRY_PARAMS
    pressure: wp.array(dtype=float)
    """Each vertex's nodal pressure [Pa] as the last pressure pass left it (a volumetric law's; else one zero)."""


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
def tet_pressure(t: wp.vec4i, pressure: Any):
    # p_t: the mean of the tet's corners' nodal pressures
    return 0.25 * ((pressure[t[0]] + pressure[t[1]]) + (pressure[t[2]] + pressure[t[3]]))


@wp.func
def corner_position(q: Any, rest: Any, c: int):
    # corner c's position: q[c], or for c < 0 (a batch's corner outside its region) rest[-c - 1], at rest
    if c < 0:
        return rest[-c - 1]
    return q[c]


@wp.func
def tet_volume6(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, x3: wp.vec3):
    # six times the volume of the tet (x0, x1, x2, x3), positive where it keeps its rest orientation
    return wp.dot(wp.cross(x2 - x0, x3 - x0), x1 - x0)


@wp.func
def nodal_value(volume6: float, nodal: wp.vec2):
    # p_a = kappa_a (J_a - 1) of a vertex whose tets' deformed volumes sum to volume6 / 6, its nodal
    # weights (1 / (6 S_a), kappa_a) (TetEntry.nodal)
    return nodal[1] * (volume6 * nodal[0] - 1.0)


@wp.func
def nodal_pressure(begin: int, end: int, topology: Any, params: Any, shift: int, q: Any, rest: Any):
    # p_a = kappa_a (J_a - 1) of a vertex from its incident tets, entries begin..end (corner positions
    # from q, or `rest` for a negative corner: corner_position): J_a = sum v_t / S_a, with the vertex's
    # weights from its first entry (nodal_value; the module's docstring)
    if begin >= end:
        return 0.0
    volume6 = float(0.0)
    k = begin
    while k < end:  # a while loop: here 17% fewer instructions than range() on the CPU (callgrind)
        t = topology[nonneg(k)]
        volume6 += tet_volume6(corner_position(q, rest, t[0]), corner_position(q, rest, t[1]), corner_position(q, rest, t[2]),
                               corner_position(q, rest, t[3]))
        k += 1
    return nodal_value(volume6, params[begin + shift].nodal)


@wp.func
def gathered_force(
    x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float,
    begin: int, end: int, corner: Any, force: Any, shift: int, q: Any, qd: Any, pressure: Any,
):
    # vertex_force's sum with its tets' forces computed once a tet (tet_forces, kernels/region/volumes.py):
    # the anchor and damper, then force[corner[k]] for the entries begin..end, in entry order
    f = anchor_force(x, u, x_rest, ka, kda, scale)
    k = begin
    while k < end:
        f += force[nonneg(corner[nonneg(k)])]
        k += 1
    return f


@wp.func
def corner_gradient(dm_inv: wp.mat33, c: int):
    # b_c: the gradient of corner c's barycentric coordinate at rest (rows of D_m^-1; corner 0 minus their sum)
    if c == 0:
        return -wp.vec3(dm_inv[0, 0] + dm_inv[1, 0] + dm_inv[2, 0], dm_inv[0, 1] + dm_inv[1, 1] + dm_inv[2, 1],
                        dm_inv[0, 2] + dm_inv[1, 2] + dm_inv[2, 2])
    return wp.vec3(dm_inv[c - 1, 0], dm_inv[c - 1, 1], dm_inv[c - 1, 2])


def tet_law(stress: Any, shear: float, element_bulk: float, entry_force: Any = None, tet_forces: Any = None):
    """(vertex_force, implicit_row, static_row, tet_forces) of a tet law whose first Piola-Kirchhoff
    stress is `stress(F, dJ, mu, pressure)` (pressure: the tet's mean nodal pressure), so that a tet's
    force on its corner c is -V_0 P b_c, and whose Gauss-Newton blocks are K_ab = V_0 (shear mu (b_a .
    b_b) I + (element_bulk mu + lambda_0) (dJ b_a)(dJ b_b)^T): positive semi-definite in every state
    (neo_hookean.py's docstring). `entry_force(x, t, p, q, pressure)`: the same force on the entry's
    vertex (at x) written for the explicit kernels' gather (vertex_force), where a law has a cheaper
    form; default corner_force's. tet_forces(x0, x1, x2, x3, r, pressure): the four corners' forces of
    a tet (TetRest r), where a law has a cheaper form than its stress once (default)."""
    SHEAR, ELEMENT_BULK = float(shear), float(element_bulk)

    @wp.func
    def corner_force(F: wp.mat33, dJ: wp.mat33, p: TetEntry, pressure: float):
        # the tet's elastic force on the entry's corner, -V_0 P b
        return (-p.volume) * (stress(F, dJ, p.mu, pressure) * p.gradient)

    @wp.func
    def stress_tet_forces(x0: wp.vec3, x1: wp.vec3, x2: wp.vec3, x3: wp.vec3, r: TetRest, pressure: float):
        # the elastic forces on the tet's corners 0..3: -V_0 P b_c, b_1..b_3 the rows of D_m^-1 (the
        # columns of -V_0 P D_m^-T), b_0 minus their sum
        F = wp.matrix_from_cols(x1 - x0, x2 - x0, x3 - x0) * r.dm_inv
        f0 = column(F, 0)
        f1 = column(F, 1)
        f2 = column(F, 2)
        dJ = wp.matrix_from_cols(wp.cross(f1, f2), wp.cross(f2, f0), wp.cross(f0, f1))
        H = (-r.volume) * (stress(F, dJ, r.mu, pressure) * wp.transpose(r.dm_inv))
        h1 = column(H, 0)
        h2 = column(H, 1)
        h3 = column(H, 2)
        return -(h1 + h2 + h3), h1, h2, h3

    @wp.func
    def tet_term(q: Any, t: wp.vec4i, p: TetEntry, pressure: Any):
        # the tet's dJ/dF and its element force on the corner p.corner, at positions q
        F, dJ = tet_state(q, t, p)
        return dJ, corner_force(F, dJ, p, tet_pressure(t, pressure))

    @wp.func
    def corner_entry_force(x: wp.vec3, t: wp.vec4i, p: TetEntry, q: Any, pressure: Any):
        # the tet's force on the entry's vertex, from corner_force
        dJ, fc = tet_term(q, t, p, pressure)
        return fc

    ENTRY_FORCE = corner_entry_force if entry_force is None else entry_force
    TET_FORCES = stress_tet_forces if tet_forces is None else tet_forces

    @wp.func
    def block(p: TetEntry, g_a: wp.vec3, b_a: wp.vec3, b_c: wp.vec3, g_c: wp.vec3):
        # the Gauss-Newton block K_ac of the tet (b: rest barycentric gradients, g = dJ b)
        return p.volume * ((SHEAR * p.mu) * wp.dot(b_a, b_c) * wp.identity(n=3, dtype=float) + (ELEMENT_BULK * p.mu + p.bulk) * wp.outer(g_a, g_c))

    @wp.func
    def vertex_force(
        x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float,
        begin: int, end: int, topology: Any, params: Any, shift: int, q: Any, qd: Any, pressure: Any,
    ):
        # the internal force on a vertex at x with velocity u: its anchor and damper (scaled by `scale`),
        # eq. (3), then the elastic forces of its incident tets, entries begin..end (tet topology[k], rest
        # data params[k + shift]; corner positions from q, nodal pressures from `pressure`, indexed as q)
        f = anchor_force(x, u, x_rest, ka, kda, scale)
        for k in range(begin, end):
            f += ENTRY_FORCE(x, topology[nonneg(k)], params[nonneg(k + shift)], q, pressure)
        return f

    @wp.func
    def implicit_row(
        x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float, m: float, dt: float,
        begin: int, end: int, topology: Any, params: Any, shift: int, row_begin: int, row_end: int, row_neighbour: Any,
        q: Any, qd: Any, local_of: Any, by_local: int, self_id: int, driven: int, dv_driven: wp.vec3, free_count: int,
        csr_block: Any, csr_local: Any, out_shift: int, pressure: Any,
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
            t = topology[nonneg(k)]
            p = params[nonneg(k + shift)]
            dJ, fc = tet_term(q, t, p, pressure)
            f += fc
            g_a = dJ * p.gradient
            for c in range(4):
                b_c = corner_gradient(p.dm_inv, c)
                K = block(p, g_a, p.gradient, b_c, dJ * b_c)
                vc = nonneg(t[c])
                Kv += K * qd[vc]
                if c == p.corner:
                    D += dt * dt * K
                else:
                    e = nonneg(row_begin + p.slots[c] + out_shift)  # vc's entry in the row (TetEntry.slots)
                    csr_block[e] = csr_block[e] - dt * dt * K
                    if vc == driven:
                        correction -= dt * dt * K * dv_driven
        return f, D, Kv, correction

    @wp.func
    def static_row(x: wp.vec3, x_rest: wp.vec3, ka: float, begin: int, end: int, topology: Any, params: Any, shift: int, q: Any,
                   pressure: Any):
        # the static equilibrium at a vertex whose neighbours are held where they are (velocities zero):
        # its force (anchor and incident tets) and its diagonal stiffness block (the anchor's and the
        # tets' Gauss-Newton blocks, as implicit_row's)
        zero = wp.vec3(0.0)
        f = anchor_force(x, zero, x_rest, ka, 0.0, 1.0)
        D = ka * wp.identity(n=3, dtype=float)
        for k in range(begin, end):
            p = params[k + shift]
            dJ, fc = tet_term(q, topology[k], p, pressure)
            f += fc
            g_a = dJ * p.gradient
            D += block(p, g_a, p.gradient, p.gradient, g_a)
        return f, D

    return vertex_force, implicit_row, static_row, TET_FORCES
