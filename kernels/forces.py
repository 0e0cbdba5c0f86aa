"""The ALMSDM's forces on one vertex, gathered over its CSR neighbours (no atomics): eqs. (3)-(6)."""

import warp as wp

EPS_LENGTH = 1.0e-9
"""Shorter springs than this [m] have no direction: their force is zero (no 1/0, no NaN)."""


@wp.func
def edge_direction(r: wp.vec3):
    # unit vector along the spring, zero for a collapsed one
    l = wp.length(r)
    if l > EPS_LENGTH:
        return r / l
    return wp.vec3(0.0)


@wp.func
def gather_vertex_force(
    v: int,
    x: wp.vec3,
    u: wp.vec3,
    adj_offsets: wp.array(dtype=wp.int32),
    adj_vertex: wp.array(dtype=wp.int32),
    adj_edge: wp.array(dtype=wp.int32),
    q_rest: wp.array(dtype=wp.vec3),
    anchor_ke: wp.array(dtype=wp.float32),
    anchor_kd: wp.array(dtype=wp.float32),
    anchor_scale: float,
    spring_ke: wp.array(dtype=wp.float32),
    spring_kd: wp.array(dtype=wp.float32),
    spring_rest_length: wp.array(dtype=wp.float32),
    q: wp.array(dtype=wp.vec3),
    qd: wp.array(dtype=wp.vec3),
):
    # anchor spring and damper to the rest position, eq. (3)
    f = -anchor_scale * (anchor_ke[v] * (x - q_rest[v]) + anchor_kd[v] * u)
    for k in range(adj_offsets[v], adj_offsets[v + 1]):
        j = adj_vertex[k]
        e = adj_edge[k]
        r = q[j] - x
        l = wp.length(r)
        if l > EPS_LENGTH:
            # elastic force along the edge, eqs. (4)-(5), and damping along it, eq. (6)
            s = spring_ke[e] * (l - spring_rest_length[e]) + spring_kd[e] * wp.dot(qd[j] - u, r) / l
            f += (s / l) * r
    return f
