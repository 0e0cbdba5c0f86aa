"""The large-deformation (neo-Hookean) and locking-free (P2/P0) references against closed forms."""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from almsdm_warp.evaluation import fem, hertz
from almsdm_warp.evaluation import fem_nonlinear as nl
from almsdm_warp.mesh import primitives

E, NU = 10e3, 0.45
# a quarter block 80 x 80 x 40 mm (two symmetry planes), graded toward the contact at the origin
GRID = np.array([0.0, 1.0, 2.0, 3.5, 6.0, 10.0, 20.0, 40.0])


def _block():
    return primitives.tet_grid_arrays(GRID, GRID, -GRID[::-1])


def _block_supports(x):
    return fem.clamped_below(x, -0.04 + 1e-9) | fem.symmetry_planes(x, "xy")


def _box_on_rollers():
    """The 2 x 3 x 4 mm box on rollers (x = 0, y = 0, z = 0 held normally): (vertices, tets, size [m], fixed, top)."""
    size = np.array([2.0, 3.0, 4.0]) * 1e-3
    vertices, tets = primitives.tet_box_arrays((2.0, 3.0, 4.0), (2, 2, 3))
    on = lambda axis, value: np.abs(vertices[:, axis] - value) < 1e-12  # noqa: E731
    fixed = np.zeros((len(vertices), 3), dtype=bool)
    fixed[on(0, 0.0), 0] = fixed[on(1, 0.0), 1] = fixed[on(2, 0.0), 2] = True
    return vertices, tets, size, fixed, on(2, size[2])


def _uniaxial_nominal_stress(stretch):
    """The closed form of F = diag(s, s, stretch): (nominal stress P_zz [Pa], s), the lateral stretch
    s from P_xx = mu (s - 1/s) + lambda ln J / s = 0 (scipy root), P_zz = mu (stretch - 1/stretch) +
    lambda ln J / stretch."""
    lam, mu = fem.lame(E, NU)
    lateral = brentq(lambda s: mu * (s - 1.0 / s) + lam * math.log(s * s * stretch) / s, 0.2, 5.0)
    return mu * (stretch - 1.0 / stretch) + lam * math.log(lateral**2 * stretch) / stretch, lateral


def _central(fun, x, h):
    return np.array([(fun(x + h * e) - fun(x - h * e)) / (2.0 * h) for e in np.eye(len(x))])


def test_tangent_and_force_are_the_energy_derivatives():
    """At a random 10% deformation of a 1 mm cube (6 tets): force = dE/du, tangent = d force/du."""
    body = nl.NeoHookeanBody(*primitives.tet_box_arrays(1.0, 1), E, NU)
    u = 1e-4 * np.random.default_rng(0).standard_normal(body.size)
    force, tangent = body.force(u), body.tangent(u).toarray()
    np.testing.assert_allclose(_central(body.energy, u, 1e-9), force, atol=1e-8 * np.abs(force).max())
    np.testing.assert_allclose(_central(body.force, u, 1e-9).T, tangent, atol=1e-8 * np.abs(tangent).max())
    np.testing.assert_allclose(tangent, tangent.T, atol=1e-12 * np.abs(tangent).max())


def test_linearises_to_linear_elasticity():
    """At F = I the tangent is the linear stiffness of E and nu (fem.stiffness, independent code)."""
    vertices, tets = primitives.tet_box_arrays((2.0, 3.0, 4.0), (2, 2, 3))
    body = nl.NeoHookeanBody(vertices, tets, E, NU)
    linear = fem.stiffness(vertices, tets, E, NU).toarray()
    np.testing.assert_allclose(body.tangent(np.zeros(body.size)).toarray(), linear, atol=1e-12 * np.abs(linear).max())


@pytest.mark.parametrize("stretch", [1.3, 0.7])
def test_uniaxial_stretch_matches_the_closed_form(stretch):
    """A 2 x 3 x 4 mm box on rollers, its top moved to `stretch` x its height, the sides free:
    the closed form's force and lateral stretch (_uniaxial_nominal_stress). P1 holds the
    homogeneous answer exactly: measured to 1e-9."""
    vertices, tets, size, fixed, top = _box_on_rollers()
    fixed[top, 2] = True
    values = np.zeros((len(vertices), 3))
    values[top, 2] = (stretch - 1.0) * size[2]
    result = nl.solve(vertices, tets, young=E, poisson=NU, fixed=fixed, values=values, steps=5)
    nominal, lateral = _uniaxial_nominal_stress(stretch)
    np.testing.assert_allclose(result.reactions[top, 2].sum(), nominal * size[0] * size[1], rtol=1e-7)
    exact = vertices * [lateral - 1.0, lateral - 1.0, stretch - 1.0]
    np.testing.assert_allclose(result.displacement, exact, atol=1e-9 * size.max())


def test_flat_press_compresses_like_the_closed_form():
    """A sphere R 100 m (flat over the box: 3e-8 m of sag) presses the 2 x 3 x 4 mm box on rollers to
    0.7 of its height, frictionless: uniaxial compression, the contact's force = P_zz(0.7) x area."""
    vertices, tets, size, fixed, _ = _box_on_rollers()
    sphere = nl.Sphere(100.0, 0.3 * size[2], centre_xy=(1e-3, 1.5e-3))
    result = nl.solve(vertices, tets, young=E, poisson=NU, fixed=fixed, sphere=sphere, steps=5)
    nominal, _ = _uniaxial_nominal_stress(0.7)
    np.testing.assert_allclose(result.force, -nominal * size[0] * size[1], rtol=1e-4)  # measured 2e-5
    assert result.max_penetration <= 1e-6 * sphere.depth


