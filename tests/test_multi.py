"""Several probes at once (issue 7, item 2): a region each, merged where they touch, retired at rest.
Against independent answers: single-probe palpations (far probes do not interact), breadth-first
distances from scipy (the merged region), and a float64 Newton solve of the static equilibrium
with both probes held (the merged region's reactions)."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import shortest_path
from test_simulation_press import scene_and_mesh, static_reactions, top_vertex

from almsdm_warp.protocol.adaptive import AdaptivePalpation
from almsdm_warp.sim.model import PROBE_DISPLACEMENT
from almsdm_warp.protocol.multi import MultiPalpation, MultiRegion

DEPTH = 10.0e-3


def hops(mesh, seeds):
    """Hop distance of every vertex to the nearest seed (scipy breadth-first), inf if unreachable."""
    n = mesh.vertex_count
    e = mesh.edges.astype(np.int64)
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    return shortest_path(a, unweighted=True, directed=False, indices=list(seeds)).min(axis=0)


def far_pair(mesh):
    a = top_vertex(mesh)
    sv = mesh.surface_vertices
    return a, int(sv[np.argmax(np.linalg.norm(mesh.vertices[sv] - mesh.vertices[a], axis=1))])


def near_pair(mesh, apart=3):
    a = top_vertex(mesh)
    d = hops(mesh, [a])
    sv = mesh.surface_vertices
    return a, int(sv[np.flatnonzero(d[sv] == apart)[0]])


def test_region_from_several_seeds_is_breadth_first(device):
    _, mesh = scene_and_mesh()
    a, b = near_pair(mesh, apart=5)
    region = MultiRegion(mesh, device).build_seeds([b, a], 3)
    d = hops(mesh, [a, b])
    np.testing.assert_array_equal(np.sort(region.vertices()), np.flatnonzero(d <= 3))
    np.testing.assert_array_equal(np.sort(region.boundary()), np.flatnonzero(d == 3))
    np.testing.assert_array_equal(region.vertex_ring.numpy()[np.flatnonzero(d <= 3)], d[d <= 3])
    region.expand(1)
    np.testing.assert_array_equal(np.sort(region.vertices()), np.flatnonzero(d <= 4))


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_far_probes_are_two_single_palpations(device, integrator):
    """Two probes far apart: two regions that never merge, each growing and pressing as one
    AdaptivePalpation alone at its vertex (same rings, same force; implicit: within 2% at the
    ramp's corner, 0.1% at the peak), both retired at the end."""
    scene, mesh = scene_and_mesh()
    dt = 1e-3 if integrator == "explicit" else 5e-3
    pair = far_pair(mesh)
    multi = MultiPalpation(mesh, scene.tissue, tol=1e-4, integrator=integrator, dt=dt, device=device)
    multi.touch(pair)
    assert len(multi.patches) == 2
    results = multi.press(DEPTH, ramp=0.1, hold=0.1, settle=0.3)
    assert multi.patches == [] and len(multi.retired) == 2
    for i, v in enumerate(pair):
        alone = AdaptivePalpation(mesh, scene.tissue, tol=1e-4, integrator=integrator, dt=dt, device=device)
        alone.touch(v)
        expected = alone.press(DEPTH, ramp=0.1, hold=0.1, settle=0.3)
        retired = next(r for r in multi.retired if r["probes"] == [i])
        assert retired["rings"] == alone.press_log[0]["rings"]
        if integrator == "explicit":  # the same step, the reaction summed in another order
            np.testing.assert_allclose(results[i].force, expected.force, rtol=1e-5, atol=1e-6)
            np.testing.assert_allclose(results[i].displacement, expected.displacement, rtol=1e-5, atol=1e-8)
        else:  # backward Euler sees a held vertex at its last velocity: off for a few steps at the ramp's end
            np.testing.assert_allclose(results[i].force, expected.force, rtol=0.02, atol=1e-6)
            np.testing.assert_allclose(results[i].peak_force_N, expected.peak_force_N, rtol=1e-3)
            hold_end = expected.release_step - 1
            np.testing.assert_allclose(results[i].force[hold_end], expected.force[hold_end], rtol=1e-4)
    rest = multi.model.particle_q_rest.numpy()
    for state in multi.states:
        np.testing.assert_array_equal(state.particle_q.numpy(), rest)


def test_touching_regions_merge_and_hold_both_probes(device):
    """Two probes 3 hops apart with 2 rings each: their regions share vertices, so they are one
    region grown from both (scipy's breadth-first set). Both pressed 10 mm and held (implicit,
    quasi-static): the reactions match a float64 static solve with both vertices held."""
    scene, mesh = scene_and_mesh()
    pair = near_pair(mesh, apart=3)
    multi = MultiPalpation(mesh, scene.tissue, rings=2, integrator="implicit", dt=5e-3, device=device)
    multi.touch(pair)
    assert len(multi.patches) == 1 and multi.patches[0].probes == [0, 1]
    d = hops(mesh, pair)
    region = multi.patches[0].region
    np.testing.assert_array_equal(np.sort(region.vertices()), np.flatnonzero(d <= 2))
    rest, normal = multi.rest_positions(), multi.inward_normals()
    for s in range(200):
        targets = rest + normal * DEPTH * min((s + 1) / 20, 1.0)
        multi.set_probes(PROBE_DISPLACEMENT, targets)
        forces = multi.step().copy()
    free = np.flatnonzero(d < 2)
    expected = static_reactions(mesh, scene.tissue, np.asarray(pair), targets.astype(np.float32).astype(np.float64), free)
    np.testing.assert_allclose(forces, expected, rtol=2e-4, atol=1e-4)
    # the probes push each other: each reaction differs from its probe's alone
    alone = static_reactions(mesh, scene.tissue, np.asarray(pair[:1]), targets[:1], np.flatnonzero(hops(mesh, pair[:1]) < 2))
    assert np.linalg.norm(alone[0] - expected[0]) > 1e-3 * np.linalg.norm(expected[0])


def test_adaptive_regions_merge_when_they_grow_into_each_other(device):
    """Probes 5 hops apart start with separate 1-ring regions; growing to the tolerance they meet
    and become one, which then holds both probes and retires after the release."""
    scene, mesh = scene_and_mesh()
    pair = near_pair(mesh, apart=5)
    multi = MultiPalpation(mesh, scene.tissue, tol=3e-5, integrator="implicit", dt=5e-3, device=device)
    multi.touch(pair)
    assert len(multi.patches) == 2
    results = multi.press(DEPTH, ramp=0.1, hold=0.1, settle=0.3)
    assert len(multi.retired) == 1 and multi.retired[0]["probes"] == [0, 1]
    events = [e["event"] for e in multi.retired[0]["events"]]
    assert "merged" in events and events[-1] == "retired"
    assert all(r.peak_force_N > 1.0 and np.isfinite(r.force).all() for r in results)


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_one_probe_released_while_the_other_holds(device, integrator):
    """Probe 0 released, probe 1 held: probe 0's region relaxes and is retired alone (its vertices
    exactly at rest) while probe 1's goes on; pressed again, probe 0 gets a fresh region and the
    same forces as its first press."""
    scene, mesh = scene_and_mesh()
    dt = 1e-3 if integrator == "explicit" else 5e-3
    multi = MultiPalpation(mesh, scene.tissue, tol=1e-4, integrator=integrator, dt=dt, device=device)
    multi.touch(far_pair(mesh))
    rest, normal = multi.rest_positions(), multi.inward_normals()
    ramp = int(round(0.05 / dt))

    def press0(steps):
        out = []
        for s in range(steps):
            multi.set_probes([PROBE_DISPLACEMENT, PROBE_DISPLACEMENT], rest + normal * DEPTH * min((s + 1) / ramp, 1.0))
            out.append(multi.step()[0].copy())
        return np.array(out)

    first = press0(2 * ramp)
    region0 = multi.patch_of(0).vertices()
    for _ in range(int(round(0.3 / dt))):
        multi.set_probes([0, PROBE_DISPLACEMENT], rest + normal * DEPTH)
        held = multi.step()[1].copy()
    assert multi.patch_of(0) is None and multi.patch_of(1) is not None
    assert [r["probes"] for r in multi.retired] == [[0]]
    q0 = multi.model.particle_q_rest.numpy()
    for state in multi.states:
        np.testing.assert_array_equal(state.particle_q.numpy()[region0], q0[region0])
    assert np.linalg.norm(held) > 1.0  # probe 1 still pressing
    again = press0(2 * ramp)
    np.testing.assert_allclose(again, first, rtol=1e-6, atol=1e-7)


def test_bad_probe_sets(device):
    scene, mesh = scene_and_mesh()
    multi = MultiPalpation(mesh, scene.tissue, device=device)
    with pytest.raises(ValueError, match="distinct"):
        multi.touch([5, 5])
    with pytest.raises(ValueError):
        multi.touch([mesh.vertex_count])
    with pytest.raises(ValueError):
        MultiPalpation(mesh, scene.tissue, tol=0.0, device=device)
    multi.touch([5, 6])
    with pytest.raises(ValueError, match="PROBE_OFF"):
        multi.set_probes([1, 2])


def test_a_multi_press_that_diverged_is_pressed_again_from_where_it_began(device):
    """As Palpation's (test_simulation_press.py): two probes on a neo-Hookean ball, their plan too bold (the
    patches' critical step taken 2.2x too long, one substep of 1.6x the true one), diverge; the press is
    pressed again from where it began at twice the substeps and gives the numbers of a plan of two
    substeps, bit for bit. A press not begun right after touch() is not pressed again."""
    from almsdm_warp.mesh.primitives import tet_ball
    from almsdm_warp.solvers.stepper import SimulationDiverged
    from almsdm_warp.tissue.material import Material

    mesh, tissue = tet_ball(30.0, 8.0), Material(youngs_modulus=5e3, density=1000.0, rayleigh_alpha=60.0)
    pair = [int(np.argmax(mesh.vertices[:, 2])), int(np.argmax(mesh.vertices[:, 0]))]
    made = lambda dt: MultiPalpation(mesh, tissue, rings=2, dt=dt, device=device, law="neo-hookean", retire=False)
    probe = made(1e-3)
    probe.touch(pair)
    probe.step()
    assert len(probe.patches) == 2  # two regions, apart
    true = probe.critical_dt
    press = dict(depth=4e-3, ramp=0.02, hold=0.01, settle=0.01)
    runs = []
    for estimate in (2.2 * true, true):  # the bold plan (1 substep), and a plan of 2 at the same frame
        multi = made(1.6 * true)
        multi.model.critical_dt = lambda *args, _c=estimate, **kw: _c
        multi.touch(pair)
        runs.append((multi, multi.press(**press)))
    (bold, got), (_, want) = runs
    assert [r.substeps for r in got] == [2, 2] == [r.substeps for r in want] and bold.substeps == 2
    assert [r.diverged_at for r in got] == [(1,), (1,)] and [r.diverged_at for r in want] == [(), ()]
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.force, w.force)
        np.testing.assert_array_equal(g.displacement, w.displacement)
    late = made(1.6 * true)
    late.model.critical_dt = lambda *args, **kw: 2.2 * true
    late.touch(pair)
    late.step()  # not right after touch(): its state is not the one a fresh touch makes
    with pytest.raises(SimulationDiverged):
        late.press(**press)
