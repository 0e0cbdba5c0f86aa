"""Batched palpations: regions against Region and a breadth-first search, presses against Palpation."""

import numpy as np
import pytest
import scipy.sparse as sp
import warp as wp
from scipy.sparse.csgraph import shortest_path

from almsdm_warp import Region
from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import load_scene
from conftest import SCENES, load_cached
from test_probe_sphere import anchor_bed  # noqa: F401 (a fixture: the Winkler bed)

SEEDS = [0, 17, 311, 500, 693, 1001]
SHORT = dict(depth=0.01, ramp=0.05, hold=0.05, settle=0.1)  # 200 steps: ramp, hold, release, settle


@pytest.fixture(scope="module")
def stomach():
    return load_cached(SCENES / "stomach.obj")


def _graph(mesh):
    e = mesh.edges
    n = mesh.vertex_count
    return sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()


@pytest.mark.parametrize("rings,capacity", [(1, None), (4, None), (6, 4), (14, None)])
def test_batch_regions_match_region_and_bfs(device, stomach, rings, capacity):
    # capacity 4 is far too small for 6 rings: the build must grow and retry, not truncate; 14 rings: regions
    # of hundreds of vertices, whose membership tests binary-search the rings grown (find_local)
    bp = BatchPalpation(stomach, rings=rings, device=device, capacity=capacity).touch(SEEDS)
    hops = shortest_path(_graph(stomach), directed=False, unweighted=True, indices=SEEDS)
    offsets, neighbours, edges = stomach.adjacency
    local_offsets = bp.regions.local_offsets.numpy()
    local_neighbour = bp.regions.local_neighbour.numpy()
    local_edge = bp.regions.local_edge.numpy()
    for b, seed in enumerate(SEEDS):
        got = bp.region(b)
        ref = Region(stomach, device).build(seed, rings)
        np.testing.assert_array_equal(got, ref.vertices())
        assert bp.free_vertex_counts[b] == ref.free_count
        # independent: the region is exactly the vertices within `rings` hops, ring by ring
        assert set(got) == set(np.flatnonzero(hops[b] <= rings))
        assert np.all(np.diff(hops[b][got]) >= 0)
        # local topology: each free vertex's CSR neighbours, in mesh CSR order, as local indices
        for i in range(bp.free_vertex_counts[b]):
            v = got[i]
            k0, k1 = local_offsets[b, i], local_offsets[b, i + 1]
            np.testing.assert_array_equal(got[local_neighbour[b, k0:k1]], neighbours[offsets[v] : offsets[v + 1]])
            np.testing.assert_array_equal(local_edge[b, k0:k1], edges[offsets[v] : offsets[v + 1]])


@pytest.mark.parametrize("kernel", ["exact", "fast"])
def test_batch_press_equals_palpation_bits(device, stomach, kernel):
    # same device, same points: the exact kernel gives the same force and recovery, bit for bit;
    # the fast one ("fast" runs on the CPU as blocks of fibers with real barriers) within 1e-5
    bp = BatchPalpation(stomach, rings=4, device=device, kernel=kernel).touch(SEEDS)
    assert bp.kernel == kernel
    res = bp.press(**SHORT)
    for b, seed in enumerate(SEEDS):
        pal = Palpation(stomach, rings=4, device=device)
        pal.touch(seed)
        ref = pal.press(**SHORT)
        if kernel == "exact":  # the same loop as the one-palpation kernel: the same bits on CPU and CUDA
            assert res.peak_force[b] == ref.peak_force_N
            assert res.recovery_error[b] * 1e3 == ref.recovery_error_mm
            if device == "cpu":
                assert res.hold_force[b] == ref.force[ref.release_step - 1]
        else:  # an approximate reciprocal square root, no division: the project's 1e-5
            np.testing.assert_allclose(res.peak_force[b], ref.peak_force_N, rtol=1e-5)
            np.testing.assert_allclose(res.hold_force[b], ref.force[ref.release_step - 1], rtol=1e-5)
            np.testing.assert_allclose(res.recovery_error[b] * 1e3, ref.recovery_error_mm, rtol=1e-3, atol=2e-5)
    assert np.all(res.peak_force > 0.5)


