"""Supports: vertices below a plane are fixed. No step moves them (explicit and implicit, local region
and global), and a pressed, supported tet ball settles where SciPy's linear static solve of the same
network (supported vertices and the driven vertex as Dirichlet conditions) puts it."""

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse.linalg as spla
from fuzzing import run_main
from helpers import spring_stiffness_matrix

from almsdm_warp.errors import InputError

from almsdm_warp.mesh.primitives import icosphere, tet_ball
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import load_scene
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, Model
from almsdm_warp.solvers import make_solver
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.params import TissueParams

TISSUE = Material(youngs_modulus=10.0e3, poisson_ratio=0.45, density=1000.0, rayleigh_alpha=180.0)  # about 2 omega_1 of the supported ball: its slowest mode critically damped
FIXED_BELOW = -8e-3  # [m]: the bottom of a ball of radius 20 mm


@pytest.fixture(scope="module")
def ball():
    return tet_ball(20.0, 8.0)


def top(mesh):
    surface = np.asarray(sorted(mesh.surface_vertices))
    return int(surface[np.argmax(mesh.vertices[surface, 2])])


def hold(pal, vertex, depth, steps):
    """Drive `vertex` down by `depth` [m] and hold it there for `steps` steps; returns the last force."""
    pal.touch(vertex)
    target = pal.mesh.vertices[vertex] - np.array([0.0, 0.0, depth])
    pal.set_probe(PROBE_DISPLACEMENT, target)
    for _ in range(steps):
        force = pal.step()
    return np.array(force, dtype=np.float64), pal.state.particle_q.numpy().astype(np.float64)


def test_support_mask_and_default_anchors(ball):
    model = Model(ball, TISSUE, "cpu", fixed_below=FIXED_BELOW)
    np.testing.assert_array_equal(model.support_mask, ball.vertices[:, 2] < FIXED_BELOW)
    assert 0 < model.support_count < ball.vertex_count
    # a supported tet mesh needs no anchors; the paper's preset keeps them unless supported
    assert not Model(ball, TissueParams(), "cpu", fixed_below=FIXED_BELOW).anchor_ke.numpy().any()
    assert Model(ball, TissueParams(), "cpu").anchor_ke.numpy().min() == 124.0
    assert Model(ball, TissueParams(), "cpu", fixed_below=FIXED_BELOW, anchors=True).anchor_ke.numpy().min() == 124.0
    with pytest.raises(ValueError, match="every vertex is supported"):
        Model(ball, TISSUE, "cpu", fixed_below=1.0)
    with pytest.raises(ValueError, match="finite"):
        Model(ball, TISSUE, "cpu", fixed_below=float("nan"))


def test_free_set_lists_supported_vertices_after_the_free_ones(ball):
    """vertex_local maps each supported vertex past free_count, as the region's fixed ring is."""
    model = Model(ball, TISSUE, "cpu", fixed_below=FIXED_BELOW)
    solver = make_solver(model, "implicit")
    solver.set_global()
    free = solver.free_vertex.numpy()[: solver.free_count]
    local = solver.vertex_local.numpy()
    assert solver.free_count == ball.vertex_count - model.support_count
    assert not model.support_mask[free].any()
    np.testing.assert_array_equal(local[free], np.arange(solver.free_count))
    assert (local[model.support_mask] >= solver.free_count).all()


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
@pytest.mark.parametrize("rings", [6, "global"])
def test_supported_vertices_do_not_move_under_a_press(ball, device, integrator, rings):
    pal = Palpation(ball, TISSUE, rings=rings, integrator=integrator, dt=1e-4, device=device, fixed_below=FIXED_BELOW)
    _, q = hold(pal, top(ball), 5e-3, 300)
    moved = np.linalg.norm(q - pal.model.particle_q_rest.numpy(), axis=1)
    supported = pal.model.support_mask
    if rings != "global":
        inside = np.zeros(ball.vertex_count, dtype=bool)
        inside[pal.region.vertices()] = True
        assert (inside & supported).any()  # the region reaches the support
    assert moved[supported].max() == 0.0
    assert moved[~supported].max() > 1e-4  # the rest did move


