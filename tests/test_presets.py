"""Physics by default on any mesh: tissue presets, a support chosen from the mesh and the press, the mesh's
unit guessed from its size, and Python's `palpation(path)` pressing what `almsdm palpate path` presses. CPU."""

import json

import meshio
import numpy as np
import pytest
import trimesh

import almsdm_warp as am
from almsdm_warp.cli.main import main
from almsdm_warp.errors import InputError
from almsdm_warp.mesh.primitives import icosphere_arrays
from almsdm_warp.mesh.units import guess_scale
from almsdm_warp.scene.support import FAR_SIDE, parse_support, support_height
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.presets import DEFAULT_PRESET, PRESETS
from helpers import write_tet_ball

SHORT = ["--depth-mm", "4", "--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05"]


@pytest.fixture(scope="module")
def sphere_obj(tmp_path_factory):
    """A 30 mm icosphere surface (162 vertices) in millimetres."""
    v, f = icosphere_arrays(30.0, 2)
    path = tmp_path_factory.mktemp("presets") / "sphere.obj"
    trimesh.Trimesh(v * 1e3, f, process=False).export(path)
    return path


@pytest.fixture(scope="module")
def ball_vtu(tmp_path_factory):
    """A 20 mm tet ball (edges ~7 mm) in millimetres."""
    return write_tet_ball(tmp_path_factory.mktemp("presets") / "ball.vtu", 20.0, 7.0)


