"""A safe time step by default: the explicit integrator takes each frame in substeps under 0.9 x
the critical step of the region it simulates, falls back to the implicit one past the limit, and a
run that diverges anyway raises instead of returning inf or 1e19 N."""

import json
import math

import numpy as np
import pytest
from conftest import SHARED_MESHES

from almsdm_warp.batch.batch_palpation import BatchPalpation
from almsdm_warp.checks import LIMITS, substeps_for
from almsdm_warp.cli.main import main
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.solvers.stepper import SimulationDiverged
from almsdm_warp.region.contact import top_vertex
from almsdm_warp.scene.loader import resolve_scene_or_mesh
from almsdm_warp.sim.model import PROBE_DISPLACEMENT, Model

DEPTH = 0.01


@pytest.fixture(scope="module")
def stomach():
    scene = resolve_scene_or_mesh("paper_stomach")  # the paper's constants: the critical steps below are theirs
    return scene, scene.load_mesh()


def palpation(stomach, dt, vertex=None, **kw):
    scene, mesh = stomach
    p = Palpation(mesh, scene.tissue, rings=4, dt=dt, device="cpu", **kw)
    p.touch(top_vertex(mesh) if vertex is None else vertex)
    return p


def free(p):
    return p.region.vertices()[: p.region.free_count]


def held_forces(p, frames):
    """The feedback force of `frames` frames with the probe held DEPTH in (a copy per frame)."""
    p.set_probe(PROBE_DISPLACEMENT, p.rest_position() + p.inward_normal() * DEPTH)
    return np.array([p.step().copy() for _ in range(frames)])


def test_substeps_for_is_the_ceiling_under_0_9_of_the_critical_step():
    assert substeps_for(1e-3, 2e-3) == 1
    assert substeps_for(1e-3, 1e-3) == 2  # 1 ms > 0.9 ms
    assert substeps_for(5e-3, 1.61e-3) == math.ceil(5e-3 / (0.9 * 1.61e-3)) == 4
    assert substeps_for(1.0, math.inf) == 1
    assert substeps_for(1.0, 1e-6) == LIMITS["substeps"] + 1  # past the limit: the caller falls back


@pytest.mark.parametrize("n", [2, 3])
def test_a_frame_of_n_substeps_is_n_steps_of_dt_over_n(stomach, n):
    """The captured frame alternates the two states n times: the same bits as n frames of one
    step each at dt / n (dt chosen so that dt / n is the same float)."""
    h = 1e-3
    coarse = palpation(stomach, n * h, substeps=n)
    fine = palpation(stomach, h, substeps=1)
    assert coarse.step_dt == h
    a = held_forces(coarse, 20)
    b = held_forces(fine, 20 * n)[n - 1 :: n]
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(coarse.positions(), fine.positions())


def test_explicit_past_the_critical_step_substeps_and_matches_implicit(stomach):
    """dt 5 ms, about 3 x the region's critical step: n = ceil(dt / (0.9 crit)) substeps, a finite
    press whose peak force is within 2% of the implicit integrator's at 0.5 ms."""
    p = palpation(stomach, 5e-3)
    crit = p.model.critical_dt(free(p))
    assert p.substeps == math.ceil(5e-3 / (0.9 * crit)) >= 3 and p.step_dt < 0.9 * crit
    explicit = p.press(DEPTH, ramp=0.1, hold=0.2, settle=0.1)
    implicit = palpation(stomach, 5e-4, integrator="implicit").press(DEPTH, ramp=0.1, hold=0.2, settle=0.1)
    assert np.all(np.isfinite(explicit.force))
    assert math.isclose(explicit.peak_force_N, implicit.peak_force_N, rel_tol=0.02)


def test_substeps_follow_the_region(stomach):
    """Expanding the region or moving the contact re-plans the substeps from the new free set."""
    scene, mesh = stomach
    p = palpation(stomach, 2.5e-3)
    for change in (lambda: p.expand(3), lambda: p.touch(0)):
        change()
        crit = p.model.critical_dt(free(p))
        assert p.critical_dt == pytest.approx(crit) and p.substeps == math.ceil(2.5e-3 / (0.9 * crit))


def test_past_the_substep_limit_it_falls_back_to_implicit(stomach):
    p = palpation(stomach, 0.2)  # 0.2 s frames: over 100 substeps of the ~1.6 ms critical step
    assert p.solver.integrator == "implicit" and p.substeps == 1
    assert len(p.notes) == 1 and "implicit" in p.notes[0]
    result = p.press(DEPTH, ramp=0.2, hold=0.4, settle=0.4)
    assert np.all(np.isfinite(result.force)) and 1.0 < result.peak_force_N < 5.0


