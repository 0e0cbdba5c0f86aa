"""The arrays the kernels share, grouped as Warp structs: each kernel takes one value per group.

Each struct is built once where its data lives (the Model, a Control, the batch's regions, a
press, a conjugate-gradient scratch) and passed as it is to every launch. A new per-vertex or
per-spring field is one member here and one line where the struct is built.
"""

import warp as wp


@wp.struct
class TissueArrays:
    """The Model's static arrays (almsdm_warp.sim.model.Model.arrays)."""

    q_rest: wp.array(dtype=wp.vec3)
    """Rest positions [m], [particle_count]."""
    particle_mass: wp.array(dtype=wp.float32)
    """Lumped vertex mass [kg], [particle_count]."""
    anchor_ke: wp.array(dtype=wp.float32)
    """Anchor stiffness k_i [N/m], [particle_count], eq. (3)."""
    anchor_kd: wp.array(dtype=wp.float32)
    """Anchor damping d_i [N s/m], [particle_count], eq. (3)."""
    spring_ke: wp.array(dtype=wp.float32)
    """Spring stiffness k_ij [N/m], [spring_count], eqs. (4)-(5)."""
    spring_kd: wp.array(dtype=wp.float32)
    """Spring damping d_ij [N s/m], [spring_count], eq. (6)."""
    spring_rest_length: wp.array(dtype=wp.float32)
    """Spring rest length [m], [spring_count]."""
    adj_offsets: wp.array(dtype=wp.int32)
    """Mesh CSR vertex adjacency: vertex v's entries are adj_offsets[v]..adj_offsets[v + 1]."""
    adj_vertex: wp.array(dtype=wp.int32)
    """Neighbour of each CSR entry, [2 * spring_count]."""
    adj_edge: wp.array(dtype=wp.int32)
    """Spring (mesh edge id) of each CSR entry, [2 * spring_count]."""
    adj_spring: wp.array(dtype=wp.vec3)
    """(k_ij, d_ij, rest length) of each CSR entry's spring, [2 * spring_count]."""


@wp.struct
class ProbeArrays:
    """One or several probes (a Control, or the probes of a MultiPalpation), one entry each."""

    probe_vertex: wp.array(dtype=wp.int32)
    """Mesh id of the held vertex (-1: none)."""
    probe_mode: wp.array(dtype=wp.int32)
    """Off / displacement / force."""
    probe_target: wp.array(dtype=wp.vec3)
    """Target of the held vertex [m] (displacement mode)."""
    probe_force: wp.array(dtype=wp.vec3)
    """Force the probe applies [N] (force mode)."""
    probe_reaction: wp.array(dtype=wp.vec3)
    """Output: the tissue's internal forces on the held vertex [N]."""


@wp.struct
class ProbeSphereArrays:
    """A spherical probe (a Control's, sphere mode): its radius, who may touch, each contact's reaction."""

    probe_radius: wp.array(dtype=wp.float32)
    """Radius [m], [1]; the centre is probe_target[0]."""
    probe_surface: wp.array(dtype=wp.int32)
    """1 for a vertex the sphere may touch (a surface vertex), [particle_count]."""
    probe_contact: wp.array(dtype=wp.vec3)
    """Output: each free vertex's contact reaction [N], zero off contact, [particle_count]."""


CG_FIELDS = (
    ("dv", wp.vec3, "vertex"),
    ("r", wp.vec3, "vertex"),
    ("p", wp.vec3, "vertex"),
    ("Ap", wp.vec3, "vertex"),
    ("diag", wp.mat33, "vertex"),
    ("diag_inv", wp.mat33, "vertex"),
    ("normal", wp.vec3, "vertex"),
    ("csr_block", wp.mat33, "entry"),
    ("csr_local", wp.int32, "entry"),
    ("stats", wp.float32, "stats"),
)
"""The conjugate-gradient solve's arrays (kernels/implicit/block_cg.py): name, element type and size
(per unknown, per CSR entry, or the solve's (iterations, relative residual)); `normal`: the unit
normal of an unknown constrained along it (a sphere's contact), else zero."""


