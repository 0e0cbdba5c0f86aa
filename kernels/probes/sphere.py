"""The rigid spherical probe's law, once: frictionless one-sided contact and its reaction.

Functions of values, inlined by Warp, called by the explicit and the implicit step. A vertex
inside the sphere is put on its surface along the sphere's normal (frictionless: the tangential
motion is kept); the tissue's force on the probe at that vertex is the normal part of the
vertex's internal force, as the driven vertex's reaction is its internal force (radius -> 0
leaves one contact vertex and the paper's probe).
"""

import warp as wp

from ..implicit.block_cg import filter_normal

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

EPS_CENTRE = 1.0e-12
"""A point closer than this [m] to the centre has no normal: it is pushed along +z."""


@wp.func
def sphere_normal(x: wp.vec3, centre: wp.vec3):
    # outward unit normal of the sphere at the direction of x, and x's distance from the centre
    r = x - centre
    l = wp.length(r)
    n = wp.vec3(0.0, 0.0, 1.0)
    if l > EPS_CENTRE:
        n = r / l
    return n, l


@wp.func
def sphere_contact_reaction(f: wp.vec3, n: wp.vec3):
    # the tissue's force on the probe at a contact vertex: the normal part of the internal force f,
    # pushing only (a one-sided contact never pulls)
    return wp.min(wp.dot(f, n), 0.0) * n


@wp.func
def onto_sphere(x_in: wp.vec3, x_out: wp.vec3, centre: wp.vec3, radius: float, dt: float):
    # x_out put on the sphere's surface along its normal; the velocity that takes x_in there in dt
    n, l = sphere_normal(x_out, centre)
    x1 = centre + radius * n
    return x1, (x1 - x_in) / dt


@wp.func
def onto_sphere_from(x_in: wp.vec3, x_out: wp.vec3, centre: wp.vec3, radius: float, dt: float):
    # the end x_out of a step from x_in put on the sphere's surface: pushed along the normal at x_in
    # to the plane tangent there, then onto the sphere along its normal; returns (the point, the
    # velocity that takes x_in there in dt, the sphere's normal there). Straight along the normal at
    # x_out, a step that ends deep inside would scale the step's tangential move by
    # radius / (radius - depth): a vertex sliding over the sphere would gain speed each step. Through
    # the tangent plane the move only shrinks. The velocity is consistent with the position (one
    # that kept the step's tangential velocity while the point moved less would put energy in too).
    n0, l0 = sphere_normal(x_in, centre)
    x_t = x_out + wp.max(radius - wp.dot(x_out - centre, n0), 0.0) * n0
    n1, l1 = sphere_normal(x_t, centre)
    x1 = centre + radius * n1
    return x1, (x1 - x_in) / dt, n1


@wp.func
def sphere_project(x_in: wp.vec3, x_out: wp.vec3, u_out: wp.vec3, f: wp.vec3, centre: wp.vec3, radius: float, dt: float):
    # the explicit step's contact: a vertex the step left inside the sphere goes onto its surface
    # (onto_sphere_from); returns (position, velocity, the contact reaction from its internal force
    # f, whether it touched)
    n, l = sphere_normal(x_out, centre)
    if l < radius:
        x1, u1, n1 = onto_sphere_from(x_in, x_out, centre, radius, dt)
        return x1, u1, sphere_contact_reaction(f, n1), True
    return x_out, u_out, wp.vec3(0.0), False


@wp.func
def sphere_contact_step(x_in: wp.vec3, u_in: wp.vec3, x_out: wp.vec3, u_out: wp.vec3, m: float, centre: wp.vec3, radius: float, dt: float):
    # the explicit step's contact at a free surface vertex the step took from (x_in, u_in) to
    # (x_out, u_out): sphere_project with the step's own internal force, f = m (u_out - u_in) / dt
    f = m * (u_out - u_in) / dt
    return sphere_project(x_in, x_out, u_out, f, centre, radius, dt)


@wp.func
def sphere_holds(x: wp.vec3, u: wp.vec3, f: wp.vec3, centre: wp.vec3, radius: float, slack: float, dt: float):
    # the implicit step's contact test: a vertex is held where its predicted position x + dt u is
    # inside the sphere, or where it is on the sphere (within radius x (1 + slack)) while its internal
    # force f pushes the probe; returns (held, the sphere's normal at x, the normal velocity change
    # that ends the step on the sphere)
    n_p, l_p = sphere_normal(x + dt * u, centre)
    n, l = sphere_normal(x, centre)
    held = l_p < radius or (l < radius * (1.0 + slack) and wp.dot(f, n) < 0.0)
    dv_n = (radius - wp.dot(n, x - centre)) / dt - wp.dot(n, u)
    return held, n, dv_n


@wp.func
def sphere_constrain(x: wp.vec3, u: wp.vec3, f: wp.vec3, rhs: wp.vec3, dv: wp.vec3, centre: wp.vec3, radius: float, slack: float, dt: float):
    # the implicit step's contact at one vertex: where the sphere holds it (sphere_holds), the warm
    # start dv gets the prescribed normal velocity change and the right-hand side rhs keeps only its
    # tangential part (Baraff & Witkin's filter); returns (the held normal or zero, dv, rhs, the
    # contact reaction)
    held, n, dv_n = sphere_holds(x, u, f, centre, radius, slack, dt)
    if held:
        return n, filter_normal(dv, n) + dv_n * n, filter_normal(rhs, n), sphere_contact_reaction(f, n)
    return wp.vec3(0.0), dv, rhs, wp.vec3(0.0)
