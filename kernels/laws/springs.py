"""The paper's tissue law: anchors and edge springs with dampers, eqs. (3)-(6), and their Jacobian.

A law is one file of `wp.func`s that every step kernel composes (kernels/explicit, kernels/implicit;
one region, a batch, a stroke; CPU or CUDA), registered in kernels/laws/__init__.py:
- `vertex_force`: the internal force on one vertex, its anchor and then its springs over its CSR
  entries (a gather in mesh CSR order: no atomics, the same bits on every run);
- `implicit_row`: the same vertex's row of the implicit step's linear system (its force, its
  diagonal block, K v, the driven neighbour's term) with its off-diagonal blocks written out;
- `static_row`: its static equilibrium's force and stiffness block with its neighbours held (the
  adaptive region's look past its fixed ring, kernels/region/ring_motion.py).
The per-spring pieces below take vectors and scalars, never arrays. The two row functions are
generic over the arrays they read (a mesh's CSR, a compacted region's, a block's shared memory): a
layout passes its own, and `shift` moves the spring index from the neighbour's entry to the spring
table's (0 where both are indexed alike). Warp specializes and inlines them: the composed one-region
step runs the instructions the loop written out in the kernel ran (docs/performance.md).
"""

from typing import Any

import warp as wp

from ..index import nonneg

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

VOLUMETRIC = False
"""Whether the law's entries are a vertex's incident tets (a batch then builds them as local tets, the
region's fixed ring's too) and it has a nodal pressure pass before its forces (`nodal_pressure`,
kernels/laws/neo_hookean.py): the kernels run that pass only for such a law."""

ENTRY_TOPOLOGY = wp.array(dtype=wp.int32)
"""Entry k of a vertex (its CSR adjacency): the neighbour at the spring's other end."""
ENTRY_PARAMS = wp.array(dtype=wp.vec3)
"""Entry k: its spring's (k_ij [N/m], d_ij [N s/m], rest length [m])."""


@wp.struct
class Entries:
    """The law's entries as one kernel argument (Model.entries): CSR offsets, topology, parameters."""

    offsets: wp.array(dtype=wp.int32)
    topology: ENTRY_TOPOLOGY
    params: ENTRY_PARAMS
    pressure: wp.array(dtype=float)
    """Each vertex's nodal pressure [Pa] as the last pressure pass left it (a volumetric law's; else one zero)."""

EPS_LENGTH = 1.0e-9
"""Shorter springs than this [m] have no direction: their force is zero (no 1/0, no NaN)."""


@wp.func
def anchor_force(x: wp.vec3, v: wp.vec3, x_rest: wp.vec3, k: float, d: float, scale: float):
    # anchor spring and damper pulling the vertex back to its rest position, eq. (3)
    return -scale * (k * (x - x_rest) + d * v)


@wp.func
def spring_force_along(r: wp.vec3, dv: wp.vec3, l: float, inv_l: float, k: float, d: float, L0: float):
    # force on vertex i of spring ij, r = x_j - x_i, dv = v_j - v_i, given its length l and 1 / l:
    # elastic along the edge, eqs. (4)-(5), plus damping along it, eq. (6)
    s = k * (l - L0) + d * wp.dot(dv, r) * inv_l
    return (s * inv_l) * r


@wp.func
def spring_force(x_i: wp.vec3, v_i: wp.vec3, x_j: wp.vec3, v_j: wp.vec3, k: float, d: float, L0: float):
    # force on vertex i of the spring and damper ij, eqs. (4)-(6); zero for a collapsed spring
    r = x_j - x_i
    l = wp.length(r)
    if l > EPS_LENGTH:
        return spring_force_along(r, v_j - v_i, l, 1.0 / l, k, d, L0)
    return wp.vec3(0.0)


@wp.func
def add_spring_force(f: wp.vec3, x_i: wp.vec3, v_i: wp.vec3, x_j: wp.vec3, v_j: wp.vec3, k: float, d: float, L0: float):
    # f plus spring_force(x_i, v_i, x_j, v_j, k, d, L0): the sum inside the branch, so that on CUDA
    # the last multiplication fuses with it (one rounding, as a gather written out in a kernel)
    r = x_j - x_i
    l = wp.length(r)
    if l > EPS_LENGTH:
        return f + spring_force_along(r, v_j - v_i, l, 1.0 / l, k, d, L0)
    return f


@wp.func
def edge_direction(r: wp.vec3):
    # unit vector along the spring, zero for a collapsed one
    l = wp.length(r)
    if l > EPS_LENGTH:
        return r / l
    return wp.vec3(0.0)


@wp.func
def spring_block(ke: float, kd: float, L0: float, r: wp.vec3, dt: float):
    # the implicit step's block of one spring, dt C_e + dt^2 K_e, and K_e itself:
    # K_e = ke (d d^T + max(1 - L0/l, 0) (I - d d^T)) (made positive semi-definite when compressed), C_e = kd d d^T
    l = wp.length(r)
    d = edge_direction(r)
    ddt = wp.outer(d, d)
    geo = float(0.0)
    if l > EPS_LENGTH:
        geo = wp.max(1.0 - L0 / l, 0.0)
    Kb = ke * (ddt + geo * (wp.identity(n=3, dtype=float) - ddt))
    return dt * kd * ddt + dt * dt * Kb, Kb