def test_batch_implicit_press_equals_palpation_bits(device, stomach):
    # backward Euler with CG, one thread per palpation: the same bits as the one-palpation solve
    res = BatchPalpation(stomach, rings=3, device=device, integrator="implicit").touch(SEEDS[:4]).press(**SHORT)
    for b, seed in enumerate(SEEDS[:4]):
        pal = Palpation(stomach, rings=3, device=device, integrator="implicit")
        pal.touch(seed)
        ref = pal.press(**SHORT)
        if device == "cpu":
            assert res.peak_force[b] == ref.peak_force_N
            assert res.recovery_error[b] * 1e3 == ref.recovery_error_mm
        else:
            np.testing.assert_allclose(res.peak_force[b], ref.peak_force_N, rtol=2e-6)
            np.testing.assert_allclose(res.recovery_error[b] * 1e3, ref.recovery_error_mm, rtol=1e-3, atol=2e-5)


@pytest.mark.parametrize("kernel", ["exact", "fast"])
def test_batch_launch_chunks_do_not_change_bits(device, stomach, kernel):
    # the state goes through global memory between launches: any split gives the same numbers
    whole = BatchPalpation(stomach, rings=3, device=device, kernel=kernel).touch(SEEDS[:3]).press(**SHORT)
    split = BatchPalpation(stomach, rings=3, device=device, kernel=kernel, threads=64).touch(SEEDS[:3]).press(**SHORT, steps_per_launch=7)
    np.testing.assert_array_equal(whole.peak_force, split.peak_force)
    np.testing.assert_array_equal(whole.recovery_error, split.recovery_error)


def test_batch_repeated_vertices(device, stomach):
    # the same contact twice in a batch gives the same result twice (palpations do not interact)
    res = BatchPalpation(stomach, rings=2, device=device).touch([693, 5, 693]).press(**SHORT)
    assert res.peak_force[0] == res.peak_force[2]
    assert res.recovery_error[0] == res.recovery_error[2]


@pytest.mark.parametrize("radius", [0.0, 0.004])
def test_a_batch_pressed_again_reuses_its_buffers(device, stomach, radius):
    # one batch gathering chunk after chunk from a region table (its device arrays kept, uploads staged
    # through pinned memory on CUDA) gives what a new batch gives for each chunk, bit for bit
    chunks = [[693, 5, 693, 311], [5, 1001, 311, 693], [1001, 1001, 5, 5], [311, 5]]
    reused = BatchPalpation(stomach, rings=2, device=device, probe_radius=radius)
    reused.cache_regions(sum(chunks, []), depth=SHORT["depth"])
    arrays = None
    for chunk in chunks:
        got = reused.touch(chunk, SHORT["depth"]).press(**SHORT)
        fresh = BatchPalpation(model=reused.model, rings=2, probe_radius=radius).touch(chunk, SHORT["depth"]).press(**SHORT)
        for name in ("vertex", "peak_force", "hold_force", "recovery_error", "region_vertices", "free_vertices"):
            np.testing.assert_array_equal(getattr(got, name), getattr(fresh, name), err_msg=name)
        if arrays is not None and len(chunk) == 4:
            assert reused.q_state is arrays[0] and reused.regions.region_vertex is arrays[1]  # kept, not made again
        arrays = (reused.q_state, reused.regions.region_vertex)
    assert reused.q_state.shape[0] == 2  # the smaller chunk has arrays of its size


def test_device_buffers_upload_and_reuse(device):
    from almsdm_warp.batch.batch_palpation import DeviceBuffers

    buffers = DeviceBuffers(wp.get_device(device))
    a = buffers.upload("a", np.arange(5, dtype=np.int32), wp.int32)
    b = buffers.upload("b", np.arange(6, dtype=np.float64).reshape(2, 3), wp.vec3d)
    np.testing.assert_array_equal(a.numpy(), np.arange(5))
    np.testing.assert_array_equal(b.numpy(), np.arange(6).reshape(2, 3))
    a2 = buffers.upload("a", np.arange(5, 10, dtype=np.int32), wp.int32)  # the same array, new values
    assert a2.ptr == a.ptr or device == "cpu"
    np.testing.assert_array_equal(a2.numpy(), np.arange(5, 10))
    z = buffers.array("z", (2, 3), wp.float32)
    z.fill_(7.0)
    assert buffers.array("z", (2, 3), wp.float32) is z and not z.numpy().any()  # the same, zeroed again
    z.fill_(7.0)
    first = buffers.array("z", (1, 3), wp.float32)  # fewer rows: a view of the held array's first, zeroed
    assert first.ptr == z.ptr and first.shape == (1, 3) and not first.numpy().any() and z.numpy()[1].all()
    assert buffers.array("z", (2, 3), wp.float32) is z  # still held
    assert buffers.array("z", (3, 3), wp.float32) is not z
    assert buffers.array("z", (3, 2), wp.float32).shape == (3, 2)  # another row length: a new array


