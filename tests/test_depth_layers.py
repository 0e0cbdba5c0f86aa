"""The depth, layers and lesions section (evaluation/depth_layers.py) on a tiny slab: its reference is the
neo-Hookean FEM of the same tets (recomputed here from the geometry alone), the neo-Hookean law holds
within 5% of it, and every registered law is pressed. CPU; about 5 s."""

import numpy as np
import pytest

from almsdm_warp.evaluation import depth_layers as dl
from almsdm_warp.evaluation import fem_nonlinear as nl
from almsdm_warp.tissue.laws import LAWS

EDGE_MM = 4.0  # a 30 x 30 x 10 mm slab of 243 vertices, 768 tets


@pytest.fixture(scope="module")
def slab():
    case = dl.slab_case(EDGE_MM)
    return case, dl.press_laws(case)


def test_the_slab_is_the_stated_geometry(slab):
    case, row = slab
    x = case.mesh.vertices
    np.testing.assert_allclose(x.min(axis=0), [-0.015, -0.015, 0.0], atol=1e-12)
    np.testing.assert_allclose(x.max(axis=0), [0.015, 0.015, 0.010], atol=1e-12)
    np.testing.assert_allclose(x[case.vertex], [0.0, 0.0, 0.010], atol=1e-12)  # the top face's centre
    assert (case.sphere, case.depth) == (0.005, 0.002)
    assert row["vertices"] == case.mesh.vertex_count and row["tets"] == case.mesh.tet_count


def test_reference_is_the_neo_hookean_fem_of_the_same_tets(slab):
    case, row = slab
    x, tets = case.mesh.vertices, case.mesh.tetrahedra
    fixed = np.repeat((x[:, 2] < 1e-9)[:, None], 3, axis=1)  # the rigid base: the bottom face
    ref = nl.solve(x, tets, young=10e3, poisson=0.45, fixed=fixed, sphere=nl.Sphere(0.005, 0.002), steps=4)
    assert row["fem_N"] == pytest.approx(ref.force, rel=1e-6)
    assert 0.1 < ref.force < 0.2  # docs/calibration.md: 0.157-0.174 N on 1-2 mm edges


def test_neo_hookean_law_holds_within_5_percent_of_the_fem(slab):
    _, row = slab
    press = row["laws"]["neo-hookean"]
    assert press["of_fem"] == pytest.approx(press["force_N"] / row["fem_N"])
    assert abs(press["of_fem"] - 1.0) < 0.05  # measured 0.961
    assert press["inverted_tets"] == 0


@pytest.mark.parametrize("law", list(LAWS))
def test_every_registered_law_is_pressed(slab, law):
    _, row = slab
    press = row["laws"][law]
    assert press["integrator"] == dl.law_integrator(law)
    assert "error" in press or (press["force_N"] > 0 and press["of_fem"] > 0 and press["seconds"] > 0)


def test_lesion_tets_are_the_products(slab):
    """The reference picks the lesion's tets itself; they are the ones the product stiffens (a fair ratio)."""
    case, _ = slab
    stiff = dl.with_lesion(case, below_mm=4.0, radius_mm=5.0, factor=5.0)
    assert stiff.lesion.center == pytest.approx((0.0, 0.0, 0.006))
    young = dl.fem_young(stiff)
    factor = stiff.lesion.element_factor(case.mesh.vertices, case.mesh.tetrahedra)
    np.testing.assert_array_equal(young, 10e3 * factor)
    assert 0 < (young > 10e3).sum() < len(young)


def test_lesion_row_ratios():
    def row(fem, forces):
        return {"case": "deep", "fem_N": fem, "laws": {law: {"force_N": f} for law, f in forces.items()}}

    free, stiff = row(2.0, {"a": 1.0, "b": None}), row(3.0, {"a": 1.2, "b": 1.0})
    out = dl.lesion_row(free, stiff)
    assert out["fem_ratio"] == 1.5 and out["fem_N_without"] == 2.0
    assert out["laws"]["a"]["ratio"] == pytest.approx(1.2) and out["laws"]["a"]["ratio_of_fem"] == pytest.approx(0.8)
    assert out["laws"]["b"]["ratio"] is None and out["laws"]["b"]["ratio_of_fem"] is None  # a law that failed: no ratio