@wp.func
def nodal_pressure(begin: int, end: int, neighbour: Any, spring: Any, shift: int, q: Any, rest: Any):
    # springs have no volume and no nodal pressure (VOLUMETRIC: the kernels never run this pass for them)
    return 0.0


@wp.func
def vertex_force(
    x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float,
    begin: int, end: int, neighbour: Any, spring: Any, shift: int, q: Any, qd: Any, pressure: Any,
):
    # the internal force on a vertex at x with velocity u: its anchor (scaled by `scale`), eq. (3),
    # then the springs of its CSR entries begin..end, eqs. (4)-(6): entry k's neighbour is
    # neighbour[k] (an index of q, qd) and its spring (k_ij, d_ij, rest length) spring[k + shift]
    # (`pressure`: a volumetric law's nodal pressures, which springs have none of)
    f = anchor_force(x, u, x_rest, ka, kda, scale)
    for k in range(begin, end):
        j = nonneg(neighbour[nonneg(k)])
        s = spring[nonneg(k + shift)]
        f = add_spring_force(f, x, u, q[j], qd[j], s[0], s[1], s[2])
    return f


@wp.func
def static_row(x: wp.vec3, x_rest: wp.vec3, ka: float, begin: int, end: int, neighbour: Any, spring: Any, shift: int, q: Any,
               pressure: Any):
    # the static equilibrium K u = f at a vertex whose neighbours are held where they are, linearized
    # at x (velocities zero: the dampers add nothing): its force and the stiffness's diagonal block
    # (anchor and springs along their edges, eqs. (3)-(5)), over the same entries as vertex_force
    zero = wp.vec3(0.0)
    f = anchor_force(x, zero, x_rest, ka, 0.0, 1.0)
    D = ka * wp.identity(n=3, dtype=float)
    for k in range(begin, end):
        j = neighbour[k]
        s = spring[k + shift]
        f = add_spring_force(f, x, zero, q[j], zero, s[0], 0.0, s[2])
        d = edge_direction(q[j] - x)
        D += s[0] * wp.outer(d, d)
    return f, D


@wp.func
def anchor_row(x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float, m: float, dt: float):
    # a row's start, every law's: the anchor's force, eq. (3), the diagonal block m + dt d_i + dt^2 k_i
    # and K v0's anchor term (anchors scaled by `scale`)
    ka_s = scale * ka
    kda_s = scale * kda
    return anchor_force(x, u, x_rest, ka, kda, scale), (m + dt * kda_s + dt * dt * ka_s) * wp.identity(n=3, dtype=float), ka_s * u


@wp.func
def row_unknown(j: int, local_of: Any, by_local: int, self_id: int, driven: int, free_count: int):
    # the unknown of neighbour j in a row's CSR entry: its local index (j itself where by_local, else
    # local_of[j]), -1 where it is none (the fixed ring past free_count, the driven vertex)
    lj = j
    if by_local == 0:
        lj = local_of[j]
    if lj >= free_count or j == driven or self_id == driven:
        lj = -1
    return lj


@wp.func
def implicit_row(
    x: wp.vec3, u: wp.vec3, x_rest: wp.vec3, ka: float, kda: float, scale: float, m: float, dt: float,
    begin: int, end: int, neighbour: Any, spring: Any, shift: int, row_begin: int, row_end: int, row_neighbour: Any,
    q: Any, qd: Any, local_of: Any, by_local: int, self_id: int, driven: int, dv_driven: wp.vec3, free_count: int,
    csr_block: Any, csr_local: Any, out_shift: int, pressure: Any,
):
    # one vertex's row of (M + dt C + dt^2 K) dv = dt (f0 - dt K v0) - A_ic dv_c (Baraff & Witkin),
    # over the same entries as vertex_force. The system's row (the vertex's CSR adjacency,
    # row_begin..row_end of row_neighbour) is the springs' own entries here. Writes each entry's
    # block dt C_e + dt^2 K_e (minus the system's off-diagonal block) to csr_block[k + out_shift] and
    # the neighbour's unknown to csr_local[k + out_shift]: its local index (the neighbour id itself
    # where by_local, else local_of[neighbour]), -1 where it is no unknown (the fixed ring past
    # free_count, or the driven vertex, whose id is `driven` and whose known velocity change is
    # dv_driven; self_id is this vertex's id in the same numbering).
    # Returns (f0, the diagonal block, K v0, -A_ic dv_c).
    f, D, Kv = anchor_row(x, u, x_rest, ka, kda, scale, m, dt)
    correction = wp.vec3(0.0)
    for k in range(begin, end):
        j = neighbour[k]
        s = spring[k + shift]
        f = add_spring_force(f, x, u, q[j], qd[j], s[0], s[1], s[2])
        B, Kb = spring_block(s[0], s[1], s[2], q[j] - x, dt)
        csr_block[k + out_shift] = B
        csr_local[k + out_shift] = row_unknown(j, local_of, by_local, self_id, driven, free_count)
        D += B
        Kv += Kb * (u - qd[j])
        if j == driven:
            correction += B * dv_driven  # -A_ic dv_c, with A_ic = -B
    return f, D, Kv, correction
