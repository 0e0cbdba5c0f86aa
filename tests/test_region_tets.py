"""A region's tets for the per-tet nodal pressure pass (kernels/region/volumes.py) against a brute force
over the mesh's tets in float64, and the explicit step with that pass against the per-vertex one."""

import numpy as np
import pytest
import warp as wp

from almsdm_warp.kernels.explicit.step import update_pressure
from almsdm_warp.kernels.region.volumes import RegionTets
from almsdm_warp.mesh.primitives import tet_ball
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.protocol.stroke import ProbeStroke, builtin_stroke
from almsdm_warp.sim.model import Model
from almsdm_warp.solvers.explicit import SolverExplicit
from almsdm_warp.tissue.laws import lame
from almsdm_warp.tissue.material import Material

MATERIAL = Material(youngs_modulus=10e3, poisson_ratio=0.45, density=1000.0, rayleigh_alpha=60.0)


def brute_pressures(mesh, q, vertices):
    """Each vertex's nodal pressure kappa_a (sum_t v_t / sum_t V_t - 1) over all its tets, float64."""
    tets = mesh.tetrahedra.astype(np.int64)
    x0 = mesh.vertices.astype(np.float64)

    def det(x):
        a, b, c, d = (x[tets[:, k]] for k in range(4))
        return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))

    orientation = np.sign(det(x0))
    rest, now = np.abs(det(x0)) / 6.0, det(q.astype(np.float64)) * orientation / 6.0  # signed: an inverted tet's is negative
    _, lam = lame(MATERIAL.youngs_modulus, MATERIAL.poisson_ratio)
    n = len(x0)
    s = np.bincount(tets.ravel(), weights=np.repeat(rest, 4), minlength=n)
    v = np.bincount(tets.ravel(), weights=np.repeat(now, 4), minlength=n)
    return lam * (v[vertices] / s[vertices] - 1.0), lam


@pytest.fixture(scope="module")
def ball():
    return tet_ball(15.0, 3.0)


def region_of(palpation):
    solver = palpation.solver
    counts = solver.counts.numpy()
    order = solver.free_vertex.numpy()
    return solver, order[: counts[0]], order[: counts[1]]


def test_each_tet_with_a_free_corner_once_and_pressures_as_brute_force(device, ball):
    """The build lists each tet with a free corner once; the pass's pressures at a state where every
    vertex moved (the fixed ring's tets outside the free set at their build-time volumes) are the
    brute force's over all of each vertex's tets, and the per-vertex pass's to float32's rounding."""
    pal = Palpation(ball, MATERIAL, rings=2, law="neo-hookean", dt=1e-4, device=device, substeps=1)
    top = int(np.argmax(ball.vertices[:, 2]))
    pal.touch(top)
    solver, free, region = region_of(pal)
    rng = np.random.default_rng(3)
    q = (ball.vertices + rng.normal(scale=2e-4, size=ball.vertices.shape)).astype(np.float32)
    state = pal.model.state()
    state.particle_q.assign(q)
    tets = RegionTets(pal.model)
    tets.build(solver.free_vertex, solver.counts, solver.vertex_local, state.particle_q)
    listed = tets.arrays.tets.numpy()[: int(tets.arrays.count.numpy()[0])]
    is_free = np.zeros(ball.vertex_count, dtype=bool)
    is_free[free] = True
    want = {tuple(sorted(t)) for t in ball.tetrahedra if is_free[t].any()}
    assert len(listed) == len(want) and {tuple(sorted(t)) for t in listed} == want
    # the free vertices move after the build: their tets are computed again, the others' kept
    q2 = q.copy()
    q2[free] += rng.normal(scale=2e-4, size=(len(free), 3)).astype(np.float32)
    state.particle_q.assign(q2)
    tets.pressures(solver.free_vertex, solver.counts, 1 if device == "cpu" else len(region), state.particle_q)
    got = pal.model.nodal_pressure.numpy()[region].astype(np.float64)
    ref, lam = brute_pressures(ball, q2, region)
    assert np.abs(ref).max() > 1e-3 * lam  # a state with volume changes to see
    np.testing.assert_allclose(got, ref, atol=2e-6 * lam)
    update_pressure(pal.model, solver.free_vertex, solver.counts, 1 if device == "cpu" else len(region), state.particle_q)
    np.testing.assert_allclose(got, pal.model.nodal_pressure.numpy()[region], atol=2e-6 * lam)