def test_a_diverging_step_loop_raises(stomach):
    """A 1 kHz step() loop past the critical step (substeps fixed at 1, the paper's scheme) raises
    within a few hundred frames; it used to return 1e19 N and then inf."""
    p = palpation(stomach, 5e-3, substeps=1)
    p.set_probe(PROBE_DISPLACEMENT, p.rest_position() + p.inward_normal() * DEPTH)
    seen = []
    with pytest.raises(SimulationDiverged, match="diverged"):
        for _ in range(1000):
            seen.append(float(np.linalg.norm(p.step())))
    assert len(seen) < 1000 and all(math.isfinite(f) for f in seen)


def test_bad_substeps_are_refused(stomach):
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="substeps"):
            palpation(stomach, 1e-3, substeps=bad)


def test_batch_substeps_under_the_worst_region_and_raises_when_fixed_past_it(stomach):
    """One dt for the batch: under 0.9 x the critical step of the union of its free vertices
    (no region's is shorter). At 5 ms it presses finitely, within 3% of the implicit batch's force
    at 0.5 ms; fixed at one substep it raises instead of returning 6.7e18 N."""
    scene, mesh = stomach
    model = Model(mesh, scene.tissue, "cpu")
    vertices = [top_vertex(mesh), 0, 500]
    batch = BatchPalpation(model=model, rings=4, dt=5e-3).touch(vertices)
    union = np.unique(np.concatenate([batch.region(b)[: batch.free_vertex_counts[b]] for b in range(3)]))
    crit = model.critical_dt(union)
    assert batch.substeps == math.ceil(5e-3 / (0.9 * crit))
    got = batch.press(DEPTH, ramp=0.1, hold=0.2, settle=0.1)
    ref = BatchPalpation(model=model, rings=4, dt=5e-4, integrator="implicit").touch(vertices).press(DEPTH, 0.1, 0.2, 0.1)
    np.testing.assert_allclose(got.hold_force, ref.hold_force, rtol=0.03)
    fixed = BatchPalpation(model=model, rings=4, dt=5e-3, substeps=1).touch(vertices)
    with pytest.raises(SimulationDiverged, match="diverged at"):
        fixed.press(DEPTH, ramp=0.1, hold=0.2, settle=0.1)


def test_critical_dt_without_arpack_is_a_lower_bound(stomach, monkeypatch):
    """Where ARPACK does not converge, Gershgorin's bounds give a step no longer than the true one."""
    import scipy.sparse.linalg as sla

    scene, mesh = stomach
    model = Model(mesh, scene.tissue, "cpu")
    exact = model.critical_dt()

    def fails(*args, **kw):
        raise sla.ArpackNoConvergence("no convergence", np.zeros(0), np.zeros((0, 0)))

    monkeypatch.setattr(sla, "eigsh", fails)
    bound = model.critical_dt()
    assert 0.2 * exact < bound <= exact


def test_the_critical_step_is_the_same_on_every_call_and_the_dense_answer(stomach):
    """The whole mesh's critical step, asked three times in one process and once in another, is one
    number (ARPACK from a seeded start: from its own random one the paper preset's moved by 1e-7 between
    calls, and a plan's substeps could differ between runs), within eigsh's 1e-6 of the dense eigenvalue."""
    import subprocess
    import sys

    import scipy.linalg

    from almsdm_warp.tissue import laws

    scene, mesh = stomach
    model = Model(mesh, scene.tissue, "cpu")
    values = {model.critical_dt() for _ in range(3)}
    assert len(values) == 1
    code = ("from almsdm_warp.warp_init import init_warp; init_warp(); from almsdm_warp.scene.loader import resolve_scene_or_mesh; "
            "from almsdm_warp.sim.model import Model; s = resolve_scene_or_mesh('paper_stomach'); "
            "print(repr(Model(s.load_mesh(), s.tissue, 'cpu').critical_dt()))")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()[-1]
    assert float(other) == values.pop()
    # the dense answer: the largest eigenvalue of M^-1/2 K M^-1/2 and its mode's damping (stable_step's rule)
    K, C = laws.springs_matrices(model)
    w = np.repeat(1.0 / np.sqrt(model.particle_mass_host), 3)
    Kd, Cd = w[:, None] * K.toarray() * w[None, :], w[:, None] * C.toarray() * w[None, :]
    lam, vec = scipy.linalg.eigh(Kd, subset_by_index=[len(Kd) - 1, len(Kd) - 1])
    g = vec[:, 0] @ Cd @ vec[:, 0]
    dense = (-g + np.sqrt(g * g + 4.0 * lam[0])) / lam[0]
    assert model.critical_dt() == pytest.approx(dense, rel=1e-6)


