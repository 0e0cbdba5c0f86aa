"""The depth, layers and lesions section (evaluation/depth_layers.py) on a tiny slab at nu 0.2 (where P1
tets do not lock): its references are the neo-Hookean FEM and the P2/P0 solve of the same tets
(recomputed here from the geometry alone), the neo-Hookean law holds within 15% of the former, and
every registered law is pressed. CPU; about 8 s."""

import numpy as np
import pytest

from almsdm_warp.evaluation import depth_layers as dl
from almsdm_warp.evaluation import fem
from almsdm_warp.evaluation import fem_nonlinear as nl
from almsdm_warp.tissue.laws import LAWS

EDGE_MM = 4.0  # a 30 x 30 x 10 mm slab of 243 vertices, 768 tets
NU = 0.2


@pytest.fixture(scope="module")
def slab():
    case = dl.slab_case(EDGE_MM, poisson=NU)
    return case, dl.press_laws(case, linear=True)


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
    ref = nl.solve(x, tets, young=10e3, poisson=NU, fixed=fixed, sphere=nl.Sphere(0.005, 0.002), steps=4)
    assert row["fem_N"] == pytest.approx(ref.force, rel=1e-6)
    assert 0.05 < ref.force < 0.2  # measured 0.112 N (nu 0.45 on 1-2 mm edges: 0.157-0.174 N, docs/calibration.md)
    linear = fem.sphere_press(x, tets, young=10e3, poisson=NU, sphere_radius=0.005, depth=0.002,
                              fixed=lambda n: n[:, 2:3].repeat(3, axis=1) < 1e-9, mixed=True)
    assert row["p2p0_N"] == pytest.approx(linear.force, rel=1e-9)


def test_neo_hookean_law_holds_within_15_percent_of_the_fem(slab):
    """The law against the FEM on a mesh this coarse (two tets through the slab's thickness): measured 0.90
    (its nodal-averaged volume term is softer on coarse tets); the springs law, 0.58, would fail it."""
    _, row = slab
    press = row["laws"]["neo-hookean"]
    assert press["of_fem"] == pytest.approx(press["force_N"] / row["fem_N"])
    assert press["of_p2p0"] == pytest.approx(press["force_N"] / row["p2p0_N"])
    assert abs(press["of_fem"] - 1.0) < 0.15
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


def test_summary_judges_each_case_against_its_bound():
    """TARGETS applied to made-up rows: a law 10% under the P1 FEM on a slab misses it (8%) though within 2% of
    P2/P0; 9% under on the deep press is within (10%); a lesion ratio 6% off misses (5%); a failed press misses."""
    def press(of_fem, **kw):
        return {"of_fem": of_fem, "force_N": of_fem, "inverted_tets": 0, **kw}

    laws = list(LAWS)
    slab = {"case": "slab", "fem_N": 1.0, "p2p0_N": 0.9, "laws": {law: press(0.90, of_p2p0=0.98) for law in laws}}
    deep = {"case": "deep", "fem_N": 1.0, "laws": {law: press(0.91) for law in laws}}
    lesion = {"case": "lesion", "fem_N": 1.0, "laws": {law: press(1.0, ratio_of_fem=0.94) for law in laws}}
    deep["laws"][laws[0]] = {"error": "RuntimeError: ran away"}
    out = dl.summarise([slab, deep, lesion])
    for law in laws:
        assert out[law]["misses"] == (["slab", "deep", "lesion"] if law == laws[0] else ["slab", "lesion"])
        assert out[law]["slab_within_p2p0"] and out[law]["slab_of_p2p0"] == [0.98]