def test_small_press_matches_the_linear_solve():
    """Rigid sphere R 20 mm pressed 0.2 mm (a = 2 mm, a/R = 0.1) into the quarter block, P1 both.

    Measured: neo-Hookean within 0.3% of the linear active-set solve (fem.sphere_press); a driven
    vertex pushed 1 um: 0.02%. The contact's gap is closed to 1e-6 of the depth.
    """
    vertices, tets = _block()
    radius, depth = 0.02, 0.0002
    large = nl.solve(vertices, tets, young=E, poisson=NU, fixed=_block_supports, sphere=nl.Sphere(radius, depth),
                     steps=2, copies=4)
    linear = fem.sphere_press(vertices, tets, young=E, poisson=NU, sphere_radius=radius, depth=depth, order=1,
                              copies=4, fixed=_block_supports)
    assert abs(large.force / linear.force - 1.0) < 0.005
    assert large.max_penetration <= 1e-6 * depth
    assert math.isclose(large.contact_radius, linear.contact_radius)

    fixed = _block_supports(vertices)
    apex = np.flatnonzero(np.linalg.norm(vertices, axis=1) < 1e-12)
    fixed[apex] = True
    values = np.zeros((len(vertices), 3))
    values[apex, 2] = -1e-6
    driven = nl.solve(vertices, tets, young=E, poisson=NU, fixed=fixed, values=values, steps=1)
    _, reactions = fem.solve_dirichlet(fem.stiffness(vertices, tets, E, NU), fixed.ravel(), values.ravel())
    np.testing.assert_allclose(driven.reactions[apex, 2].sum(), reactions.reshape(-1, 3)[apex, 2].sum(), rtol=1e-3)


def bonded_layer_factor(poisson, radius, depth, thickness):
    """Dimitriadis et al. 2002 (Biophys. J. 82, 2798), a sphere on an elastic layer bonded to a rigid
    base: the force over Hertz's, 1 - 2 a0/pi x + 4 a0^2/pi^2 x^2 - 8/pi^3 (a0^3 + 4 pi^2/15 b0) x^3,
    x = sqrt(R d) / h."""
    a0 = -(1.2876 - 1.4678 * poisson + 1.3442 * poisson**2) / (1.0 - poisson)
    b0 = (0.6387 - 1.0277 * poisson + 1.5164 * poisson**2) / (1.0 - poisson)
    x = math.sqrt(radius * depth) / thickness
    return 1 - 2 * a0 / math.pi * x + 4 * a0**2 / math.pi**2 * x**2 - 8 / math.pi**3 * (a0**3 + 4 * math.pi**2 / 15 * b0) * x**3


def test_mixed_element_does_not_lock():
    """nu = 0.499: a sphere R 20 mm pressed 0.2 mm into the quarter block (clamped 40 mm below).

    Reference: Hertz x the bonded-layer factor (1.060 at a/h = 0.05). Measured: P2/P0 0.989 of it
    (0.985 and 0.988 on finer grids: converged), plain P2 1.045 (1.022 finer: slowly), P1 3.9 (locked).
    """
    vertices, tets = _block()
    radius, depth, nu = 0.02, 0.0002, 0.499
    expected = hertz.hertz_force(E, nu, radius, depth) * bonded_layer_factor(nu, radius, depth, 0.04)
    forces = {}
    for label, order, mixed in (("P1", 1, False), ("P2", 2, False), ("P2/P0", 2, True)):
        forces[label] = fem.sphere_press(vertices, tets, young=E, poisson=nu, sphere_radius=radius, depth=depth,
                                         order=order, mixed=mixed, copies=4, fixed=_block_supports).force
    assert abs(forces["P2/P0"] / expected - 1.0) < 0.03
    assert forces["P2"] > 1.03 * forces["P2/P0"]
    assert forces["P1"] > 2.0 * forces["P2/P0"]


def test_a_modulus_per_tet_is_the_uniform_one_where_all_are_equal_and_scales_the_stress():
    """young as one value a tet: the same forces as the scalar where every tet has it; twice it in
    every tet doubles the internal force of a given displacement (the energy is linear in E)."""
    from almsdm_warp.evaluation.fem_nonlinear import NeoHookeanBody
    from almsdm_warp.mesh.primitives import tet_box_arrays

    x, tets = tet_box_arrays(10.0, 2)
    u = np.random.default_rng(4).normal(0.0, 2e-4, x.shape).ravel()
    one = NeoHookeanBody(x, tets, 10e3, 0.45)
    each = NeoHookeanBody(x, tets, np.full(len(tets), 10e3), 0.45)
    twice = NeoHookeanBody(x, tets, np.full(len(tets), 20e3), 0.45)
    np.testing.assert_allclose(each.force(u), one.force(u), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(twice.force(u), 2.0 * one.force(u), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose((twice.tangent(u) - 2.0 * one.tangent(u)).toarray(), 0.0, atol=1e-9)
