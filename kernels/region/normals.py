"""Area-weighted vertex normals of the surface, three ways (paper section 1.3, Table 2).

A vertex normal is the normalized sum of its incident triangles' normals, each weighted by its
area: n_i = sum_f (x_b - x_a) x (x_c - x_a) over faces f = (a, b, c) around i (the cross product
is twice the area times the unit face normal), then n_i / |n_i|. Vertices on no triangle (inside
a tet mesh) get a zero normal.

- *global*: every face's normal, then every vertex gathers its faces' (the paper's first column);
- *local by search*: only the given vertices, each finding its faces by scanning every triangle
  (the paper's second column: no incidence kept);
- *local precomputed*: only the given vertices, each reading its faces from the vertex-to-face
  CSR built once at load (the paper's third column).

All three add the same face normals in the same order (faces by id), so they agree to the bit;
sums are gathers per vertex, never float atomics.
"""

import warp as wp

from ..arrays import MeshArrays

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})

EPS_NORMAL = wp.constant(1.0e-30)
"""Below this squared length a summed normal counts as zero (guards the 1/|n|)."""


@wp.func
def normalize_or_zero(n: wp.vec3):
    l2 = wp.dot(n, n)
    if l2 > EPS_NORMAL:
        return n / wp.sqrt(l2)
    return wp.vec3(0.0)


@wp.func
def face_area_normal(q: wp.array(dtype=wp.vec3), a: int, b: int, c: int):
    # area-weighted face normal: (x_b - x_a) x (x_c - x_a) = 2 A n_f
    x_a = q[a]
    return wp.cross(q[b] - x_a, q[c] - x_a)


@wp.kernel
def eval_face_normals(q: wp.array(dtype=wp.vec3), mesh: MeshArrays, face_normal: wp.array(dtype=wp.vec3)):
    # global, pass 1: one thread per triangle
    f = wp.tid()
    face_normal[f] = face_area_normal(q, mesh.triangles[f, 0], mesh.triangles[f, 1], mesh.triangles[f, 2])


@wp.kernel
def gather_vertex_normals(mesh: MeshArrays, face_normal: wp.array(dtype=wp.vec3), vertex_normal: wp.array(dtype=wp.vec3)):
    # global, pass 2: one thread per vertex sums its faces' normals (a gather, no atomics)
    i = wp.tid()
    n = wp.vec3(0.0)
    for k in range(mesh.vertex_face_offsets[i], mesh.vertex_face_offsets[i + 1]):
        n += face_normal[mesh.vertex_face[k]]
    vertex_normal[i] = normalize_or_zero(n)


@wp.kernel
def eval_listed_normals(
    q: wp.array(dtype=wp.vec3), mesh: MeshArrays, vertices: wp.array(dtype=wp.int32), by_search: int, vertex_normal: wp.array(dtype=wp.vec3)
):
    # one thread per listed vertex; its faces in id order either way, so both give the same bits
    i = vertices[wp.tid()]
    n = wp.vec3(0.0)
    if by_search:
        # local by search: scan every triangle for the ones it is on
        for f in range(mesh.triangles.shape[0]):
            a = mesh.triangles[f, 0]
            b = mesh.triangles[f, 1]
            c = mesh.triangles[f, 2]
            if a == i or b == i or c == i:
                n += face_area_normal(q, a, b, c)
    else:
        # local precomputed: read its faces from the incidence CSR
        for k in range(mesh.vertex_face_offsets[i], mesh.vertex_face_offsets[i + 1]):
            f = mesh.vertex_face[k]
            n += face_area_normal(q, mesh.triangles[f, 0], mesh.triangles[f, 1], mesh.triangles[f, 2])
    vertex_normal[i] = normalize_or_zero(n)


def eval_vertex_normals_global(dmesh, q, face_normal, vertex_normal):
    """Every vertex's normal from every face's: two launches (faces, then a gather per vertex)."""
    d = dmesh.device
    if dmesh.triangles.shape[0]:
        wp.launch(eval_face_normals, dim=dmesh.triangles.shape[0], inputs=[q, dmesh.arrays], outputs=[face_normal], device=d)
    wp.launch(gather_vertex_normals, dim=dmesh.vertex_count, inputs=[dmesh.arrays, face_normal], outputs=[vertex_normal], device=d)


def eval_vertex_normals_search(dmesh, q, vertices, count, vertex_normal):
    """The normals of `vertices[:count]`, each found by scanning every triangle."""
    if count:
        wp.launch(
            eval_listed_normals, dim=count, inputs=[q, dmesh.arrays, vertices, 1], outputs=[vertex_normal], device=dmesh.device
        )


def eval_vertex_normals_incident(dmesh, q, vertices, count, vertex_normal):
    """The normals of `vertices[:count]` from their incident faces (the precomputed CSR)."""
    if count:
        wp.launch(
            eval_listed_normals, dim=count, inputs=[q, dmesh.arrays, vertices, 0], outputs=[vertex_normal], device=dmesh.device
        )