@pytest.mark.parametrize("integrator", ["explicit", "implicit"])
def test_pressed_supported_ball_settles_at_the_linear_static_solution(ball, integrator):
    """A 0.1 mm press (linear range) held until the motion dies out: positions and the reaction match
    K u = 0 on the free vertices with u = 0 on the supports and u = press on the driven vertex."""
    depth, vertex = 1e-4, top(ball)
    pal = Palpation(ball, TISSUE, rings="global", integrator=integrator, dt=1e-4, device="cpu", fixed_below=FIXED_BELOW,
                    law="springs")  # the springs law: its linear statics, K of its springs
    force, q = hold(pal, vertex, depth, 3000)
    model = pal.model
    x = ball.vertices
    K = spring_stiffness_matrix(x, ball.edges.astype(np.int64), model.spring_ke_host, ball.edge_rest_length, 0.0).tocsr()
    known = np.zeros(ball.vertex_count, dtype=bool)
    known[model.support_mask] = True
    known[vertex] = True
    u = np.zeros((ball.vertex_count, 3))
    u[vertex, 2] = -depth
    dof_known = np.repeat(known, 3)
    rhs = -K[~dof_known][:, dof_known] @ u.reshape(-1)[dof_known]
    u.reshape(-1)[~dof_known] = spla.spsolve(K[~dof_known][:, ~dof_known].tocsc(), rhs)
    np.testing.assert_allclose(q - x, u, atol=0.02 * depth)
    reaction = (K @ u.reshape(-1)).reshape(-1, 3)[vertex]  # the force the probe applies
    np.testing.assert_allclose(-force, reaction, rtol=0.03, atol=0.01 * np.abs(reaction).max())


def test_surface_with_supports_keeps_its_foundation(device):
    sphere = icosphere(20.0, 2)
    wall = Material(youngs_modulus=20e3, thickness=3e-3, foundation=1e6, damping_ratio=0.5)
    pal = Palpation(sphere, wall, rings=4, integrator="implicit", dt=1e-3, device=device, fixed_below=-15e-3)
    assert pal.model.anchor_ke.numpy().min() > 0  # anchors stay on a surface
    _, q = hold(pal, top(sphere), 5e-3, 50)
    assert np.abs(q - pal.model.particle_q_rest.numpy())[pal.model.support_mask].max() == 0.0


# -- scenes and the command line ---------------------------------------------------------------
SCENES = Path(__file__).resolve().parents[1] / "scenes"


def liver_scene(tmp_path, extra):
    path = tmp_path / "scene.toml"
    path.write_text(f'[mesh]\npath = "{(SCENES / "liver.vtu").as_posix()}"\n{extra}')
    return path


def test_scene_support_section(tmp_path):
    scene = load_scene(liver_scene(tmp_path, "[support]\nfixed_below_mm = -5.0\n"))
    assert scene.fixed_below == pytest.approx(-5e-3)
    assert scene.as_dict()["support"] == {"fixed_below_mm": pytest.approx(-5.0), "rule": None}
    assert load_scene(SCENES / "paper_liver.toml").fixed_below is None
    assert load_scene(SCENES / "liver.toml").fixed_below == pytest.approx(-0.02)  # a tet material needs a support
    for text, message in (("[support]\nfixed_below = 1.0\n", r"unknown key 'fixed_below' in \[support\]"),
                          ("[support]\nfixed_below_mm = nan\n", r"\[support\] fixed_below_mm must be finite"),
                          ('[support]\nfixed_below_mm = "low"\n', r"\[support\] fixed_below_mm must be a number")):
        path = liver_scene(tmp_path, text)
        with pytest.raises(InputError, match=rf"^{path}: {message}"):
            load_scene(path)


