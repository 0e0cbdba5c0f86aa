"""The rigid spherical probe's law, once: frictionless one-sided contact and its reaction.

Functions of values, inlined by Warp, called by the explicit and the implicit step. A vertex
inside the sphere is put on its surface along the sphere's normal (frictionless: the tangential
motion is kept); the tissue's force on the probe at that vertex is the normal part of the
vertex's internal force, as the driven vertex's reaction is its internal force (radius -> 0
leaves one contact vertex and the paper's probe).
"""

import warp as wp

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
