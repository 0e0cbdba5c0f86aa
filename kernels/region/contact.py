"""Contact on the device: the closest surface point to each probe, and the nearest surface vertex.

The closest point comes from the surface's BVH (`wp.Mesh`). The nearest vertex is exact, not a
corner guess: a corner of the closest face gives an upper bound d0 on the distance, and a BVH
query over the surface vertices inside the box of half-width d0 finds every vertex that can beat
it. Ties go to the lower vertex id, as a brute-force argmin would.
"""

import warp as wp

from ..arrays import MeshArrays

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.kernel
def query_closest_points(
    mesh_id: wp.uint64,
    probe: wp.array(dtype=wp.vec3),
    max_dist: float,
    contact_point: wp.array(dtype=wp.vec3),
    contact_face: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    q = wp.mesh_query_point_no_sign(mesh_id, probe[tid], max_dist)
    if q.result:
        contact_point[tid] = wp.mesh_eval_position(mesh_id, q.face, q.u, q.v)
        contact_face[tid] = q.face
    else:
        contact_point[tid] = probe[tid]
        contact_face[tid] = -1


@wp.func
def closer(d2: float, v: int, best_d2: float, best_v: int):
    # (distance, vertex id) in lexicographic order: the brute-force argmin's tie-break
    return d2 < best_d2 or (d2 == best_d2 and v < best_v)


@wp.kernel
def query_nearest_vertices(
    vertex_bvh: wp.uint64, mesh: MeshArrays, point: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32),
    nearest_vertex: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    p = point[tid]
    f = face[tid]
    if f < 0:
        nearest_vertex[tid] = -1
        return
    # upper bound from the closest face's corners
    best_v = int(mesh.triangles[f, 0])
    best_d2 = wp.length_sq(mesh.rest_position[best_v] - p)
    for c in range(1, 3):
        v = int(mesh.triangles[f, c])
        d2 = wp.length_sq(mesh.rest_position[v] - p)
        if closer(d2, v, best_d2, best_v):
            best_v = v
            best_d2 = d2
    # every vertex that can beat it lies in this box
    r = wp.sqrt(best_d2) * 1.0001 + 1.0e-9
    lo = p - wp.vec3(r, r, r)
    hi = p + wp.vec3(r, r, r)
    query = wp.bvh_query_aabb(vertex_bvh, lo, hi)
    item = int(0)
    while wp.bvh_query_next(query, item):
        v = mesh.bvh_vertex[item]
        d2 = wp.length_sq(mesh.rest_position[v] - p)
        if closer(d2, v, best_d2, best_v):
            best_v = v
            best_d2 = d2
    nearest_vertex[tid] = best_v


def eval_contacts(dmesh, probe, contact_point, contact_face, nearest_vertex, max_dist=1.0e6):
    """Closest surface point, its face and the nearest surface vertex for each probe position [m]."""
    wp.launch(
        query_closest_points,
        dim=len(probe),
        inputs=[dmesh.surface.id, probe, max_dist],
        outputs=[contact_point, contact_face],
        device=dmesh.device,
    )
    wp.launch(
        query_nearest_vertices,
        dim=len(probe),
        inputs=[dmesh.vertex_bvh.id, dmesh.arrays, contact_point, contact_face],
        outputs=[nearest_vertex],
        device=dmesh.device,
    )