def struct_of(name: str, doc: str, members: dict):
    """A Warp struct named `name` with `members` (member name -> Warp type) in that order."""
    return wp.struct(type(name, (), {"__annotations__": dict(members), "__doc__": doc, "__module__": __name__}))


def _cg_struct(name: str, array_type, doc: str):
    # one member list for the one-palpation scratch (1-d) and the batch's (a row per palpation)
    return struct_of(name, doc, {field: array_type(dtype=dtype) for field, dtype, _ in CG_FIELDS})


CGArrays = _cg_struct("CGArrays", wp.array, "The one-palpation implicit step's conjugate-gradient scratch.")
BatchCGArrays = _cg_struct("BatchCGArrays", wp.array2d, "The implicit batch's conjugate-gradient scratch, a row per palpation.")


_INT = wp.array(dtype=wp.int32)

MeshArrays = struct_of(
    "MeshArrays",
    """A DeviceMesh's topology and rest geometry (almsdm_warp.mesh.device_mesh.DeviceMesh.arrays).

    adj_offsets, adj_vertex, adj_edge: the CSR vertex adjacency (vertex v's entries are
    adj_offsets[v]..adj_offsets[v + 1]; each entry's neighbour and mesh edge id); triangles
    [triangle_count, 3]; vertex_face_offsets, vertex_face: the vertex-to-triangle incidence CSR;
    rest_position [m]; bvh_vertex: the vertex id of each item of the surface-vertex BVH.
    """,
    {"adj_offsets": _INT, "adj_vertex": _INT, "adj_edge": _INT, "triangles": wp.array2d(dtype=wp.int32)}
    | {"vertex_face_offsets": _INT, "vertex_face": _INT, "rest_position": wp.array(dtype=wp.vec3), "bvh_vertex": _INT},
)

RegionArrays = struct_of(
    "RegionArrays",
    """One Region's device arrays (almsdm_warp.region.region.Region.arrays documents each).

    Per mesh vertex: vertex_ring, vertex_local (-1 outside). In local order: region_vertex,
    region_ring, region_boundary; per region spring: region_edge, region_edge_local; region_count:
    the vertices placed so far (one entry, the ring growth's counter).
    """,
    {"vertex_ring": _INT, "vertex_local": _INT, "region_vertex": _INT, "region_ring": _INT, "region_boundary": _INT}
    | {"region_edge": _INT, "region_edge_local": wp.array(dtype=wp.vec2i), "region_count": _INT},
)


@wp.struct
class BatchRegionArrays:
    """Compacted per-palpation regions (almsdm_warp.batch.batch_palpation.BatchRegions documents each)."""

    region_vertex: wp.array2d(dtype=wp.int32)
    ring_offsets: wp.array2d(dtype=wp.int32)
    region_count: wp.array(dtype=wp.int32)
    free_count: wp.array(dtype=wp.int32)
    local_offsets: wp.array2d(dtype=wp.int32)
    local_neighbour: wp.array2d(dtype=wp.int32)
    local_edge: wp.array2d(dtype=wp.int32)
    local_owner: wp.array2d(dtype=wp.int32)
    local_spring: wp.array2d(dtype=wp.int32)
    spring_entry: wp.array2d(dtype=wp.int32)
    spring_count: wp.array(dtype=wp.int32)
    entry_count: wp.array(dtype=wp.int32)
    status: wp.array(dtype=wp.int32)


@wp.struct
class BatchElements:
    """A volumetric law's tets of each palpation's region vertices, free and fixed ring (almsdm_warp.
    batch.batch_palpation.BatchPalpation.elements): CSR offsets per vertex [B, vertex capacity + 1],
    each local entry's tet as local corner indices (-(id + 1) for a mesh vertex outside the region)
    [B, entry capacity], per vertex the shift from a local entry to the mesh's entry of the same tet
    (whose parameters the law keeps) [B, vertex capacity], and the nodal pressures."""

    offsets: wp.array2d(dtype=wp.int32)
    topology: wp.array2d(dtype=wp.vec4i)
    shift: wp.array2d(dtype=wp.int32)
    pressure: wp.array2d(dtype=wp.float32)
    """Each region vertex's nodal pressure [Pa], [B, vertex capacity] (the implicit batch's)."""


