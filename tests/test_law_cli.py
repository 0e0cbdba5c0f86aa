"""The tissue law at the interfaces (a scene's [tissue] law, --law, the JSON's model.law), the hold
force beside the peak (palpate's presses[].hold_force_N, a sweep's hold_force_N column), the count of
inverted tets after a press and the sliver note at load. CPU."""

import json

import meshio
import numpy as np
import pytest

from almsdm_warp.cli.main import main
from almsdm_warp.errors import InputError
from almsdm_warp.mesh.io import load_mesh
from almsdm_warp.mesh.topology import inverted_tets, tet_quality
from almsdm_warp.mesh.validate import SLIVER_QUALITY
from almsdm_warp.scene.loader import load_scene
from helpers import write_tet_ball

PRESS = ["--tissue", "paper", "--rings", "2", "--depth-mm", "0.5", "--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05"]
NEO = ["--law", "neo-hookean", "--youngs-modulus-kpa", "10", "--rayleigh-alpha-per-s", "200", "--fixed-below-mm", "-5"]


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    """A 10 mm tet ball (edges ~4 mm) in a .vtu file the loader reads."""
    return write_tet_ball(tmp_path_factory.mktemp("law") / "ball.vtu", 10.0, 4.0)


def scene_file(folder, ball, law_line):
    path = folder / "scene.toml"
    path.write_text(f'[mesh]\npath = "{ball}"\n\n[tissue]\nmodel = "material"\nyoungs_modulus_kPa = 10.0\n{law_line}\n')
    return path


# -- the scene key ----------------------------------------------------------------------------
def test_scene_law_key(tmp_path, ball):
    scene = load_scene(scene_file(tmp_path, ball, 'law = "neo-hookean"'))
    assert scene.law == "neo-hookean" and scene.as_dict()["tissue"]["law"] == "neo-hookean"
    assert load_scene(scene_file(tmp_path, ball, "")).law is None  # the default: the model's for its mesh and tissue
    assert load_scene(scene_file(tmp_path, ball, 'law = "corotational"')).law == "corotational"
    path = scene_file(tmp_path, ball, 'law = "hooke"')
    with pytest.raises(InputError, match=r"\[tissue\] law = 'hooke' is not a tissue law \(allowed: 'springs', 'neo-hookean', 'corotational'\)$") as exc:
        load_scene(path)
    assert str(exc.value).startswith(str(path)) and "\n" not in str(exc.value)


def test_default_law_is_the_tets_for_a_material_on_a_volume(ball):
    from almsdm_warp.mesh.primitives import icosphere
    from almsdm_warp.sim.model import Model
    from almsdm_warp.tissue.material import Material
    from almsdm_warp.tissue.params import TissueParams

    tets = load_mesh(ball)
    assert Model(tets, Material(youngs_modulus=10e3), "cpu").law == "neo-hookean"
    assert Model(tets, TissueParams(), "cpu").law == "springs"  # the paper's per-spring constants
    assert Model(icosphere(20.0, 2), Material(youngs_modulus=10e3, thickness=2e-3), "cpu").law == "springs"  # a surface


def test_scene_law_in_a_paper_scene(tmp_path, ball):
    # the law key is taken with either tissue model (the paper's preset is refused by the law when it runs)
    path = tmp_path / "paper.toml"
    path.write_text(f'[mesh]\npath = "{ball}"\n\n[tissue]\nlaw = "springs"\nedge_stiffness_N_per_m = 62.0\n')
    assert load_scene(path).law == "springs"


