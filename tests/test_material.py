"""Springs, anchors, masses and dampers derived from a material (almsdm_warp.tissue.material).

Independent answers: hand-computed k_ij on a regular tet and a cube of six tets, the closed-form
moduli of an equilateral triangle network, static solves of the network (scripts/material_check.py,
SciPy, apart from the project's kernels), a two-mass oscillator's eigenvalues.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from almsdm_warp.mesh.topology import tet_surface, unique_edges
from almsdm_warp.scene.loader import TissueParams
from almsdm_warp.tissue.material import (
    PAPER_SPRINGS,
    Material,
    POISSON_LAWS,
    damping,
    springs_from_material,
    springs_uniform,
)

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "material_check.py"
_spec = importlib.util.spec_from_file_location("material_check", SCRIPT)
check = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check)

NO_TRIANGLES = np.zeros((0, 3), dtype=np.int64)


def edge_k(springs, edges, i, j):
    row = np.flatnonzero((edges[:, 0] == min(i, j)) & (edges[:, 1] == max(i, j)))
    assert len(row) == 1
    return springs.edge_stiffness[row[0]]


@pytest.mark.parametrize("law", ["young", "indentation"])
def test_regular_tet_edge_stiffness_is_modulus_times_volume_over_length_squared(law):
    l, E, nu = 0.01, 5.0e3, 0.45
    v = l * np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / (2 * math.sqrt(2))
    tets = np.array([[0, 1, 2, 3]])
    s = springs_from_material(Material(E, nu), v, NO_TRIANGLES, tets, law=law)
    e_net = E if law == "young" else E * (15 / 16) / (1 - nu**2)
    # V = l^3 / (6 sqrt 2), so k = E_net V / l^2 = E_net l / (6 sqrt 2) on all six edges
    np.testing.assert_allclose(s.edge_stiffness, np.full(6, e_net * l / (6 * math.sqrt(2))), rtol=1e-12)


def test_cube_of_six_tets_edge_stiffness_by_hand():
    a, E = 0.02, 1.0e4
    corners = a * np.array(list(np.ndindex(2, 2, 2)), float)  # vertex 4x + 2y + z at (x, y, z)
    # six tets around the diagonal 0-7, one per order of axes (x = 4, y = 2, z = 1)
    tets = np.array([[0, 4, 6, 7], [0, 4, 5, 7], [0, 2, 6, 7], [0, 2, 3, 7], [0, 1, 5, 7], [0, 1, 3, 7]])
    s = springs_from_material(Material(E, 0.3), corners, NO_TRIANGLES, tets, law="young")
    edges = unique_edges(NO_TRIANGLES, tets)
    assert len(edges) == 19  # 12 cube edges, 6 face diagonals, 1 body diagonal
    V = a**3 / 6
    # body diagonal: all six tets, l^2 = 3 a^2
    assert edge_k(s, edges, 0, 7) == pytest.approx(E * 6 * V / (3 * a * a))
    # an axis edge from 0: the two tets whose path starts along it
    assert edge_k(s, edges, 0, 4) == pytest.approx(E * 2 * V / a**2)
    # an axis edge in the middle of a path (4-6: after x, along y): one tet
    assert edge_k(s, edges, 4, 6) == pytest.approx(E * V / a**2)
    # a face diagonal 0-6 (x then y, or y then x): two tets, l^2 = 2 a^2
    assert edge_k(s, edges, 0, 6) == pytest.approx(E * 2 * V / (2 * a * a))
    # an axis edge that no tet uses is not an edge: 1-4 is not in the mesh
    assert not np.any((edges[:, 0] == 1) & (edges[:, 1] == 4))


def test_poisson_laws_match_the_indentation_modulus_of_a_quarter_poisson_network():
    for nu in (0.0, 0.3, 0.45, 0.49):
        # an isotropic central-spring network has nu = 1/4: its E/(1 - 1/16) must equal E/(1 - nu^2)
        assert POISSON_LAWS["indentation"](nu) / (1 - 1 / 16) == pytest.approx(1 / (1 - nu**2))
        assert POISSON_LAWS["young"](nu) == 1.0


@pytest.mark.parametrize("kind", ["structured", "jittered"])
def test_tet_box_modulus_does_not_follow_the_mesh(kind):
    material = Material(youngs_modulus=1.0, poisson_ratio=0.25)
    coarse = check.network_moduli(*check.tet_box(4, kind=kind), material, law="young")[0]
    fine = check.network_moduli(*check.tet_box(8, kind=kind), material, law="young")[0]
    # the derived network's modulus changes by under 3% when the cells halve ...
    assert abs(fine - coarse) / fine < 0.03
    # ... and stays within 20% of E (a lattice's anisotropy; docs/calibration.md)
    assert 0.8 < fine < 1.2
    # the same boxes with one constant on every edge: the modulus grows as the cells shrink (as k / h
    # in the interior, less the softer boundary layer)
    p4, t4 = check.tet_box(4, kind=kind)
    p8, t8 = check.tet_box(8, kind=kind)
    uniform = []
    for p, t in ((p4, t4), (p8, t8)):
        e = unique_edges(NO_TRIANGLES, t).astype(np.int64)
        uniform.append(check.uniaxial(p, check.spring_matrix(p, e, np.full(len(e), 62.0)))[0])
    assert uniform[1] / uniform[0] > 1.4


def test_equilateral_membrane_has_the_closed_form_moduli():
    # a network of equilateral triangles with k = E t sum(A) / l^2 is isotropic, with plane-stress
    # modulus E t and Poisson ratio 1/3 in its interior
    ratio, nu = check.network_moduli(*check.membrane(8, kind="equilateral"), Material(2.0e3, thickness=1e-3))
    assert ratio == pytest.approx(1.0, abs=0.01)
    assert nu == pytest.approx(1 / 3, abs=0.04)


def test_finite_elements_of_the_check_reproduce_uniaxial_stress():
    # the script's P1 reference: exact for a linear field on any tet mesh
    p, t = check.tet_box(3, kind="jittered")
    e_eff, nu_eff = check.uniaxial(p, check.fem_matrix(p, t, 7.0, 0.3))
    assert e_eff == pytest.approx(7.0, rel=1e-9)
    assert nu_eff == pytest.approx(0.3, rel=1e-9)


def test_winkler_anchors_sum_to_foundation_times_area_and_masses_to_rho_volume():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    m = Material(3.0e3, density=1040.0, thickness=2e-3, foundation=2.0e6)
    s = springs_from_material(m, sphere.vertices, sphere.faces)
    assert s.anchor_stiffness.sum() == pytest.approx(2.0e6 * sphere.area, rel=1e-12)
    assert s.vertex_mass.sum() == pytest.approx(1040.0 * 2e-3 * sphere.area, rel=1e-12)
    assert np.all(s.anchor_stiffness > 0)

    p, t = check.tet_box(3, size=(0.02, 0.03, 0.04), kind="jittered")
    s = springs_from_material(m, p, NO_TRIANGLES, t)
    assert s.vertex_mass.sum() == pytest.approx(1040.0 * 0.02 * 0.03 * 0.04, rel=1e-12)
    assert not np.any(s.anchor_stiffness)  # a tet mesh gets no anchors unless asked
    surface = tet_surface(t)
    s = springs_from_material(m, p, surface, t, anchor_volume=True)
    box_area = 2 * (0.02 * 0.03 + 0.02 * 0.04 + 0.03 * 0.04)
    assert s.anchor_stiffness.sum() == pytest.approx(2.0e6 * box_area, rel=1e-9)


def test_rayleigh_damping_is_alpha_mass_plus_beta_stiffness():
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.03)
    m = Material(3.0e3, thickness=1e-3, foundation=1e6, rayleigh_alpha=2.0, rayleigh_beta=1e-3)
    s = springs_from_material(m, sphere.vertices, sphere.faces)
    np.testing.assert_allclose(s.edge_damping, 1e-3 * s.edge_stiffness)
    np.testing.assert_allclose(s.anchor_damping, 2.0 * s.vertex_mass + 1e-3 * s.anchor_stiffness)


def test_damping_ratio_is_the_ratio_of_each_springs_own_mode():
    k, m1, m2, zeta = 40.0, 0.02, 0.05, 0.3
    d_edge, d_anchor = damping(Material(1.0, damping_ratio=zeta), np.array([[0, 1]]), np.array([k]),
                               np.array([k, 0.0]), np.array([m1, m2]))
    # two masses on one spring-damper, 1D: the relative mode's damping ratio, from the eigenvalues
    M = np.diag([m1, m2])
    K = k * np.array([[1, -1], [-1, 1]])
    C = d_edge[0] * np.array([[1, -1], [-1, 1]])
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
    lam = np.linalg.eigvals(A)
    lam = lam[np.abs(lam) > 1e-9][0]
    assert -lam.real / abs(lam) == pytest.approx(zeta, rel=1e-9)
    # vertex 0 on its anchor: d = 2 zeta sqrt(k m); vertex 1 has no anchor, so no damper
    assert d_anchor[0] == pytest.approx(2 * zeta * math.sqrt(k * m1))
    assert d_anchor[1] == 0.0


def test_paper_preset_is_the_default_tissue():
    t = TissueParams()
    assert (PAPER_SPRINGS.edge_stiffness, PAPER_SPRINGS.anchor_stiffness) == (t.edge_stiffness, t.anchor_stiffness)
    assert (PAPER_SPRINGS.edge_damping, PAPER_SPRINGS.anchor_damping) == (t.edge_damping, t.anchor_damping)
    assert (PAPER_SPRINGS.density, PAPER_SPRINGS.thickness) == (t.density, t.thickness)
    sphere = trimesh.creation.icosphere(subdivisions=1, radius=0.03)
    s = springs_uniform(PAPER_SPRINGS, sphere.vertices, sphere.faces)
    assert np.all(s.edge_stiffness == 62.0) and np.all(s.anchor_stiffness == 124.0)
    assert s.vertex_mass.sum() == pytest.approx(1000.0 * 25e-3 * sphere.area)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(youngs_modulus=0.0), "youngs_modulus"),
        (dict(youngs_modulus=-5.0), "youngs_modulus"),
        (dict(youngs_modulus=float("nan")), "youngs_modulus"),
        (dict(youngs_modulus=1.0, poisson_ratio=0.5), "poisson_ratio"),
        (dict(youngs_modulus=1.0, poisson_ratio=-1.0), "poisson_ratio"),
        (dict(youngs_modulus=1.0, density=0.0), "density"),
        (dict(youngs_modulus=1.0, thickness=-1e-3), "thickness"),
        (dict(youngs_modulus=1.0, foundation=-1.0), "foundation"),
        (dict(youngs_modulus=1.0, damping_ratio=-0.1), "damping_ratio"),
        (dict(youngs_modulus=1.0, rayleigh_beta=-1.0), "rayleigh_beta"),
        (dict(youngs_modulus=1.0, damping_ratio=0.1, rayleigh_alpha=1.0), "damping_ratio"),
    ],
)
def test_bad_material_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Material(**kwargs)


def test_bad_inputs_are_clear_errors():
    with pytest.raises(TypeError, match="youngs_modulus"):
        Material("1e3")
    sphere = trimesh.creation.icosphere(subdivisions=0)
    with pytest.raises(ValueError, match="thickness"):
        springs_from_material(Material(1.0), sphere.vertices, sphere.faces)
    with pytest.raises(ValueError, match="law"):
        springs_from_material(Material(1.0, thickness=1e-3), sphere.vertices, sphere.faces, law="lame")
