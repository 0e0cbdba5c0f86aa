"""The ALMSDM's force laws, each once, as functions of values: eqs. (3)-(6) and the spring Jacobian.

Every kernel (one palpation or a batch, explicit or implicit, CPU or CUDA) calls these. They take
vectors and scalars, never arrays, so Warp inlines them and a call costs nothing (a function that
takes arrays copies every array descriptor per call). `gather_vertex_force` sums them over a
vertex's CSR neighbours (a gather: no atomics, the same bits on every run).
"""

import warp as wp

from .arrays import TissueArrays

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
def gather_vertex_force(
    v: int,
    x: wp.vec3,
    u: wp.vec3,
    tissue: TissueArrays,
    anchor_scale: float,
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
):
    # the internal force on vertex v: its anchor, then its springs in mesh CSR order
    f = anchor_force(x, u, tissue.q_rest[v], tissue.anchor_ke[v], tissue.anchor_kd[v], anchor_scale)
    for k in range(tissue.adj_offsets[v], tissue.adj_offsets[v + 1]):
        e = tissue.adj_edge[k]
        j = tissue.adj_vertex[k]
        f = add_spring_force(f, x, u, q[j], qd[j], tissue.spring_ke[e], tissue.spring_kd[e], tissue.spring_rest_length[e])
    return f