def test_a_model_of_non_finite_stiffness_is_refused_when_made(stomach):
    # a float32 overflow (inf stiffness, "critical step not finite") is refused at its root: the factor
    scene, mesh = stomach
    with pytest.raises(ValueError, match=r"edge_scale must be finite factors >= 0, 0 or of magnitude 1e-12 to 1e\+12: edge_scale\[0\] = 1e\+308"):
        Model(mesh, scene.tissue, "cpu", edge_scale=np.full(mesh.edge_count, 1e308))
    with pytest.raises(ValueError, match=r"anchor_scale must be .*anchor_scale\[3\] = nan"):
        Model(mesh, scene.tissue, "cpu", anchor_scale=np.r_[np.ones(3), np.nan, np.ones(mesh.vertex_count - 4)])


@pytest.mark.skipif(not (SHARED_MESHES / "gca_stomach_1002v.obj").exists(), reason="gca_stomach_1002v.obj is not present")
def test_a_mesh_that_diverged_with_the_defaults_now_presses(tmp_path):
    """`almsdm palpate gca_stomach_1002v.obj --vertex 0` diverged at the default 1 ms (critical step
    0.88 ms); it now runs in substeps, and its peak force is within 2% of the implicit one at 0.1 ms."""
    mesh = str(SHARED_MESHES / "gca_stomach_1002v.obj")
    runs = {}
    for name, extra in (("explicit", []), ("implicit", ["--integrator", "implicit", "--dt-ms", "0.1"])):
        out = tmp_path / f"{name}.json"
        assert main(["palpate", mesh, "--vertex", "0", "--settle-s", "0.1", *extra, "--json", str(out)]) == 0
        runs[name] = json.loads(out.read_text())
    model = runs["explicit"]["model"]
    assert model["dt_s"] > model["critical_dt_s"] and model["substeps"] >= 2
    f = [runs[k]["presses"][0]["peak_force_N"] for k in ("explicit", "implicit")]
    assert all(math.isfinite(x) for x in f) and math.isclose(*f, rel_tol=0.02)


def test_sweep_past_the_critical_step_writes_a_finite_table(tmp_path, capsys):
    """`sweep --dt-ms 2` wrote inf into its table; it now substeps, says its cost first, and every
    number it writes is finite."""
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE

    out = tmp_path / "t.csv"
    assert main(["sweep", "paper_stomach", "--out", str(out), "--points", "4", "--dt-ms", "2", "--settle-s", "0.1"]) == 0
    stdout = capsys.readouterr().out
    assert "cost: " in stdout and "x at most 2 substep(s)" in stdout, stdout
    table = SWEEP_TABLE.read(out)
    assert all(np.all(np.isfinite(table[c])) for c in table) and np.all(table["peak_force_N"] > 0.5)


def test_a_sweep_that_diverges_writes_nothing(tmp_path, monkeypatch, capsys):
    """A chunk with a non-finite number raises before it is written: one line, exit 2, no table
    and no parts folder (a rerun of the same plan would diverge again)."""
    finish = BatchPalpation.finish_press

    def one_inf(self):
        result = finish(self)
        result.peak_force[0] = np.inf
        return result

    monkeypatch.setattr(BatchPalpation, "finish_press", one_inf)
    out = tmp_path / "t.csv"
    assert main(["sweep", "paper_stomach", "--out", str(out), "--points", "4", "--settle-s", "0.05"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "peak_force_N is not finite" in err and "nothing is written" in err, err
    assert list(tmp_path.iterdir()) == []


def test_multi_probe_substeps_under_the_patches_critical_step(stomach):
    """Two probes, 4 rings each, dt 5 ms: the frame is taken in substeps under 0.9 x the critical
    step of the patches' free vertices together, and each probe's peak force is within 3% of the
    implicit integrator's at 0.5 ms."""
    from almsdm_warp.protocol.multi import MultiPalpation

    scene, mesh = stomach
    vertices = [top_vertex(mesh), 0]
    results = {}
    for integrator, dt in (("explicit", 5e-3), ("implicit", 5e-4)):
        multi = MultiPalpation(mesh, scene.tissue, rings=4, integrator=integrator, dt=dt, device="cpu", retire=False)
        multi.touch(vertices)
        results[integrator] = multi.press(DEPTH, ramp=0.1, hold=0.2, settle=0.05)
        if integrator == "explicit":
            union = np.unique(np.concatenate([p.region.vertices()[: p.region.free_count] for p in multi.patches]))
            assert multi.substeps == math.ceil(dt / (0.9 * multi.model.critical_dt(union))) >= 3
    for a, b in zip(results["explicit"], results["implicit"]):
        assert np.all(np.isfinite(a.force)) and math.isclose(a.peak_force_N, b.peak_force_N, rel_tol=0.03)