@pytest.mark.parametrize("radius", [0.0, 0.004])
def test_region_table_gathers_the_built_regions(stomach, radius):
    # a batch of repeated contacts gathered from the table of its distinct ones against the same batch
    # built contact by contact: every region array, the counts, the contacts' local index and the press
    # equal, bit for bit (with a sphere, patches of the press's depth)
    contacts = np.array([693, 5, 693, 311, 5, 1001])
    built = BatchPalpation(stomach, rings=2, device="cpu", probe_radius=radius)
    cached = BatchPalpation(model=built.model, rings=2, probe_radius=radius)
    table = cached.cache_regions([1001, 5, 311, 693, 5], depth=SHORT["depth"])
    np.testing.assert_array_equal(table.vertices, [5, 311, 693, 1001])
    a, b = built.touch(contacts, SHORT["depth"]).regions, cached.touch(contacts, SHORT["depth"]).regions
    assert cached._region_host is not None  # gathered, not built
    counts = {n: getattr(a, n).numpy() for n in ("region_count", "free_count", "entry_count", "spring_count", "status")}
    for n, c in counts.items():
        np.testing.assert_array_equal(getattr(b, n).numpy(), c, err_msg=n)
    np.testing.assert_array_equal(b.ring_offsets.numpy(), a.ring_offsets.numpy())
    rows = {"region_vertex": "region_count", "local_offsets": "free_count", "local_neighbour": "entry_count",
            "local_edge": "entry_count", "local_owner": "entry_count", "local_spring": "entry_count",
            "spring_entry": "spring_count"}
    for name, count in rows.items():
        x, y = getattr(a, name).numpy(), getattr(b, name).numpy()
        for k, n in enumerate(counts[count] + (name == "local_offsets")):
            np.testing.assert_array_equal(y[k, :n], x[k, :n], err_msg=f"{name} of palpation {k}")
    np.testing.assert_array_equal(cached.contact_local.numpy(), built.contact_local.numpy())
    ra, rb = built.press(**SHORT), cached.press(**SHORT)
    for name in ("peak_force", "hold_force", "recovery_error"):
        np.testing.assert_array_equal(getattr(rb, name), getattr(ra, name), err_msg=name)
    # a contact the table lacks is built as before
    cached.touch([693, 0], SHORT["depth"])
    assert cached._region_host is None
    np.testing.assert_array_equal(cached.region(1), built.touch([0], SHORT["depth"]).region(0))


def test_batch_rejects_bad_vertices(stomach):
    bp = BatchPalpation(stomach, rings=2, device="cpu")
    with pytest.raises(ValueError, match="outside the mesh"):
        bp.touch([0, 5000])
    with pytest.raises(ValueError, match="non-empty"):
        bp.touch([])
    with pytest.raises(RuntimeError, match="touch"):
        bp.press()


def test_batch_region_covering_a_small_component(device):
    # a tetrahedron's surface: 2 rings cover it, the outer non-empty ring (1) is fixed, as in Region
    from almsdm_warp.mesh.tissue_mesh import TissueMesh

    tet = TissueMesh.from_arrays(
        np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [0, 0, 30]], dtype=float),
        np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
    )
    bp = BatchPalpation(tet, rings=3, device=device).touch([0, 2])
    for b, seed in enumerate([0, 2]):
        ref = Region(tet, device).build(seed, 3)
        np.testing.assert_array_equal(bp.region(b), ref.vertices())
        assert bp.free_vertex_counts[b] == ref.free_count == 1
    assert np.all(np.isfinite(bp.press(**SHORT).peak_force))