def palpate_json(path, tmp_path, *extra):
    out = tmp_path / "p.json"
    assert main(["palpate", str(path), *SHORT, *extra, "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_presets_are_the_calibration_tables_values():
    """docs/calibration.md: E = 2 mu (1 + nu), liver mu 1.8 kPa, stomach 0.637 kPa, nu 0.45; a 3 mm wall on
    0.1 kPa/mm; a 10 mm sphere; the paper's constants only as 'paper'."""
    for name, mu, rho in (("liver", 1.8e3, 1060.0), ("stomach", 0.637e3, 1058.0)):
        t = PRESETS[name].tissue
        assert isinstance(t, Material) and t.youngs_modulus == pytest.approx(2 * mu * 1.45, rel=0.01)
        assert (t.poisson_ratio, t.density, t.thickness, t.foundation) == (0.45, rho, 3e-3, 0.1e6) and t.rayleigh_alpha > 0
        assert PRESETS[name].probe_radius == 0.01
    assert PRESETS["paper"].tissue == am.TissueParams() and PRESETS["paper"].probe_radius == 0
    assert DEFAULT_PRESET in PRESETS and am.PRESETS is PRESETS and am.load_scene is not None


def test_support_rules_against_the_heights_by_hand():
    z = np.array([-10.0, 0.0, 30.0]) * 1e-3
    vertices = np.column_stack([np.zeros(3), np.zeros(3), z])
    assert support_height("far-side", vertices, 0.03) == pytest.approx(-0.01 + FAR_SIDE * 0.04)
    assert support_height("far-side", vertices, 0.0) == pytest.approx(-0.01 + FAR_SIDE * 0.01)  # from this contact
    assert support_height("below:0.25", vertices, 0.0) == pytest.approx(-0.01 + 0.25 * 0.04)
    assert support_height("none", vertices, 0.03) is None
    for bad in ("below:1", "below:x", "side"):
        with pytest.raises(InputError, match="support"):
            parse_support(bad)


def test_a_bare_surface_gets_the_preset_and_its_foundation(sphere_obj, tmp_path):
    data = palpate_json(sphere_obj, tmp_path)
    wall = PRESETS[DEFAULT_PRESET].tissue
    assert data["tissue"]["preset"] == DEFAULT_PRESET and data["tissue"]["youngs_modulus_kPa"] == pytest.approx(wall.youngs_modulus * 1e-3)
    assert data["tissue"]["foundation_kPa_per_mm"] == pytest.approx(0.1) and data["support"]["fixed_below_mm"] is None
    assert data["model"]["probe_radius_mm"] == 10.0 and data["model"]["rings"] == "auto"
    press = data["presses"][0]
    # a 10 mm sphere 4 mm into a 30 mm sphere on a Winkler bed of 0.1 kPa/mm: kappa times the overlap's volume,
    # pi R d^2 with R = 10 x 30 / (10 + 30) mm (the membrane adds to it; a 162-vertex sphere resolves it coarsely);
    # the paper's constants give about 40 times that
    winkler = 0.1e6 * np.pi * 7.5e-3 * 0.004**2
    assert 0.6 * winkler < press["hold_force_N"] < 2 * winkler


def test_a_bare_tet_volume_is_held_on_its_far_side(ball_vtu, tmp_path):
    data = palpate_json(ball_vtu, tmp_path)
    v = meshio.read(ball_vtu).points  # mm, as in the file
    contact_z = data["contact"]["point_mm"][2]
    want = v[:, 2].min() + FAR_SIDE * (contact_z - v[:, 2].min())
    assert data["support"]["rule"] == "far-side" and data["support"]["fixed_below_mm"] == pytest.approx(want)
    assert contact_z == pytest.approx(v[:, 2].max())  # pressed from the top
    assert 0 < data["presses"][0]["hold_force_N"] < 1.0


def test_paper_only_on_request(sphere_obj, tmp_path):
    data = palpate_json(sphere_obj, tmp_path, "--tissue", "paper")
    assert data["tissue"]["model"] == "paper" and data["model"]["probe_radius_mm"] == 0.0 and data["model"]["rings"] == 4


def test_python_palpation_presses_what_the_command_line_presses(sphere_obj, tmp_path):
    data = palpate_json(sphere_obj, tmp_path)
    pal = am.palpation(sphere_obj, device="cpu")
    r = pal.press(0.004, 0.05, 0.05, 0.05)
    assert pal.vertex == data["contact"]["vertex"]
    assert (r.peak_force_N, r.hold_force_N) == (data["presses"][0]["peak_force_N"], data["presses"][0]["hold_force_N"])


@pytest.mark.parametrize("span, scale", [(128.0, 1.0), (6.5, 10.0), (12.8, 10.0), (0.2, 1000.0), (2.0e5, 1e-3)])
def test_unit_guessed_from_the_size(span, scale):
    got, line = guess_scale(span)
    assert got == scale and f"{span * scale:.4g} mm organ" in line


def test_a_centimetre_mesh_is_read_in_centimetres(tmp_path, capsys):
    v, f = icosphere_arrays(30.0, 1)
    path = tmp_path / "cm.obj"
    trimesh.Trimesh(v * 1e2, f, process=False).export(path)  # 6 units across: a 60 mm sphere in cm
    out = tmp_path / "t.json"
    assert main(["touch", str(path), "--json", str(out)]) == 0
    assert "read in centimetres" in capsys.readouterr().err
    point = json.loads(out.read_text())["contact"]["point_mm"]
    assert point[2] == pytest.approx(v[:, 2].max() * 1e3, rel=1e-5)  # 3 cm = 30 mm
    assert main(["touch", str(path), "--scale-mm", "1", "--json", str(out)]) == 0
    assert "not an organ's size" in capsys.readouterr().err


def test_a_dataset_of_a_bare_mesh_takes_its_preset(ball_vtu, tmp_path):
    """A mesh file in a dataset: the preset's sphere, auto rings (sized per point, as a sweep's) and its
    far-side support (the points it holds left out)."""
    from almsdm_warp.batch import dataset as ds
    from almsdm_warp.batch.sampling import pressable_points

    spec = tmp_path / "spec.toml"
    spec.write_text(f'[dataset]\nscenes = ["{ball_vtu}"]\npoints = 4\nmaps = "none"\n'
                    '[press]\ndepth_mm = 3.0\nramp_s = 0.03\nhold_s = 0.02\nsettle_s = 0.02\n')
    [item] = ds.plan_items(ds.load_spec(spec))
    v = item.plan.mesh.vertices
    plane = v[:, 2].min() + FAR_SIDE * (v[:, 2].max() - v[:, 2].min())
    assert item.plan.fixed_below == pytest.approx(plane) and item.plan.probe_radius == PRESETS[DEFAULT_PRESET].probe_radius
    _, kept = pressable_points(item.plan.mesh, 4, None)
    assert len(item.plan.vertices) == int((v[kept, 2] >= plane).sum()) >= 1
    assert item.plan.tol == pytest.approx(1e-4) and np.all(item.plan.point_rings >= 1)
    assert main(["sweep", "--dataset", str(spec), "--out", str(tmp_path / "out")]) == 0
    table = ds.DATASET_TABLE.read(tmp_path / "out" / "table.npz")
    np.testing.assert_array_equal(table["rings"], item.plan.point_rings)


def test_scene_support_rule_key(ball_vtu, tmp_path):
    """[support] rule: the same rule as --support and the JSON's support.rule; a height beside it is refused."""
    from almsdm_warp.scene.loader import load_scene

    path = tmp_path / "s.toml"
    path.write_text(f'[mesh]\npath = "{ball_vtu}"\n[tissue]\nmodel = "material"\nyoungs_modulus_kPa = 5.2\n[support]\nrule = "below:0.25"\n')
    scene = load_scene(path)
    assert scene.support == "below:0.25" and scene.as_dict()["support"]["rule"] == "below:0.25"
    data = palpate_json(path, tmp_path)
    v = meshio.read(ball_vtu).points
    assert data["support"]["fixed_below_mm"] == pytest.approx(v[:, 2].min() + 0.25 * np.ptp(v[:, 2]))
    path.write_text(path.read_text() + "fixed_below_mm = -5.0\n")
    with pytest.raises(InputError, match=r"\[support\] rule and fixed_below_mm both given"):
        load_scene(path)
