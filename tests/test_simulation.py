"""The ALMSDM solver on one triangle against closed forms: Hooke's law, eqs. (3)-(6) term by term,
a damped and an undamped oscillator, one backward-Euler step, and the critical step.

The mesh is a right triangle with 10 mm legs, vertex 0 at the origin (so that float32 positions
near it resolve sub-nanometre offsets). Region(seed 0, rings 1) frees vertex 0 alone; vertices 1
and 2 are the fixed ring. The press tests on the organ scenes are in test_simulation_press.py.
"""

import math

import numpy as np
import pytest

from almsdm_warp import Region, TissueMesh
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, PROBE_OFF, Model
from almsdm_warp.solvers import INTEGRATORS as REGISTERED, make_solver
from almsdm_warp.tissue.params import TissueParams

LEG = 10.0e-3  # [m]
EPS32 = float(np.finfo(np.float32).eps)
INTEGRATORS = ("explicit", "implicit")


def triangle_mesh():
    vertices = np.array([[0.0, 0.0, 0.0], [LEG, 0.0, 0.0], [0.0, LEG, 0.0]])
    return TissueMesh(vertices, np.array([[0, 1, 2]]))


class Triangle:
    """Model, region (vertex 0 free), solver, two states and a control on one device."""

    def __init__(self, tissue, device, integrator):
        self.mesh = triangle_mesh()
        self.tissue = tissue
        self.model = Model(self.mesh, tissue, device)
        self.region = Region(self.model.dmesh).build(0, 1)
        assert self.region.free_count == 1 and sorted(self.region.boundary().tolist()) == [1, 2]
        self.solver = make_solver(self.model, integrator)
        self.solver.set_region(self.region)
        self.state_in = self.model.state()
        self.state_out = self.model.state()
        self.control = self.model.control()
        # what the device holds: float32 rest positions and rest lengths
        self.rest = self.model.particle_q_rest.numpy().astype(np.float64)
        self.rest_length = self.model.spring_rest_length.numpy().astype(np.float64)
        self.mass = float(self.model.particle_mass_host[0])

    def set_state(self, q=None, qd=None):
        if q is not None:
            self.state_in.particle_q.assign(np.asarray(q, dtype=np.float32))
        if qd is not None:
            self.state_in.particle_qd.assign(np.asarray(qd, dtype=np.float32))

    def step(self, dt):
        self.solver.step(self.state_in, self.state_out, self.control, dt)

    def swap(self):
        self.state_in, self.state_out = self.state_out, self.state_in

    def spring(self, a, b):
        """Index of the mesh edge (a, b) and its rest length [m]."""
        e = int(np.flatnonzero(np.all(np.sort(self.mesh.edges, axis=1) == sorted((a, b)), axis=1))[0])
        return e, self.rest_length[e]


def expected_force(tri, q, qd):
    """Eqs. (3)-(6) on vertex 0, written out in float64 from the device's float32 inputs."""
    t = tri.tissue
    q = np.asarray(q, dtype=np.float32).astype(np.float64)
    qd = np.asarray(qd, dtype=np.float32).astype(np.float64)
    # anchor spring and damper, eq. (3)
    f = -t.anchor_stiffness * (q[0] - tri.rest[0]) - t.anchor_damping * qd[0]
    for j in (1, 2):
        _, rest_length = tri.spring(0, j)
        r = q[j] - q[0]
        length = np.linalg.norm(r)
        if length < 1e-9:
            continue  # a collapsed spring has no direction
        d = r / length
        f += t.edge_stiffness * (length - rest_length) * d  # Hooke, eqs. (4)-(5)
        f += t.edge_damping * np.dot(qd[j] - qd[0], d) * d  # damper along the edge, eq. (6)
    return f


def force_atol(tissue, q):
    """Float32 rounding of the spring lengths: a few ulps of the largest coordinate, times k."""
    scale = max(float(np.abs(q).max()), LEG)
    return 16 * EPS32 * scale * (tissue.edge_stiffness + tissue.anchor_stiffness)