def test_batch_tets_with_supports_as_a_brute_force_search(device):
    # a tet law's regions reaching below a support: the held vertices leave the free set and go after it,
    # out of ring order (hold_supports), so each region vertex's local tets and each free vertex's local
    # neighbours are searched in the region's sorted runs (find_in_runs); the answer: a dictionary of the
    # region's mesh ids, each tet corner its local index or -(id + 1) outside the region
    from almsdm_warp.mesh.primitives import tet_ball
    from almsdm_warp.sim.model import Model
    from almsdm_warp.tissue.material import Material

    mesh = tet_ball(15.0, 3.0)
    material = Material(youngs_modulus=5e3, poisson_ratio=0.45, density=1000.0, rayleigh_alpha=60.0)
    model = Model(mesh, material, device, law="neo-hookean", fixed_below=-6e-3)
    surface = mesh.surface_vertices
    z = mesh.vertices[surface, 2]
    contacts = surface[(z > -4e-3) & (z < -1e-3)][:6]
    bp = BatchPalpation(model=model, rings=3).touch(contacts)
    held = model.support_mask
    offsets, neighbours, _ = mesh.adjacency
    entry_offsets, entry_topology = model.entry_offsets.numpy(), model.entry_topology.numpy()
    local_offsets, local_neighbour = bp.regions.local_offsets.numpy(), bp.regions.local_neighbour.numpy()
    element_offsets, element_topology = bp.element_offsets.numpy(), bp.element_topology.numpy()
    moved = 0
    for b in range(len(contacts)):
        got = bp.region(b)
        nf = bp.free_vertex_counts[b]
        ref = Region(mesh, device).build(int(contacts[b]), 3)
        assert set(got) == set(ref.vertices()) and not held[got[:nf]].any()
        moved += int(held[ref.vertices()[: ref.free_count]].any())
        local = {int(v): i for i, v in enumerate(got)}
        for i in range(nf):
            k0, k1 = local_offsets[b, i], local_offsets[b, i + 1]
            np.testing.assert_array_equal(local_neighbour[b, k0:k1], [local[int(u)] for u in neighbours[offsets[got[i]]:offsets[got[i] + 1]]])
        for i, v in enumerate(got):
            want = [[local.get(int(c), -int(c) - 1) for c in t] for t in entry_topology[entry_offsets[v]:entry_offsets[v + 1]]]
            np.testing.assert_array_equal(element_topology[b, element_offsets[b, i]:element_offsets[b, i + 1]], want)
    assert moved >= 3  # most of these regions had held vertices among their free rings


def test_batch_fast_kernel_same_bits_with_fewer_threads_than_free_vertices(stomach):
    # with 32 threads the free vertices beyond the block's threads take the shared-memory path
    # instead of registers: where the step's data lives changes, not its arithmetic or order
    ref = BatchPalpation(stomach, rings=4, device="cpu", kernel="fast").touch(SEEDS).press(**SHORT)
    bp = BatchPalpation(stomach, rings=4, device="cpu", kernel="fast", threads=32).touch(SEEDS)
    assert bp.free_vertex_counts.max() > 32
    res = bp.press(**SHORT, steps_per_launch=7)
    for name in ("peak_force", "hold_force", "recovery_error"):
        np.testing.assert_array_equal(getattr(res, name), getattr(ref, name), err_msg=name)


def test_batch_rejects_unknown_kernel(stomach):
    with pytest.raises(ValueError, match="unknown kernel 'entries'"):
        BatchPalpation(stomach, rings=2, device="cpu", kernel="entries")


# -- the sphere, supports and the material model --------------------------------------------------
MATERIAL = dict(youngs_modulus=5e3, thickness=0.003, foundation=1e6, damping_ratio=0.5)
"""A membrane on a foundation (tissue/material.py): every spring, anchor, damper and mass from E, nu, rho."""
SPHERE_PRESS = dict(depth=0.005, ramp=0.05, hold=0.05, settle=0.1)
DT = 5e-4
"""Under the critical step of these regions: one substep, so that a batch's steps are Palpation's frames."""


@pytest.fixture(scope="module")
def supported(stomach):
    """(material, support plane [m], contacts above it whose regions reach below it)."""
    from almsdm_warp.tissue.material import Material

    z = float(np.percentile(stomach.vertices[:, 2], 20))
    order = np.argsort(stomach.vertices[:, 2])
    return Material(**MATERIAL), z, [int(v) for v in order[[300, 700, 1000]]]


def _sphere_batch(stomach, supported, device, radius=0.004, **kw):
    material, z, contacts = supported
    return BatchPalpation(stomach, material, rings=3, device=device, probe_radius=radius, fixed_below=z, dt=DT, **kw).touch(contacts)