@wp.struct
class BatchPress:
    """One press of a batch: its schedule and each palpation's direction and force records."""

    press_direction: wp.array(dtype=wp.vec3d)
    """Inward unit normal at each contact vertex, [B] (float64, as the host computes the target)."""
    depth: wp.float64
    """Press depth [m]."""
    ramp_steps: int
    press_steps: int
    """Steps of the ramp; steps while pressed (ramp and hold)."""
    dt: float
    """Step [s]."""
    peak_force: wp.array(dtype=wp.float64)
    """Running largest |feedback force| [N] (its square with the "fast" kernel), [B]."""
    peak_reaction: wp.array(dtype=wp.vec3)
    hold_reaction: wp.array(dtype=wp.vec3)


@wp.struct
class BatchRecords:
    """A batch's opt-in records for learning (almsdm_warp/batch/records.py; kernels/probes/press.py): the
    feedback force sampled along the ramp, and at the end of the hold the contact patch's area and the
    contact forces on an n x n grid over the sphere's footprint. Kernels made without records never read it."""

    curve_points: int
    """Samples of the force curve a press (0: none); sample k at the first step whose depth reaches (k + 1) / curve_points."""
    force_curve: wp.array2d(dtype=wp.vec3)
    """Feedback force [N] at each sample, [B, curve_points]."""
    map_size: int
    """n of the n x n tactile grid (0: no patch, no map)."""
    tactile: wp.array2d(dtype=wp.float64)
    """Normal contact force [N] in each grid cell at the end of the hold, [B, n * n], row-major (rows along e2)."""
    patch_area: wp.array(dtype=wp.float64)
    """Surface area [m^2] of the vertices in contact at the end of the hold, [B]."""
    vertex_area: wp.array(dtype=wp.float32)
    """Each mesh vertex's share of the surface [m^2] (a third of each triangle at it), [particle_count]."""


def struct_from(struct, source, **values):
    """An instance of `struct` with each member taken from `values`, else from `source`'s attribute of that name."""
    out = struct()
    for name in struct.vars:
        setattr(out, name, values[name] if name in values else getattr(source, name))
    return out


@wp.struct
class BatchSphere:
    """A batch's spherical probe (one radius for every palpation) and each palpation's contact vertex."""

    radius: float
    """Radius [m] as the contact test reads it (float32); 0: the paper's probe, no sphere."""
    radius64: wp.float64
    """Radius [m] in float64, as the host computes the sphere's centre."""
    probe_surface: wp.array(dtype=wp.int32)
    """1 for each mesh vertex the sphere may touch (a surface vertex), [particle_count]."""
    contact_local: wp.array(dtype=wp.int32)
    """Local index of each palpation's contact vertex in its region (0 without a sphere), [B]."""


@wp.struct
class RegionTetArrays:
    """A region's tets for the per-tet nodal pressure pass (RegionTets.arrays)."""

    tets: wp.array(dtype=wp.vec4i)
    """The active tets' corners (mesh ids, each tet's own oriented order), [tet_count]."""
    count: wp.array(dtype=wp.int32)
    """[1]: how many tets are active (the first slots of volume6)."""
    entry_slot: wp.array(dtype=wp.int32)
    """Each entry's slot in volume6, [entries] (written for the region vertices' entries only)."""
    volume6: wp.array(dtype=wp.float32)
    """Six times the tets' deformed volumes [m^3]: the active ones (each step), then one a fixed-ring
    entry of a tet with no free corner (at the build), [entries]."""
    tet_slot: wp.array(dtype=wp.int32)
    """Scratch of the build: each active tet's slot, [tet_count]."""
    tet_id: wp.array(dtype=wp.int32)
    """Each active tet's id (its TetRest), [tet_count]."""
    entry_corner: wp.array(dtype=wp.int32)
    """Each free vertex's entry: 4 x its tet's slot + its corner there, the entry's force in `force`, [entries]."""
    force: wp.array(dtype=wp.vec3)
    """Each active tet's elastic forces on its four corners [N] (entry_corner), [4 tet_count]."""