def test_cli_palpate_with_a_material_and_supports_writes_them(tmp_path):
    out = tmp_path / "out.json"
    z_mm = float(np.percentile(load_scene(SCENES / "liver.toml").load_mesh().vertices[:, 2], 20)) * 1e3
    code, stdout, err = run_main(["palpate", str(SCENES / "liver.vtu"), "--youngs-modulus-kpa", "10", "--poisson-ratio", "0.45",
                                  "--fixed-below-mm", f"{z_mm}", "--rayleigh-alpha-per-s", "50", "--ramp-s", "0.02",
                                  "--hold-s", "0", "--settle-s", "0.02", "--rings", "global", "--integrator", "implicit", "--json", str(out)])
    assert code == 0, err
    record = json.loads(out.read_text())
    assert record["tissue"]["model"] == "material"
    assert record["tissue"]["youngs_modulus_kPa"] == pytest.approx(10.0) and record["tissue"]["poisson_ratio"] == 0.45
    assert record["support"]["fixed_below_mm"] == pytest.approx(z_mm)
    mesh = load_scene(SCENES / "liver.toml").load_mesh()
    assert record["model"]["free_vertices"] == int((mesh.vertices[:, 2] >= z_mm * 1e-3).sum())
    assert record["presses"][0]["peak_force_N"] > 0


@pytest.mark.parametrize(
    "args, message",
    [
        (["--youngs-modulus-kpa", "10", "--poisson-ratio", "0.5"], "--poisson-ratio: Material.poisson_ratio = 0.5: must be in (-1, 0.5)"),
        (["--tissue", "paper", "--density-kg-m3", "1000"], "--density-kg-per-m3 make the tissue a material, which needs --youngs-modulus-kpa"),
        (["--fixed-below-mm", "1000"], "--fixed-below-mm 1000 is above every vertex of liver.vtu"),
        (["--youngs-modulus-kpa", "0"], "argument --youngs-modulus-kpa: must be > 0"),
        (["--fixed-below-mm", "inf"], "argument --fixed-below-mm: must be finite"),
    ],
)
def test_cli_impossible_material_or_support_is_one_line_exit_2(args, message, tmp_path):
    out = tmp_path / "out.json"
    code, stdout, err = run_main(["palpate", str(SCENES / "liver.vtu"), *args, "--json", str(out)])
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_surface_material_needs_a_thickness(tmp_path):
    code, _stdout, err = run_main(["palpate", "paper_stomach", "--youngs-modulus-kpa", "10"])  # its constants give no thickness
    assert code == 2 and "surface mesh: the material model needs a membrane --thickness-mm > 0" in err


def test_sweep_of_a_supported_scene_never_presses_or_moves_the_support(tmp_path):
    """A supported scene sweeps: points below the plane are left out (a press there reads no force),
    and every point pressed reads a force above zero."""
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE

    out = tmp_path / "map.csv"
    code, _stdout, err = run_main(["sweep", str(liver_scene(tmp_path, "[support]\nfixed_below_mm = -5.0\n")), "--points", "6",
                                   "--out", str(out)])
    assert code == 0, err
    table = SWEEP_TABLE.read(out)
    assert np.all(table["z_mm"] >= -5.0) and np.all(table["peak_force_N"] > 0)


def test_api_refuses_what_it_cannot_hold():
    """A probe on a supported vertex would read zero force: an error, in a batch as alone, not a silent answer."""
    from almsdm_warp.batch import BatchPalpation
    from almsdm_warp.mesh.primitives import tet_ball
    from almsdm_warp.protocol import Palpation

    mesh = tet_ball(50.0, 20.0)
    z = mesh.vertices[:, 2]
    with pytest.raises(ValueError, match="held by the support"):
        BatchPalpation(mesh, rings=2, device="cpu", fixed_below=-0.04).touch([int(np.argmin(z))])
    pal = Palpation(mesh, rings=2, device="cpu", fixed_below=-0.04)
    with pytest.raises(ValueError, match="held by the support"):
        pal.touch(int(np.argmin(z)))