@pytest.mark.parametrize("kernel,integrator,radius", [("exact", "explicit", 0.004), ("fast", "explicit", 0.004),
                                                      (None, "implicit", 0.004), ("exact", "explicit", 0.0)])
def test_batch_sphere_supports_material_equal_palpation(device, stomach, supported, kernel, integrator, radius):
    # radius 0: the paper's driven vertex on the same material and supports
    material, z, contacts = supported
    bp = _sphere_batch(stomach, supported, device, radius, kernel=kernel, integrator=integrator)
    res = bp.press(**SPHERE_PRESS)
    held = stomach.vertices[:, 2] < z
    assert bp.substeps == 1 and any(held[bp.region(b)].any() for b in range(len(contacts)))
    for b, v in enumerate(contacts):
        pal = Palpation(stomach, material, rings=3, device=device, integrator=integrator, probe_radius=radius, fixed_below=z, dt=DT)
        pal.touch(v)
        ref = pal.press(**SPHERE_PRESS)
        # the same region and free set (supported vertices moved after the free ones, as the solver has them)
        np.testing.assert_array_equal(bp.region(b)[: bp.free_vertex_counts[b]], pal.solver.free_vertex.numpy()[: pal.solver.free_count])
        got = (res.peak_force[b], res.hold_force[b], res.recovery_error[b] * 1e3)
        want = (ref.peak_force_N, ref.force[ref.release_step - 1], ref.recovery_error_mm)
        if kernel == "fast":  # an approximate reciprocal square root, the contact sum in another order
            np.testing.assert_allclose(got[:2], want[:2], rtol=5e-6)
            np.testing.assert_allclose(got[2], want[2], rtol=1e-2, atol=2e-5)
        elif device == "cpu":  # the one-palpation loops, in the same order: the same bits
            assert got == want
        else:
            np.testing.assert_allclose(got, want, rtol=2e-6, atol=1e-9)
    assert np.all(res.peak_force > 0.05)


def test_batch_fast_sphere_contact_sum_in_part_warps(stomach, supported):
    # 40 threads a block: not whole warps, so each thread's contact reactions are summed in thread
    # order (whole warps add theirs by a tree); an 8 mm sphere touches vertices beyond the block's
    # threads, which take the shared-memory path with its surface flags: the exact kernel's forces
    exact = _sphere_batch(stomach, supported, "cpu", radius=0.008, kernel="exact").press(**SPHERE_PRESS)
    bp = _sphere_batch(stomach, supported, "cpu", radius=0.008, kernel="fast", threads=40)
    assert bp.threads == 40 and bp.free_vertex_counts.min() > 40
    res = bp.press(**SPHERE_PRESS)
    np.testing.assert_allclose(res.peak_force, exact.peak_force, rtol=5e-6)
    np.testing.assert_allclose(res.hold_force, exact.hold_force, rtol=5e-6)
    assert np.all(exact.peak_force > 0.3)


def test_batch_supports_never_move(device, stomach, supported):
    material, z, contacts = supported
    bp = _sphere_batch(stomach, supported, device)
    bp.press(**SPHERE_PRESS)
    q = bp.q_state.numpy()
    rest = stomach.vertices.astype(np.float32)
    moved = 0
    for b in range(len(contacts)):
        region = bp.region(b)
        held = stomach.vertices[region, 2] < z
        assert not held[: bp.free_vertex_counts[b]].any()
        local = np.flatnonzero(held)
        np.testing.assert_array_equal(q[b, local], rest[region[local]])
        moved += np.count_nonzero(np.any(q[b, : bp.free_vertex_counts[b]] != rest[region[: bp.free_vertex_counts[b]]], axis=1))
    assert moved > 0