@pytest.mark.parametrize("law", ["neo-hookean", "corotational"])
def test_a_press_with_either_pass_is_the_same_press(device, ball, law):
    """A 1 mm press, a region of 2 rings, the same on either nodal pressure pass to float32's rounding;
    the CPU's default is the per-tet pass, CUDA's the per-vertex one (SolverExplicit.tet_pass)."""
    got = {}
    for kind in ("tets", "vertices"):
        pal = Palpation(ball, MATERIAL, rings=2, law=law, dt=1e-3, device=device, substeps=6, fixed_below=-8e-3)
        pal.touch(int(np.argmax(ball.vertices[:, 2])))
        pal.solver.tet_pass = kind
        r = pal.press(1e-3, ramp=0.05, hold=0.1, settle=0.05)
        assert (pal.solver.tet_listing is not None) == (kind == "tets")
        got[kind] = (r.peak_force_N, r.displacement[-1])
    assert got["tets"][0] > 0.02
    np.testing.assert_allclose(got["tets"][0], got["vertices"][0], rtol=1e-5)
    np.testing.assert_allclose(got["tets"][1], got["vertices"][1], atol=1e-8)
    default = SolverExplicit(Model(ball, MATERIAL, device, law=law))
    default.set_global()
    assert (default.built_tets(default.model.state().particle_q) is not None) == (device == "cpu")


def test_a_stroke_rebuilds_its_tets_when_its_region_moves(ball):
    """A sliding sphere whose region moves: its tets are built again at each move, so that the force
    along the path is the per-vertex pass's to float32's rounding, relocations and all."""
    path = builtin_stroke(ball, 5e-3, dt=1e-3, depth=2e-3, length=20e-3, speed=20e-3)
    got = {}
    for kind in ("tets", "vertices"):
        s = ProbeStroke(ball, MATERIAL, probe_radius=5e-3, rings=2, dt=1e-3, device="cpu", law="neo-hookean")
        s.solver.tet_pass = kind
        got[kind] = np.array([np.array(s.step(c), dtype=np.float64).ravel() for c in path.centre])
        moves = s.relocations
    assert moves >= 2
    peak = np.abs(got["vertices"]).max()
    assert peak > 0.01
    np.testing.assert_allclose(got["tets"], got["vertices"], atol=1e-4 * peak)


@pytest.mark.parametrize("law", ["neo-hookean", "corotational"])
def test_one_step_with_each_tets_forces_once_is_the_per_vertex_step(device, ball, law):
    """One explicit step from a state where every vertex moved and moves: each tet's forces computed once
    (the law's tet_forces, summed at each free vertex in entry order) step the free vertices as the
    per-vertex gather does, to float32's rounding of the forces; the fixed ones stay."""
    rng = np.random.default_rng(5)
    q = (ball.vertices + rng.normal(scale=2e-4, size=ball.vertices.shape)).astype(np.float32)
    u = rng.normal(scale=1e-2, size=ball.vertices.shape).astype(np.float32)
    got = {}
    for kind in ("tets", "vertices"):
        pal = Palpation(ball, MATERIAL, rings=2, law=law, dt=1e-4, device=device, substeps=1)
        pal.touch(int(np.argmax(ball.vertices[:, 2])))
        pal.solver.tet_pass = kind
        a, b = pal.states
        for s in (a, b):
            s.particle_q.assign(q)
            s.particle_qd.assign(u)
        pal.solver.step(a, b, pal.control, 1e-4)
        got[kind] = (b.particle_q.numpy(), b.particle_qd.numpy())
        _, free, region = region_of(pal)
    dv = got["vertices"][1] - u
    assert np.abs(dv[free]).max() > 1e-3  # the forces move the free vertices' velocities
    np.testing.assert_allclose(got["tets"][1], got["vertices"][1], atol=1e-5 * np.abs(dv[free]).max())
    np.testing.assert_allclose(got["tets"][0], got["vertices"][0], atol=1e-7)
    outside = np.setdiff1d(np.arange(ball.vertex_count), free)
    np.testing.assert_array_equal(got["tets"][0][outside], q[outside])