HOOKE_TARGETS = {
    "tiny": [2.0e-5, -1.0e-5, 3.0e-5],
    "small": [3.0e-4, 2.0e-4, -5.0e-4],
    "out_of_plane": [0.0, 0.0, 5.0e-3],
    "large_stretch": [-20.0e-3, -15.0e-3, 10.0e-3],
    "compress_one": [8.0e-3, 1.0e-3, 0.0],
    "compress_both": [4.0e-3, 4.0e-3, 1.0e-4],
    "beyond_hypotenuse": [12.0e-3, 9.0e-3, -2.0e-3],
}


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_probe_reaction_is_hookes_law(device, integrator):
    """Displacement-controlled probe on vertex 0 at rest velocity: reaction = both springs + anchor."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.02, anchor_stiffness=124.0, anchor_damping=0.1)
    tri = Triangle(tissue, device, integrator)
    dt = 1.0e-3
    for name, target in HOOKE_TARGETS.items():
        q = tri.rest.copy()
        q[0] = target
        tri.set_state(q, np.zeros((3, 3)))
        tri.control.set(vertex=0, mode=PROBE_DISPLACEMENT, target=target)
        tri.step(dt)
        got = tri.control.probe_reaction.numpy()[0].astype(np.float64)
        want = expected_force(tri, q, np.zeros((3, 3)))
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=force_atol(tissue, q), err_msg=f"target {name}")
        # the probe holds its vertex on the target, at rest; the fixed ring is not written
        out_q = tri.state_out.particle_q.numpy()
        np.testing.assert_array_equal(out_q[0], np.float32(target))
        np.testing.assert_array_equal(tri.state_out.particle_qd.numpy()[0], 0.0)
        np.testing.assert_array_equal(out_q[1:], tri.model.particle_q_rest.numpy()[1:])


def test_hookes_law_closed_form_numbers(device):
    """One target written out by hand, so that expected_force() itself is checked: vertex 0 pulled
    to (-5, 0, 0) mm stretches spring 0-1 by 5 mm along -x and spring 0-2 to 5 sqrt(5) mm."""
    ke, ka = 62.0, 124.0
    tissue = TissueParams(edge_stiffness=ke, edge_damping=0.0, anchor_stiffness=ka, anchor_damping=0.0)
    tri = Triangle(tissue, device, "explicit")
    x = -5.0e-3
    q = tri.rest.copy()
    q[0] = [x, 0.0, 0.0]
    tri.set_state(q, np.zeros((3, 3)))
    tri.control.set(vertex=0, mode=PROBE_DISPLACEMENT, target=q[0])
    tri.step(1e-3)
    l02 = math.hypot(x, LEG)
    want = np.array(
        [
            ke * (LEG - x - LEG) * 1.0 + ke * (l02 - LEG) * (-x / l02) - ka * x,
            ke * (l02 - LEG) * (LEG / l02),
            0.0,
        ]
    )
    np.testing.assert_allclose(want, expected_force(tri, q, np.zeros((3, 3))), rtol=1e-6)
    got = tri.control.probe_reaction.numpy()[0]
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=force_atol(tissue, q))


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_probe_reaction_includes_the_dampers(device, integrator):
    """With velocities: anchor damper -d_i v_0 and edge dampers d_ij ((v_j - v_0) . r) r / |r|^2."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.5, anchor_stiffness=124.0, anchor_damping=0.3)
    tri = Triangle(tissue, device, integrator)
    q = tri.rest.copy()
    q[0] = [1.0e-3, -2.0e-3, 3.0e-3]
    qd = np.array([[0.2, -0.1, 0.3], [-0.4, 0.1, 0.05], [0.0, 0.3, -0.2]])
    tri.set_state(q, qd)
    tri.control.set(vertex=0, mode=PROBE_DISPLACEMENT, target=q[0])
    tri.step(1e-3)
    got = tri.control.probe_reaction.numpy()[0].astype(np.float64)
    want = expected_force(tri, q, qd)
    # the dampers are a large part of it (so a sign error could not pass)
    assert np.linalg.norm(want - expected_force(tri, q, np.zeros((3, 3)))) > 0.2 * np.linalg.norm(want)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=force_atol(tissue, q))


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_probe_on_a_fixed_neighbour_gives_no_nan(device, integrator):
    """The probe drives vertex 0 exactly onto vertex 1's rest position: spring 0-1 has length 0, so
    it adds nothing (kernels/laws/springs.py guards l < 1e-9); the reaction is spring 0-2 plus the anchor."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.02, anchor_stiffness=124.0, anchor_damping=0.1)
    tri = Triangle(tissue, device, integrator)
    dt = 1.0e-3
    target = tri.rest[1]
    # approach over a few steps from rest, then sit there (velocities nonzero on the way)
    for s in range(1, 6):
        tri.control.set(vertex=0, mode=PROBE_DISPLACEMENT, target=target * s / 5)
        tri.step(dt)
        tri.swap()
    for _ in range(3):
        tri.step(dt)
        tri.swap()
    for state in (tri.state_in, tri.state_out):
        assert np.all(np.isfinite(state.particle_q.numpy())) and np.all(np.isfinite(state.particle_qd.numpy()))
    reaction = tri.control.probe_reaction.numpy()[0].astype(np.float64)
    assert np.all(np.isfinite(reaction))
    q = tri.state_in.particle_q.numpy()
    np.testing.assert_array_equal(q[0], q[1])  # exactly on the neighbour
    np.testing.assert_allclose(reaction, expected_force(tri, q, np.zeros((3, 3))), rtol=1e-5, atol=force_atol(tissue, q))


def linear_backward_euler(tri, q, qd, dt):
    """One step of (M + dt C + dt^2 K) dv = dt (f0 - dt K v0) for vertex 0 (3x3, float64), with K and
    C as kernels/laws/springs.py (spring_block) documents them: K_e = ke (d d^T + max(1 - L0/l, 0) (I - d d^T)), C_e = kd d d^T."""
    t = tri.tissue
    q = np.asarray(q, dtype=np.float32).astype(np.float64)
    qd = np.asarray(qd, dtype=np.float32).astype(np.float64)
    eye = np.eye(3)
    A = (tri.mass + dt * t.anchor_damping + dt * dt * t.anchor_stiffness) * eye
    Kv = t.anchor_stiffness * qd[0]
    for j in (1, 2):
        _, rest_length = tri.spring(0, j)
        r = q[j] - q[0]
        length = np.linalg.norm(r)
        d = r / length
        ddt = np.outer(d, d)
        K = t.edge_stiffness * (ddt + max(1.0 - rest_length / length, 0.0) * (eye - ddt))
        A += dt * t.edge_damping * ddt + dt * dt * K
        Kv += K @ (qd[0] - qd[j])
    dv = np.linalg.solve(A, dt * (expected_force(tri, q, qd) - dt * Kv))
    v1 = qd[0] + dv
    return q[0] + dt * v1, v1


@pytest.mark.parametrize("offset", [[3.0e-3, -2.0e-3, 4.0e-3], [6.0e-3, 1.0e-3, 0.0]], ids=["stretched", "compressed"])
def test_implicit_step_is_linearized_backward_euler(device, offset):
    """A free vertex's backward-Euler step equals the 3x3 solve written out (probe off)."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.5, anchor_stiffness=124.0, anchor_damping=0.3)
    tri = Triangle(tissue, device, "implicit")
    q = tri.rest.copy()
    q[0] = offset
    qd = np.array([[0.2, -0.1, 0.3], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    tri.set_state(q, qd)
    dt = 2.0e-3
    tri.step(dt)
    x1, v1 = linear_backward_euler(tri, q, qd, dt)
    np.testing.assert_allclose(tri.state_out.particle_qd.numpy()[0], v1, rtol=1e-4, atol=1e-6 * np.abs(v1).max())
    np.testing.assert_allclose(tri.state_out.particle_q.numpy()[0], x1, rtol=1e-5, atol=1e-9)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_explicit_step_is_semi_implicit_euler(device, integrator):
    """v1 = v0 + dt F / m, x1 = x0 + dt v1 for the explicit scheme (probe off); the implicit one
    differs from it by O(dt^2 k / m) only."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.5, anchor_stiffness=124.0, anchor_damping=0.3)
    tri = Triangle(tissue, device, integrator)
    q = tri.rest.copy()
    q[0] = [3.0e-3, -2.0e-3, 4.0e-3]
    qd = np.zeros((3, 3))
    qd[0] = [0.2, -0.1, 0.3]
    tri.set_state(q, qd)
    dt = 1.0e-5
    tri.step(dt)
    v1 = qd[0] + dt * expected_force(tri, q, qd) / tri.mass
    x1 = np.float32(q[0]) + dt * v1
    rtol = 1e-5 if integrator == "explicit" else 1e-2
    np.testing.assert_allclose(tri.state_out.particle_qd.numpy()[0], v1, rtol=rtol)
    np.testing.assert_allclose(tri.state_out.particle_q.numpy()[0], x1, rtol=1e-5)


def run_free_vertex(tri, q0, dt, steps):
    """Release vertex 0 from q0 at rest (probe off) and record its position after each step."""
    q = tri.rest.copy()
    q[0] = q0
    tri.set_state(q, np.zeros((3, 3)))
    tri.control.set(vertex=-1, mode=PROBE_OFF)
    path = np.empty((steps + 1, 3))
    path[0] = tri.state_in.particle_q.numpy()[0]
    for s in range(steps):
        tri.step(dt)
        tri.swap()
        path[s + 1] = tri.state_in.particle_q.numpy()[0]
    return path


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_damped_oscillator_closed_form(device, integrator):
    """The anchor alone (edges 1e-9 N/m): m x'' + d x' + k x = 0 from x(0) = A, x'(0) = 0, against
    x(t) = A exp(-g t) (cos w_d t + g / w_d sin w_d t), g = d / 2m, over one period.

    Known errors at w dt = 1e-3: semi-implicit Euler is off by about w dt / 2 of the amplitude (its
    positions lag half a step) and its damping rate by g dt relative; backward Euler adds damping,
    exp(-w^2 dt t / 2), about pi w dt of the amplitude after one period. Tolerance: about twice
    the known error, 2 w dt A (explicit) and 2 pi w dt A (implicit)."""
    tissue = TissueParams(edge_stiffness=1e-9, edge_damping=0.0, anchor_stiffness=124.0, anchor_damping=0.1)
    tri = Triangle(tissue, device, integrator)
    m, k, d = tri.mass, tissue.anchor_stiffness, tissue.anchor_damping
    omega = math.sqrt(k / m)
    g = d / (2 * m)
    omega_d = math.sqrt(omega**2 - g**2)
    assert g / omega > 0.1  # clearly damped: an undamped answer would fail
    dt = 1.0e-3 / omega
    period = 2 * math.pi / omega_d
    steps = int(math.ceil(period / dt))
    A = 1.0e-3
    direction = np.array([0.6, -0.48, 0.64])  # unit, not along an axis
    path = run_free_vertex(tri, A * direction, dt, steps)
    t = dt * np.arange(steps + 1)
    x = A * np.exp(-g * t) * (np.cos(omega_d * t) + g / omega_d * np.sin(omega_d * t))
    along = path @ direction
    across = path - np.outer(along, direction)
    tol = (2.0 if integrator == "explicit" else 2 * math.pi) * omega * dt * A
    np.testing.assert_allclose(along, x, rtol=0, atol=tol)
    assert np.abs(across).max() < 1e-3 * A  # a central force keeps the line
    # the schemes' errors are of the size expected, not far below the tolerance by luck
    err = np.abs(along - x).max()
    if integrator == "implicit":
        assert err > 0.3 * math.pi * omega * dt * A * math.exp(-g * period)


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_undamped_spring_oscillator(device, integrator):
    """No anchor, no damping: vertex 0 moved 0.1 mm along edge 0-1 oscillates on that spring alone
    (edge 0-2 is perpendicular: its pull is second order in the amplitude), x(t) = A cos(w t),
    w = sqrt(k_ij / m). Semi-implicit Euler keeps the amplitude (to w dt / 2); backward Euler loses
    a fraction w^2 dt t / 2 of it."""
    tissue = TissueParams(edge_stiffness=62.0, edge_damping=0.0, anchor_stiffness=0.0, anchor_damping=0.0)
    tri = Triangle(tissue, device, integrator)
    omega = math.sqrt(tissue.edge_stiffness / tri.mass)
    dt = 1.0e-3 / omega
    periods = 2
    steps = int(math.ceil(periods * 2 * math.pi / omega / dt))
    A = 1.0e-4
    path = run_free_vertex(tri, [A, 0.0, 0.0], dt, steps)
    t = dt * np.arange(steps + 1)
    # known errors: w dt / 2 (explicit); w^2 dt t / 2 = pi w dt per period (implicit); twice that
    tol = (1.0 if integrator == "explicit" else 2 * math.pi * periods) * omega * dt * A
    np.testing.assert_allclose(path[:, 0], A * np.cos(omega * t), rtol=0, atol=tol)
    assert np.abs(path[:, 2]).max() == 0.0
    assert np.abs(path[:, 1]).max() < A * A / LEG
    if integrator == "explicit":
        # symplectic: no energy drift, the peaks keep the amplitude
        last_period = path[-int(2 * math.pi / omega / dt) :, 0]
        assert abs(np.abs(last_period).max() - A) < omega * dt * A
    else:
        last_period = path[-int(2 * math.pi / omega / dt) :, 0]
        lost = A - np.abs(last_period).max()
        expected_loss = A * (1 - math.exp(-(omega**2) * dt * t[-1] / 2))
        assert 0.5 * expected_loss < lost < 1.5 * expected_loss


def test_critical_dt_single_vertex_closed_forms(device):
    """critical_dt over vertex 0 alone: with the anchor (edges negligible) (-c + sqrt(c^2 + 4 k m)) / k;
    with the edges alone and no damping 2 / w_max, w_max^2 = k_ij / m (both edges, x and y)."""
    anchor = TissueParams(edge_stiffness=1e-9, edge_damping=0.0, anchor_stiffness=124.0, anchor_damping=0.1)
    model = Model(triangle_mesh(), anchor, device)
    m, k, c = float(model.particle_mass_host[0]), anchor.anchor_stiffness, anchor.anchor_damping
    np.testing.assert_allclose(model.critical_dt([0]), (-c + math.sqrt(c * c + 4 * k * m)) / k, rtol=1e-6)
    edges = TissueParams(edge_stiffness=62.0, edge_damping=0.0, anchor_stiffness=124.0, anchor_damping=0.0)
    model = Model(triangle_mesh(), edges, device)
    np.testing.assert_allclose(model.critical_dt([0], anchors=False), 2.0 * math.sqrt(m / 62.0), rtol=1e-6)
    # with the anchor the two act together along x and y: w^2 = (k_ij + k_i) / m
    np.testing.assert_allclose(model.critical_dt([0]), 2.0 * math.sqrt(m / (62.0 + 124.0)), rtol=1e-6)
    assert model.critical_dt([]) == math.inf


@pytest.mark.parametrize("integrator", INTEGRATORS)
def test_critical_dt_separates_growth_from_decay(device, integrator):
    """The anchor oscillator stepped at 0.98 and 1.02 x critical_dt for 100 steps: semi-implicit
    Euler decays below it and grows above it (spectral radius about 0.79 and 1.17); backward Euler
    decays at both."""
    tissue = TissueParams(edge_stiffness=1e-9, edge_damping=0.0, anchor_stiffness=124.0, anchor_damping=0.1)
    tri = Triangle(tissue, device, integrator)
    crit = tri.model.critical_dt([0])
    A = 1.0e-3
    for factor, grows in ((0.98, False), (1.02, integrator == "explicit")):
        path = run_free_vertex(tri, [A, 0.0, 0.0], factor * crit, 100)
        amplitude = np.abs(path[-10:, 0]).max()
        assert np.all(np.isfinite(path)), factor
        if grows:
            assert amplitude > 1e3 * A, (factor, amplitude)
        else:
            assert amplitude < 1e-3 * A, (factor, amplitude)


def test_integrators_by_registration(device):
    """Every registered integrator makes a solver that names itself; another name is a ValueError
    that lists the known ones."""
    assert tuple(REGISTERED) == INTEGRATORS
    model = Model(triangle_mesh(), TissueParams(), device)
    for name in REGISTERED:
        solver = make_solver(model, name)
        assert solver.integrator == name and isinstance(solver, REGISTERED[name])
    assert make_solver(model, "implicit", cg_max_iterations=7).cg_max_iterations == 7
    with pytest.raises(ValueError, match=r"unknown integrator 'rk4' \(known: explicit, implicit\)"):
        make_solver(model, "rk4")
