"""--volume and --wall on every front end (palpate, sweep, trace, datasets, scenes: scene/volume.py's one rule):
the scene keys, the tets finest where a sweep presses and along a path's contacts (a sphere's closed form), the
tet count refused before fTetWild runs, and each command end to end on a tiny ball."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from almsdm_warp.cli.main import main
from almsdm_warp.errors import InputError
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.scene.loader import load_scene, mesh_scene
from almsdm_warp.tissue.material import Material

pytest.importorskip("pytetwild", reason="fTetWild is the volume extra: pip install -e .[volume]")

BALL_MM = 15.0
PRESS = ["--youngs-modulus-kpa", "5", "--rayleigh-alpha-per-s", "100", "--integrator", "implicit", "--dt-ms", "2"]
SHORT = ["--depth-mm", "3", "--ramp-s", "0.04", "--hold-s", "0.04", "--settle-s", "0.02", "--probe-radius-mm", "8"]
"""A 3 mm press of an 8 mm sphere: edges of 0.45 sqrt(8 x 3) = 2.2 mm where pressed, near the ball's coarse 2.6 mm
(its diagonal / 20): a few thousand tets, a few seconds of fTetWild."""


@pytest.fixture(scope="module")
def ball_file(tmp_path_factory):
    """An icosphere of radius 15 mm (320 triangles) as an OBJ."""
    path = tmp_path_factory.mktemp("ball") / "ball.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=BALL_MM).export(path)
    return path


def scene_file(tmp_path, ball_file, mesh_keys: str = "", tissue_keys: str = ""):
    path = tmp_path / "scene.toml"
    path.write_text(f'[mesh]\npath = "{ball_file.as_posix()}"\n{mesh_keys}\n[tissue]\nmodel = "material"\n'
                    f"youngs_modulus_kPa = 5.0\nthickness_mm = 3.0\n{tissue_keys}\n")
    return path


def test_scene_keys_read_and_checked(tmp_path, ball_file):
    scene = load_scene(scene_file(tmp_path, ball_file, 'volume = "auto"', 'wall = "tets"'))
    assert (scene.volume, scene.wall) == ("auto", "tets")
    assert scene.as_dict()["mesh"]["volume"] == "auto" and scene.as_dict()["tissue"]["wall"] == "tets"
    plain = load_scene(scene_file(tmp_path, ball_file))
    assert (plain.volume, plain.wall) == ("off", "membrane") and "wall" not in plain.as_dict()["tissue"]
    with pytest.raises(InputError, match=r"scene\.toml: \[mesh\] volume = 'always' is not one of 'off', 'auto'"):
        load_scene(scene_file(tmp_path, ball_file, 'volume = "always"'))
    with pytest.raises(InputError, match=r"scene\.toml: \[tissue\] wall = 'shell' is not one of 'membrane', 'tets'"):
        load_scene(scene_file(tmp_path, ball_file, "", 'wall = "shell"'))


def test_what_a_surface_becomes(ball_file):
    from dataclasses import replace

    from almsdm_warp.mesh.io import load_mesh
    from almsdm_warp.scene.volume import tets_wanted

    mesh = load_mesh(ball_file)
    scene = replace(mesh_scene(ball_file), tissue=Material(youngs_modulus=5e3, thickness=3e-3))
    assert tets_wanted(scene, mesh) is None  # off and membrane: as read
    assert tets_wanted(scene, mesh, volume="auto") == "volume"
    assert tets_wanted(scene, mesh, volume="auto", wall="membrane") == "volume"
    assert tets_wanted(scene, mesh, wall="tets") == "wall"
    assert tets_wanted(replace(scene, law="springs"), mesh, volume="auto") is None  # springs need no volume
    with pytest.raises(InputError, match="both make the surface tets"):
        tets_wanted(scene, mesh, volume="auto", wall="tets")
    with pytest.raises(InputError, match="per-spring constants"):
        tets_wanted(mesh_scene(ball_file, tissue="paper"), mesh, wall="tets")


def test_path_contacts_are_a_spheres_closed_form():
    """A sphere of radius r moved straight over a ball of radius B at height h (centre (x, 0, h)): it touches
    where sqrt(x^2 + h^2) < B + r, at the radial projection B c / |c|, deepest (B + r - h) at x = 0."""
    from almsdm_warp.cli.volume_arg import path_contacts

    s = trimesh.creation.icosphere(subdivisions=4, radius=50.0)
    mesh = TissueMesh.from_arrays(s.vertices, s.faces)
    B, r, d = 0.05, 0.01, 0.004
    x = np.linspace(-0.04, 0.04, 801)
    centres = np.column_stack([x, np.zeros_like(x), np.full_like(x, B + r - d)])
    contacts, depth = path_contacts(mesh, centres, r)
    assert depth == pytest.approx(d, abs=1e-4)  # the polyhedron lies up to 0.06 mm inside the sphere
    np.testing.assert_allclose(np.linalg.norm(contacts, axis=1), B, rtol=2e-3)
    reach = np.sqrt((B + r) ** 2 - (B + r - d) ** 2) * B / (B + r)  # the last contact's x on the ball (|c| = B + r)
    assert reach - r / 8.0 <= np.abs(contacts[:, 0]).max() <= reach * 1.01  # sampled every r / 8 along the path
    assert path_contacts(mesh, centres + [0.0, 0.0, 0.02], r)[1] == 0.0  # never touching: no contacts
    assert len(path_contacts(mesh, centres + [0.0, 0.0, 0.02], r)[0]) == 0


def test_a_sweeps_tets_are_finest_at_every_pressed_point():
    from almsdm_warp.mesh.volume import contact_edge
    from almsdm_warp.scene.volume import snap_to, sweep_tets

    s = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    surface = TissueMesh.from_arrays(s.vertices, s.faces)
    scene = mesh_scene("ball.obj")  # the default preset's material, no support
    from dataclasses import replace

    scene = replace(scene, probe_radius=0.008, support=None)
    tets, points = sweep_tets("volume", scene, surface, 2, 0.003)
    edge = contact_edge(0.008, 0.003)  # 2.2 mm, where the ball's coarse edge is its diagonal / 20, 5.2 mm
    points, vertices = snap_to(tets, points)
    assert len(points) == 2 and np.linalg.norm(tets.vertices[vertices] - points, axis=1).max() < edge
    e, length = tets.edges, tets.edge_rest_length
    mid = tets.vertices[e].mean(axis=1)
    for p in points:
        near = length[np.linalg.norm(mid - p, axis=1) < 2.0 * edge]
        assert len(near) > 10 and near.mean() <= edge, (near.mean(), edge)
    far = np.min([np.linalg.norm(mid - p, axis=1) for p in points], axis=0) > 20e-3
    assert np.median(length[far]) > 1.5 * edge  # graded: not the fine edge everywhere


def test_too_many_tets_are_refused_before_fTetWild_runs(monkeypatch):
    import pytetwild

    from almsdm_warp.mesh.volume import tetrahedralize

    def not_called(*args, **kwargs):
        raise AssertionError("fTetWild ran")

    monkeypatch.setattr(pytetwild, "tetrahedralize", not_called)
    s = trimesh.creation.icosphere(subdivisions=2, radius=50.0)
    surface = TissueMesh.from_arrays(s.vertices, s.faces)
    with pytest.raises(InputError, match=r"the tets would be about [\d,]+ \(target edge 2 mm\), more than 1,000"):
        tetrahedralize(surface, edge=0.002, max_tets=1000)
    # the estimate's scale: 8.5 / edge^3 over the ball's volume (4/3 pi R^3 / (2 mm)^3 x 8.5 = 556,000)
    with pytest.raises(InputError, match=r"about (5[0-9]\d|6[0-2]\d),\d{3} \("):
        tetrahedralize(surface, edge=0.002, max_tets=1000)


def test_palpate_a_wall_of_tets(tmp_path, ball_file, capsys):
    out = tmp_path / "out.json"
    args = ["palpate", str(ball_file), "--wall", "tets", "--thickness-mm", "3", *PRESS, *SHORT, "--depth-mm", "2",
            "--probe-radius-mm", "5", "--rings", "2", "--json", str(out)]  # layers of 0.45 sqrt(5 x 2) = 1.42 mm
    assert main(args) == 0
    data = json.loads(out.read_text())
    err = capsys.readouterr().err
    assert "the wall extruded inward 3 mm in 3 layer(s) of tets: 2880 tets" in err  # 320 triangles x 3 layers x 3
    assert data["mesh"]["tetrahedra"] == 2880 and data["model"]["law"] == "neo-hookean"
    top = int(np.argmax(trimesh.load(ball_file).vertices[:, 2]))
    assert data["contact"]["vertex"] == top  # the outer layer keeps the surface's vertex ids
    assert data["presses"][0]["inverted_tets"] == 0 and 0.0 < data["presses"][0]["hold_force_N"] < 1.0


@pytest.mark.parametrize("extra, message", [
    (["--wall", "tets", "--volume", "auto", "--thickness-mm", "3", "--youngs-modulus-kpa", "5"], "both make the surface tets"),
    (["--wall", "tets", "--tissue", "paper"], "per-spring constants"),
    (["--wall", "tets", "--thickness-mm", "0"], "needs a membrane --thickness-mm"),
    (["--wall", "tets", "--thickness-mm", "14", "--youngs-modulus-kpa", "5"], "folds at vertex"),
])
def test_bad_wall_is_one_line_exit_2(ball_file, capsys, extra, message):
    assert main(["palpate", str(ball_file), *extra, *SHORT]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("note: ")]
    assert len(lines) == 1 and lines[0].startswith("almsdm: ") and message in lines[0], lines


def test_sweep_presses_its_points_on_the_volume(tmp_path, ball_file, capsys):
    out = tmp_path / "map.csv"
    args = ["sweep", str(ball_file), "--out", str(out), "--points", "2", "--volume", "auto", "--rings", "1",
            "--support", "none", *PRESS, *SHORT]
    assert main(args) == 0
    text = capsys.readouterr()
    assert "tetrahedralized by fTetWild" in text.err and "of 2 points" in text.err
    table = np.genfromtxt(out, delimiter=",", names=True)
    from almsdm_warp.batch.sampling import sample_points
    from almsdm_warp.mesh.io import load_mesh

    points, _ = sample_points(load_mesh(ball_file), 2)  # the surface's points, pressed on the tets
    np.testing.assert_allclose(np.column_stack([table["x_mm"], table["y_mm"], table["z_mm"]]), points * 1e3, atol=1e-9)
    assert (table["hold_force_N"] > 0).all()


def test_trace_along_a_path_on_the_volume(tmp_path, ball_file, capsys):
    path = tmp_path / "path.csv"
    path.write_text("t_s,x_mm,y_mm,z_mm\n0,0,0,24\n0.1,0,0,20\n0.2,3,0,20\n")  # 3 mm into the top, then 3 mm along
    out = tmp_path / "trace.json"
    args = ["trace", str(ball_file), "--path", str(path), "--volume", "auto", "--rings", "2", "--probe-radius-mm", "8",
            "--youngs-modulus-kpa", "5", "--rayleigh-alpha-per-s", "100", "--integrator", "implicit", "--dt-ms", "5",
            "--json", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "tetrahedralized by fTetWild" in err and "2.2 mm within 8.82 mm of" in err  # 0.45 sqrt(8 mm x 3 mm)
    data = json.loads(out.read_text())
    assert data["mesh"]["tetrahedra"] > 0 and data["model"]["law"] == "neo-hookean" and data["peak_force_N"] > 0


def test_dataset_spec_volume(tmp_path, ball_file):
    from almsdm_warp.batch import dataset as ds

    spec = tmp_path / "spec.toml"
    body = f'[dataset]\nscenes = ["{ball_file.as_posix()}"]\npoints = 2\nrings = 1\nmaps = "none"\n[press]\ndepth_mm = 3.0\n'
    spec.write_text(body.replace("maps", 'volume = "maybe"\nmaps'))
    with pytest.raises(InputError, match=r"spec\.toml: \[dataset\] volume = 'maybe' is not one of 'off', 'auto'"):
        ds.load_spec(spec)
    spec.write_text(body.replace("maps", 'volume = "auto"\nmaps'))
    loaded = ds.load_spec(spec)
    assert loaded.volume == "auto"
    (item,) = ds.plan_items(loaded)
    mesh = item.plan.mesh
    assert mesh.is_volume and item.plan.law == "neo-hookean"
    assert set(item.plan.vertices) <= set(mesh.surface_vertices.tolist())
    assert (mesh.vertices[item.plan.vertices, 2] >= item.plan.fixed_below).all()  # the tets' far-side support
    assert main(["sweep", "--dataset", str(spec), "--out", str(tmp_path / "o"), "--volume", "auto"]) == 2


def test_touch_and_the_python_api_follow_the_scenes_wall(tmp_path, ball_file):
    """A scene's [tissue] wall = "tets" is the same wall wherever the scene is read: touch's regions and the Python
    API's palpation are on the wall's tets (palpate's --wall tets: the test above), the contact the same vertex."""
    import almsdm_warp as am

    scene = scene_file(tmp_path, ball_file, "", 'wall = "tets"\nrayleigh_alpha_per_s = 100.0\n[probe]\nradius_mm = 5.0\n'
                                                "[press]\ndepth_mm = 2.0\n[region]\nrings = 2")
    out = tmp_path / "touch.json"
    assert main(["touch", str(scene), "--json", str(out)]) == 0
    touched = json.loads(out.read_text())
    assert touched["mesh"]["tetrahedra"] == 2880  # 320 triangles x 3 layers of 1 mm (0.45 sqrt(5 x 2) = 1.42 mm) x 3
    pal = am.palpation(str(scene), integrator="implicit", dt=2e-3)
    top = int(np.argmax(trimesh.load(ball_file).vertices[:, 2]))
    assert pal.model.mesh.tet_count == 2880 and pal.model.law == "neo-hookean" and touched["contact"]["vertex"] == top
    assert pal.press(2e-3, 0.04, 0.04, 0.02).hold_force_N > 0.0