# -- --law end to end ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def neo_run(ball, tmp_path_factory):
    out = tmp_path_factory.mktemp("neo") / "out.json"
    assert main(["palpate", str(ball), *NEO, *PRESS, "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_law_flag_presses_the_tets(neo_run):
    assert neo_run["model"]["law"] == "neo-hookean" and neo_run["tissue"]["law"] == "neo-hookean"
    press = neo_run["presses"][0]
    assert 0.0 < press["hold_force_N"] <= press["peak_force_N"] < 1.0  # a damped press: the peak at or before the hold's end
    assert press["inverted_tets"] == 0  # 0.5 mm into 4 mm tets


def test_hold_force_is_the_last_pressed_frames(neo_run, ball):
    """The JSON's hold force is PressResult.force[release_step - 1] of the same press in Python."""
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.material import Material

    mesh = load_mesh(ball)
    pal = Palpation(mesh, Material(youngs_modulus=10e3, rayleigh_alpha=200.0), rings=2, dt=1e-3, device="cpu",
                    fixed_below=-5e-3, law="neo-hookean")
    pal.touch(neo_run["contact"]["vertex"])
    result = pal.press(0.5e-3, 0.05, 0.05, 0.05)
    assert result.hold_force_N == result.force[result.release_step - 1] == neo_run["presses"][0]["hold_force_N"]
    assert result.peak_force_N == neo_run["presses"][0]["peak_force_N"]
    assert result.inverted_tets == 0


def test_springs_json_has_the_new_fields(ball, tmp_path, capsys):
    out = tmp_path / "s.json"
    assert main(["palpate", str(ball), *PRESS, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["model"]["law"] == "springs" and data["presses"][0]["inverted_tets"] == 0
    assert 0.0 < data["presses"][0]["hold_force_N"] <= data["presses"][0]["peak_force_N"]
    assert "hold force" in capsys.readouterr().out


@pytest.mark.parametrize("extra", [["--integrator", "implicit", "--dt-ms", "5"], ["--rings", "auto"]])
def test_law_flag_with_the_implicit_step_and_the_adaptive_region(ball, extra, tmp_path):
    """The neo-Hookean law's other paths from the command line: the same hold force as the explicit
    run's within 2% (the implicit step at 5 ms against 2 fixed rings; the adaptive region against the
    global model)."""
    results = []
    reference = ["--rings", "global"] if "--rings" in extra else []
    for args in (reference, extra):
        out = tmp_path / f"{len(results)}.json"
        press = [a for a in PRESS if a not in ("--rings", "2")] if "--rings" in args else PRESS
        assert main(["palpate", str(ball), *NEO, *press, "--hold-s", "0.3", *args, "--json", str(out)]) == 0
        results.append(json.loads(out.read_text())["presses"][0]["hold_force_N"])
    assert results[0] > 1e-3
    np.testing.assert_allclose(results[1], results[0], rtol=0.02)


@pytest.mark.parametrize("args, message", [
    (["--law", "neo-hookean", "--tissue", "paper"], "the neo-hookean law needs a material"),  # the paper's preset, on request
    (["--law", "hooke"], "--law: 'hooke' is not a tissue law (allowed: springs, neo-hookean, corotational)"),
])
def test_palpate_refusals_are_one_line(ball, args, message, capsys):
    assert main(["palpate", str(ball), *args]) == 2
    captured = capsys.readouterr()
    assert message in captured.err and captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert "press 1" not in captured.out  # refused before any work


def test_palpate_refuses_a_surface_mesh(capsys):
    assert main(["palpate", "stomach", "--law", "neo-hookean"]) == 2
    err = capsys.readouterr().err
    assert "it needs a tet mesh, and stomach.obj has no tetrahedra" in err and err.count("\n") == 1


def test_sweep_with_the_law_is_the_batchs_press(ball, tmp_path):
    """`sweep --law neo-hookean`: each row's hold force is BatchPalpation's for its vertex (the same model and press)."""
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
    from almsdm_warp.sim.model import Model
    from almsdm_warp.tissue.material import Material

    out = tmp_path / "t.csv"
    assert main(["sweep", str(ball), *NEO, "--points", "4", *PRESS, "--out", str(out)]) == 0
    table = SWEEP_TABLE.read(out)
    model = Model(load_mesh(ball), Material(youngs_modulus=10e3, rayleigh_alpha=200.0), "cpu", fixed_below=-5e-3, law="neo-hookean")
    batch = BatchPalpation(model=model, rings=2, dt=1e-3).touch(table["vertex"])
    res = batch.press(0.5e-3, 0.05, 0.05, 0.05)
    assert np.all(table["hold_force_N"] > 0.0)
    np.testing.assert_allclose(table["hold_force_N"], res.hold_force, rtol=1e-12)


def test_sweep_refuses_a_scene_law_its_mesh_cannot_take(tmp_path, capsys):
    from pathlib import Path

    surface = Path(__file__).resolve().parents[1] / "scenes" / "stomach.obj"
    path = scene_file(tmp_path, surface, 'thickness_mm = 3.0\nlaw = "neo-hookean"')
    assert main(["sweep", str(path), "--out", str(tmp_path / "t.csv"), "--points", "4"]) == 2
    err = capsys.readouterr().err
    assert "needs a tet mesh" in err and err.count("\n") == 1
    assert not (tmp_path / "t.csv").exists() and not (tmp_path / "t.csv.parts").exists()


# -- the sweep's hold force ----------------------------------------------------------------------
def test_sweep_table_has_the_batch_hold_force(tmp_path):
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
    from conftest import SCENES, load_cached

    out = tmp_path / "t.csv"
    fast = ["--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05", "--dt-ms", "0.5"]
    assert main(["sweep", "paper_stomach", "--points", "5", "--rings", "2", "--integrator", "implicit", "--out", str(out), *fast]) == 0
    table = SWEEP_TABLE.read(out)
    assert list(table)[4:7] == ["peak_force_N", "hold_force_N", "stiffness_N_per_mm"]
    res = BatchPalpation(load_cached(SCENES / "stomach.obj"), rings=2, dt=5e-4, device="cpu", integrator="implicit") \
        .touch(table["vertex"]).press(0.01, 0.05, 0.05, 0.05)
    np.testing.assert_array_equal(table["hold_force_N"], res.hold_force)
    assert np.all(table["hold_force_N"] <= table["peak_force_N"])


def test_a_table_from_before_the_hold_force_column_still_reads(tmp_path):
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE

    old = tmp_path / "old.csv"
    old.write_text("x_mm,y_mm,z_mm,vertex,peak_force_N,stiffness_N_per_mm,recovery_error_mm,rings\n1.0,2.0,3.0,4,0.5,0.05,0.0,2\n")
    table = SWEEP_TABLE.read(old)
    assert "hold_force_N" not in table and table["peak_force_N"][0] == 0.5


# -- inverted tets ---------------------------------------------------------------------------------
def det_f_count(rest, x, tets):
    """Tets with det(F) <= 0, F = D_s D_m^-1, one at a time."""
    count = 0
    for t in tets:
        dm = np.stack([rest[t[c]] - rest[t[0]] for c in (1, 2, 3)], axis=1)
        ds = np.stack([x[t[c]] - x[t[0]] for c in (1, 2, 3)], axis=1)
        count += np.linalg.det(ds @ np.linalg.inv(dm)) <= 0.0
    return int(count)


def test_inverted_tets_count():
    corner = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64) * 1e-2
    rest = np.concatenate([corner + [2e-2 * k, 0.0, 0.0] for k in range(3)])
    tets = np.array([[0, 1, 2, 3], [4, 6, 5, 7], [8, 9, 10, 11]])  # the second wound the other way: not inverted at rest
    assert inverted_tets(rest, rest, tets) == det_f_count(rest, rest, tets) == 0
    x = rest.copy()
    x[4:8, 0] *= 1.5  # tet 1 stretched: det F = 1.5
    x[3, 2] = -0.5e-2  # tet 0's apex through its base: det F = -0.5
    assert inverted_tets(rest, x, tets) == det_f_count(rest, x, tets) == 1
    x[11, 2] = 0.0  # tet 2's apex on its base: det F = 0 counts
    assert inverted_tets(rest, x, tets) == det_f_count(rest, x, tets) == 2


def test_a_deep_press_warns_of_inverted_tets(ball, tmp_path, capsys):
    """6 mm into 4 mm tets (springs: nothing holds a tet's volume): the JSON's count and the warning
    are those of an independent count at the end of the hold of the same press in Python."""
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.material import Material

    out = tmp_path / "deep.json"
    args = ["--youngs-modulus-kpa", "10", "--fixed-below-mm", "-5", "--law", "springs", *PRESS]
    args[args.index("--depth-mm") + 1] = "6"
    assert main(["palpate", str(ball), *args, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    mesh = load_mesh(ball)
    pal = Palpation(mesh, Material(youngs_modulus=10e3), rings=2, dt=1e-3, device="cpu", fixed_below=-5e-3, law="springs")
    pal.touch(data["contact"]["vertex"])
    seen = {}

    def at_release(k, total):
        if k == release:
            seen["count"] = det_f_count(mesh.vertices, pal.positions(), mesh.tetrahedra)

    release = 100  # 50 ms ramp + 50 ms hold at 1 ms
    result = pal.press(6e-3, 0.05, 0.05, 0.05, record=at_release)
    assert result.release_step == release
    assert data["presses"][0]["inverted_tets"] == result.inverted_tets == seen["count"] > 0
    warning = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning:")]
    assert warning == [f"warning: press 1: {seen['count']} of {mesh.tet_count} tetrahedra inverted (det F <= 0) at the end "
                       f"of the hold: the press is too deep for these tets"]


# -- slivers at load -------------------------------------------------------------------------------
def test_quality_of_a_regular_tet_is_one():
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=np.float64)
    np.testing.assert_allclose(tet_quality(v, np.array([[0, 1, 2, 3]])), 1.0, rtol=1e-12)


def test_a_sliver_is_named_at_load(tmp_path):
    # a regular corner tet and, on its slanted face, a flat cap: fair edges, almost no volume
    centroid = np.full(3, 10.0 / 3.0)
    cap = centroid + 0.01 * np.ones(3) / np.sqrt(3.0)
    v = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], cap])
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    path = tmp_path / "sliver.vtu"
    meshio.write(path, meshio.Mesh(v, [("tetra", tets)]))
    mesh = load_mesh(path)
    # independently: V = area(face) x height / 3, l_rms over its 6 edges
    area = np.sqrt(3.0) / 4.0 * (10.0 * np.sqrt(2.0)) ** 2
    volume = area * 0.01 / 3.0
    edges = [10.0 * np.sqrt(2.0)] * 3 + [np.linalg.norm(cap - v[k]) for k in (1, 2, 3)]
    q = 6.0 * np.sqrt(2.0) * volume / np.sqrt(np.mean(np.square(edges))) ** 3
    assert q < SLIVER_QUALITY
    note = next(n for n in mesh.notes if "sliver" in n)
    assert note.startswith("1 sliver tetrahedron of 2 (quality under 0.02") and "worst: tetrahedron 1, vertices (1, 2, 3, 4)" in note
    assert f"quality {q:.3g}" in note
    assert mesh.tet_count == 2  # kept: only zero-volume tets are dropped


# -- the sphere near the fixed ring -----------------------------------------------------------------


def test_a_sphere_near_the_fixed_ring_is_measured_and_warned_of():
    """A 10 mm sphere pressed 10 mm into a 25 mm tet ball on a support: with 2 rings of 8 mm edges the region's
    fixed ring lies about a millimetre from the sphere at full depth and the force collapses to under half the
    global model's (the reference); with 4 rings the ring is far and the force the global model's to 2%.
    PressResult.ring_gap is the brute-force distance, and only the first is warned of."""
    from almsdm_warp.cli.palpate import press_warnings
    from almsdm_warp.evaluation.depth_layers import PRESS, ball_case
    from almsdm_warp.protocol.palpation import Palpation

    case = ball_case(8.0)
    results = {}
    for rings in (2, 4, "global"):
        pal = Palpation(case.mesh, case.material(), rings=rings, law="neo-hookean", integrator="implicit", dt=PRESS["dt"],
                        device="cpu", fixed_below=case.fixed_below, probe_radius=case.sphere)
        pal.touch(case.vertex, case.depth)
        result = results[rings] = pal.press(case.depth, ramp=PRESS["ramp"], hold=PRESS["hold"], settle=PRESS["dt"])
        if rings == "global":
            assert result.ring_gap is None
            continue
        centre = pal.rest_position() + pal.inward_normal() * (case.depth - case.sphere)
        ring = pal.region.boundary()
        assert result.ring_gap == pytest.approx(min(np.linalg.norm(case.mesh.vertices[v] - centre) for v in ring) - case.sphere, abs=1e-9)
    reference = results["global"].hold_force_N
    assert results[2].ring_gap < 0.5 * case.sphere and results[2].hold_force_N < 0.5 * reference
    assert results[4].ring_gap > case.sphere and results[4].hold_force_N == pytest.approx(reference, rel=0.02)
    assert any("fixed ring" in w for w in press_warnings(results[2], case.mesh.tet_count, case.sphere))
    assert press_warnings(results[4], case.mesh.tet_count, case.sphere) == []


def test_a_batch_measures_each_presss_ring_gap_as_one_palpation_does(device):
    """BatchResult.ring_gap: each press's sphere's distance at full depth from its region's fixed ring, the
    device kernel against PressResult.ring_gap of the same contacts pressed one by one (the same regions),
    on the deep ball at 2 rings (near) and 4 rings (far); a sweep's count of those near (sweep_lanes.near_ring)."""
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.batch.sweep_lanes import near_ring
    from almsdm_warp.evaluation.depth_layers import ball_case
    from almsdm_warp.protocol.palpation import NEAR_RING, Palpation

    case = ball_case(8.0)
    top = np.argsort(case.mesh.vertices[:, 2])[::-1]
    contacts = np.intersect1d(top[:30], case.mesh.surface_vertices)[:3]
    press = dict(depth=case.depth, ramp=0.02, hold=0.002, settle=0.002)
    for rings in (2, 4):
        batch = BatchPalpation(case.mesh, case.material(), rings=rings, dt=2e-3, device=device, law="neo-hookean", integrator="implicit",
                               fixed_below=case.fixed_below, probe_radius=case.sphere)
        result = batch.touch(contacts, case.depth).press(**press)
        one = []
        for v in contacts:
            pal = Palpation(case.mesh, case.material(), rings=rings, law="neo-hookean", integrator="implicit", dt=2e-3, device=device,
                            fixed_below=case.fixed_below, probe_radius=case.sphere)
            pal.touch(int(v), case.depth)
            one.append(pal.press(**press).ring_gap)
        np.testing.assert_allclose(result.ring_gap, one, atol=1e-6)
        assert near_ring(result, case.sphere) == int(np.sum(np.array(one) < NEAR_RING * case.sphere))
        if rings == 2:
            assert near_ring(result, case.sphere) >= 1  # the top contact's ring 1.4 mm from the sphere
    assert near_ring(result, case.sphere) == 0 and min(one) > case.sphere  # 4 rings: every ring far