def test_sphere_patches_follow_their_rule_in_any_chunking(stomach, supported):
    """The one patch rule (Palpation's ring 0 and the batch's, region.patch.sphere_patches) against a
    loop over the surface: within sqrt(2 R d) plus the longest edge, facing the probe, and the contact."""
    import math

    from almsdm_warp.region.patch import sphere_patches

    contacts = [0, 17, 311, 500, 693, 1001]
    pal = Palpation(stomach, rings=2, device="cpu", probe_radius=0.006)
    offsets, ids = sphere_patches(pal.model, np.array(contacts), 0.006, 0.008, chunk=4)  # chunks of 4: two of them
    x, normals = stomach.vertices, pal.model.vertex_normal_rest
    reach = math.sqrt(2 * 0.006 * 0.008) + float(stomach.edge_rest_length.max())
    for b, v in enumerate(contacts):
        expected = sorted({v} | {int(s) for s in stomach.surface_vertices
                                 if math.dist(x[s], x[v]) <= reach and float(np.dot(normals[s], normals[v])) > 0.0})
        np.testing.assert_array_equal(ids[offsets[b] : offsets[b + 1]], expected)
        np.testing.assert_array_equal(pal.sphere_patch(v, 0.008), expected)


def test_batch_sphere_on_anchors_is_winklers_foundation(device, anchor_bed):
    # the closed form of tests/test_probe_sphere.py, two palpations at the same spot in one batch
    from test_probe_sphere import DEPTH, R, anchor_references

    mesh, tissue, area, centre = anchor_bed
    bp = BatchPalpation(mesh, tissue, rings=2, device=device, anchor_scale=area, probe_radius=R).touch([centre, centre])
    res = bp.press(DEPTH, ramp=0.05, hold=0.1, settle=0.002)
    winkler, radial = anchor_references(R, DEPTH)
    np.testing.assert_allclose(res.hold_force, radial, rtol=2e-3)
    np.testing.assert_allclose(res.hold_force, winkler, rtol=0.03)


def test_batch_sphere_and_support_errors(stomach, supported):
    material, z, contacts = supported
    with pytest.raises(ValueError, match=r"probe_radius \[m\] must be >= 0"):
        BatchPalpation(stomach, rings=2, device="cpu", probe_radius=-0.001)
    low = int(np.argmin(stomach.vertices[:, 2]))
    with pytest.raises(ValueError, match=f"vertex {low} \\(palpation 1\\) is held by the support"):
        BatchPalpation(stomach, rings=2, device="cpu", fixed_below=z).touch([contacts[0], low])
    bp = BatchPalpation(stomach, rings=2, device="cpu", probe_radius=0.0001).touch(contacts[:1])
    with pytest.raises(ValueError, match="not less than its radius"):
        bp.press(depth=0.01, ramp=0.01, hold=0.0, settle=0.01)


def test_sweep_with_sphere_supports_and_material(tmp_path, stomach, supported, capsys):
    # the command line's sweep presses what a batch presses (the same bits on the CPU); no supported point.
    # paper_stomach: a scene whose other tissue keys (density 1000) are the fixture's
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
    from almsdm_warp.cli.main import main

    material, z, _ = supported
    out = tmp_path / "sweep.csv"
    flags = ["--youngs-modulus-kpa", "5", "--thickness-mm", "3", "--foundation-kpa-per-mm", "1", "--damping-ratio", "0.5"]
    assert main(["sweep", "paper_stomach", "--out", str(out), "--points", "10", "--rings", "3", "--probe-radius-mm", "4", "--fixed-below-mm",
                 f"{z * 1e3!r}", "--depth-mm", "5", "--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.1", *flags]) == 0
    table = SWEEP_TABLE.read(out)
    assert 0 < len(table["vertex"]) < 10 and np.all(stomach.vertices[table["vertex"], 2] >= z)
    res = BatchPalpation(stomach, material, rings=3, device="cpu", probe_radius=0.004, fixed_below=z).touch(table["vertex"]).press(**SPHERE_PRESS)
    np.testing.assert_array_equal(table["peak_force_N"], res.peak_force)
    # --rings auto with a sphere: each point's rings those an adaptive sphere press grows to (batch.sweep_auto)
    from almsdm_warp.batch.sweep_auto import size_regions

    short = ["--depth-mm", "5", "--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05"]
    assert main(["sweep", "--out", str(tmp_path / "x.csv"), "--rings", "auto", "--probe-radius-mm", "4", "--points", "2", *short]) == 0
    auto = SWEEP_TABLE.read(tmp_path / "x.csv")
    scene = load_scene(SCENES / "stomach.toml")
    want = size_regions(stomach, scene.tissue, auto["vertex"], 1e-4, depth=5e-3, ramp=0.05, hold=0.05, probe_radius=0.004)
    np.testing.assert_array_equal(auto["rings"], want)
