"""`almsdm evaluate --quick`: every part runs once (module fixture, about a minute of CPU), and
what it writes holds against independent answers: region sizes against scipy breadth-first
distances, the explicit stability boundary against the linearized critical step, the unanchored
global model never recovering, the global reference's zero error, non-blank figures, and a
results.md that names the machine, the date and the command. Bad input: one line, exit 2, nothing
written. CPU (a command-line run); no timing asserts."""

import datetime
import json
import math
import platform

import numpy as np
import pytest
from conftest import SHARED_MESHES
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from almsdm_warp.cli.main import main
from almsdm_warp.errors import InputError
from almsdm_warp.evaluation.accuracy import join_extra_points, read_extra_points
from almsdm_warp.evaluation.common import SETTINGS
from almsdm_warp.mesh import primitives
from almsdm_warp.evaluation.stability import DIVERGED, NOT_RECOVERED, OSCILLATING, STABLE, classify
from almsdm_warp.protocol.palpation import PressResult
from almsdm_warp.tissue.laws import LAWS

GPU_STEP_US = 1.25  # an input of the test: a made-up GPU time that must reach the table as given


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("evaluate")
    extra = out.parent / "bench_gpu.json"
    extra.write_text(
        json.dumps(
            {
                "mesh": "/somewhere/scenes/stomach.obj",
                "device": "cuda:0",
                "single": [
                    {"rings": 4, "integrator": "explicit", "step_us_median": GPU_STEP_US},
                    {"rings": 77, "integrator": "explicit", "step_us_median": 9.0},  # not run here: left out
                ],
            }
        )
    )
    started = datetime.datetime.now(datetime.timezone.utc)
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("ALMSDM_SHARED_MESHES", str(SHARED_MESHES))
        assert main(["evaluate", "--quick", "--out", str(out), "--extra-json", str(extra), "--no-progress"]) == 0
    results = json.loads((out / "results.json").read_text())
    return out, results, (out / "results.md").read_text(), started


def stomach_mesh():
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    return resolve_scene_or_mesh("stomach").load_mesh()


def test_results_md_names_machine_date_and_command(quick):
    out, results, md, started = quick
    import warp as wp

    assert "`almsdm evaluate --quick --device cpu --out " in md
    assert started.strftime("%Y-%m-%d") in md
    assert f"warp-lang {wp.config.version}" in md and f"Python {platform.python_version()}" in md
    with open("/proc/cpuinfo") as f:
        model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), None)
    if model:
        assert model in md
    for section in ("## 1. Recovery", "## 2. Table 1", "## 3. Force against displacement", "## 4. Table 2", "## 5. Speed against accuracy", "## 6. Stability map", "## 7. Real anatomy",
                    "## 8. Mesh convergence", "## 9. Against finite elements", "## 10. Depth, layers and lesions"):
        assert section in md


def test_figures_are_non_blank_pngs(quick):
    import matplotlib.image as mpimg

    out, results, md, _ = quick
    expected = {"recovery", "force_displacement", "speed_accuracy", "stability", "convergence", "against_fem"}
    if results["anatomy"]["rows"]:
        expected |= {"anatomy_cost", "anatomy_force"}
    assert set(results["figures"]) == expected
    for rel in results["figures"].values():
        assert f"]({rel})" in md  # linked from results.md, relative to it
        path = out / rel
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        img = mpimg.imread(path)[..., :3]
        assert img.shape[0] > 200 and img.shape[1] > 300
        ink = np.any(img < 0.9, axis=2).mean()  # share of pixels that are not (near) white
        assert 0.01 < ink < 0.6, (rel, ink)
        assert len(np.unique(img.reshape(-1, 3).round(2), axis=0)) > 8  # colours: not a flat image
    assert not list(out.glob(".*")) and not list((out / "figures").glob(".*"))  # no temporary files left


def test_recovery_table_against_breadth_first_rings_and_the_unanchored_model(quick):
    _, results, md, _ = quick
    rec = results["recovery"]
    mesh = stomach_mesh()
    n = mesh.vertex_count
    e = mesh.edges.astype(np.int64)
    graph = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    hops = shortest_path(graph, directed=False, unweighted=True, indices=rec["vertex"])
    for row in rec["rows"]:
        if row["rings"] == "global-free":
            assert row["region_vertices"] == n and row["region_springs"] == len(e)
            assert min(row["residual_mm"]) > 1.0  # never recovers (the paper: 15.2 mm)
            assert "| global, no anchors |" in md and "never recovers" in md
            continue
        inside = hops <= row["rings"]
        assert row["region_vertices"] == int(inside.sum())
        assert row["region_springs"] == int(np.count_nonzero(inside[e[:, 0]] & inside[e[:, 1]]))
        assert max(row["residual_mm"]) < 0.11  # anchored local models come back
        assert len(row["residual_mm"]) == 3  # --quick: 3 presses


def test_table1_local_matches_global_and_unanchored_never_recovers(quick):
    _, results, md, _ = quick
    rows = {r["label"]: r for r in results["table1"]["rows"]}
    for organ in ("stomach", "liver"):
        local, glob, free = rows[f"{organ}, 4 rings"], rows[f"{organ}, global anchored"], rows[f"{organ}, global free (no anchors)"]
        assert local["peak_force_N"] == pytest.approx(glob["peak_force_N"], rel=0.01)
        assert 2.0 < local["peak_force_N"] < 3.0  # calibrated to the paper's 2.4 / 2.3 N
        assert local["recovery_error_mm"] < 0.11 and local["recovery_time_s"] is not None
        assert free["recovery_time_s"] is None and free["recovery_error_mm"] > 1.0  # null: infinite
        assert free["peak_force_N"] < 0.5 * local["peak_force_N"]  # nothing anchors it: it gives way
    assert "| 0.455 |" in md and "| 15.224 |" in md and "| 2.312 |" in md  # the paper's values beside ours


def test_speed_accuracy_errors_shrink_with_rings_and_gpu_points_join(quick):
    _, results, md, _ = quick
    rows = results["accuracy"]["rows"]
    for scene, integrator in {(r["scene"], r["integrator"]) for r in rows}:
        series = [r for r in rows if r["scene"] == scene and r["integrator"] == integrator]
        glob = next(r for r in series if r["rings"] == "global")
        assert glob["force_error_N"] == 0.0 and glob["disp_error_mm"] == 0.0  # the reference against itself
        local = sorted((r for r in series if isinstance(r["rings"], int)), key=lambda r: r["rings"])
        errors = [r["disp_error_mm"] for r in local]
        assert all(b <= a + 1e-4 for a, b in zip(errors, errors[1:])), (scene, integrator, errors)
        assert errors[0] > 10 * errors[-1]
        assert [r["region_vertices"] for r in local] == sorted(r["region_vertices"] for r in local)
    extra = results["accuracy"]["extra"]
    assert len(extra) == 1 and extra[0]["device"] == "cuda:0" and extra[0]["step_us"] == GPU_STEP_US
    cpu = next(r for r in rows if (r["scene"], r["integrator"], r["rings"]) == ("stomach", "explicit", 4))
    assert extra[0]["disp_error_mm"] == cpu["disp_error_mm"]
    assert f"| stomach (cuda:0) | explicit | 4 | {cpu['region_vertices']} | {GPU_STEP_US:.1f} |" in md
    try:
        from almsdm_warp.evaluation.accuracy import find_auto_factory

        auto = find_auto_factory() is not None
    except ImportError:
        auto = False
    assert ("Rings `auto` not available" in md) == (not auto)


def test_stability_map_agrees_with_the_critical_step(quick):
    _, results, md, _ = quick
    s = results["stability"]
    assert s["cells"]
    for c in s["cells"]:
        crit = s["critical_dt_ms"][str(c["scale"])]
        if c["integrator"] == "implicit":
            assert c["state"] == STABLE, c
        elif c["dt_ms"] <= 0.9 * crit:
            assert c["state"] == STABLE, (c, crit)
        elif c["dt_ms"] >= 1.25 * crit:
            assert c["state"] == DIVERGED, (c, crit)
    assert all(c["state"] in (NOT_RECOVERED, OSCILLATING, DIVERGED) for c in s["global_free_cells"])
    # stiffer tissue, smaller critical step (about 1/sqrt(scale))
    crits = [s["critical_dt_ms"][k] for k in sorted(s["critical_dt_ms"], key=float)]
    assert crits == sorted(crits, reverse=True)


def test_table2_and_anatomy(quick):
    _, results, md, _ = quick
    from almsdm_warp.sim.normals import STRATEGIES

    # a frame is a step and a normals update: slower than the step alone, with every strategy
    assert results["table2"]["strategies"] == list(STRATEGIES)
    for row in results["table2"]["rows"]:
        assert set(row["fps"]) == set(STRATEGIES)
        assert all(0 < fps < row["steps_per_s"] for fps in row["fps"].values())
    assert "Normals strategies not available" not in md
    assert [r["region_vertices"] for r in results["table2"]["rows"][:4]] == sorted(r["region_vertices"] for r in results["table2"]["rows"][:4])
    rows = results["anatomy"]["rows"]
    if not SHARED_MESHES.is_dir():
        assert rows == [] and "were absent" in md
        return
    assert {r["file"] for r in rows} == {"gca_stomach_1002v.obj", "mor_liverTinyMesh.vtu", "mor_liverVeryCOARSE.vtu", "mor_liverCoarse.vtu"}
    for r in rows:
        assert 0 < r["region_vertices"] <= r["vertices"]
        assert r["local_peak_force_N"] == pytest.approx(r["global_peak_force_N"], rel=0.02)
        assert max(r["local_residual_mm"]) < 0.11
        if r["free_residual_mm"] is not None:
            assert r["free_residual_mm"] > 1.0


def test_convergence_and_against_fem_sections(quick):
    """The material model converges where the paper's constants follow the mesh; the ball's global
    model against an independent P2 solve on the same mesh (and Hertz's closed form, recomputed)."""
    from almsdm_warp.evaluation import fem

    _, results, md, _ = quick
    conv = results["convergence"]
    for part in (conv["icosphere"], conv["ball"]):
        material, paper = (part["series"][k] for k in part["series"])
        assert len(material) == 2 and max(material) / min(material) - 1 < 0.05
        assert max(paper) / min(paper) - 1 > 0.15  # one stiffness per edge: the force follows the mesh
    f = results["against_fem"]
    vertices, tets = primitives.tet_ball_arrays(50.0, f["edge_mm"], refine_top=4.0)
    p1 = fem.sphere_press(vertices, tets, young=10e3, poisson=0.45, order=1, sphere_radius=0.05, depth=0.002,
                          fixed=lambda x: fem.clamped_below(x, -0.04))
    assert p1.force > f["p2_force_N"] > 0.2  # P1 locks at nu 0.45: stiffer than the P2 reference
    a = (0.025 * 0.002) ** 0.5
    assert f["hertz_force_N"] == pytest.approx(4 / 3 * 10e3 / (1 - 0.45**2) * 0.025**0.5 * 0.002**1.5)
    assert f["hertz_contact_radius_mm"] == pytest.approx(a * 1e3)
    glob = next(r for r in f["rows"] if r["rings"] == "global")
    assert glob["force_N"] == pytest.approx(f["p2_force_N"], rel=0.08)  # calibration: 0.94-0.975 of P2
    assert glob["error_vs_fem_pct"] == pytest.approx(100 * (glob["force_N"] / f["p2_force_N"] - 1))
    assert glob["error_vs_global_pct"] == 0.0
    local = [r for r in f["rows"] if r["rings"] != "global"]
    assert [abs(r["error_vs_global_pct"]) for r in local] == sorted((abs(r["error_vs_global_pct"]) for r in local), reverse=True)
    assert f"| global | {glob['region_vertices']} | {glob['force_N']:.4f} |" in md


def test_depth_layers_detect_the_springs_failure_and_hold_the_neo_hookean_law(quick):
    """The known answers of issue 22 against the section's neo-Hookean FEM of the same tets: a deep press
    (a sphere R 10 mm 10 mm into a ball R 25 mm) gives the springs law far less than the FEM, with tets
    inverted; the neo-Hookean law holds several times more, none inverted; a stiff lesion raises the
    force (the FEM's ratio above 1), the neo-Hookean law's within 10% of that; the summary and results.md
    say which law misses what."""
    _, results, md, _ = quick
    d = results["depth_layers"]
    cases = {c["case"]: c for c in d["cases"]}
    assert set(cases) == {"slab", "deep", "lesion"}
    deep = cases["deep"]
    assert (deep["sphere_mm"], deep["depth_mm"]) == (10.0, 10.0) and deep["fem_N"] > 1.0  # about 1.45 N
    springs, neo = deep["laws"]["springs"], deep["laws"]["neo-hookean"]
    assert springs["of_fem"] < 0.5 and springs["inverted_tets"] > 0  # measured 0.20, 28 inverted
    assert neo["of_fem"] > 0.7 and neo["of_fem"] > 3 * springs["of_fem"] and neo["inverted_tets"] == 0  # measured 0.82
    assert "deep" in d["summary"]["springs"]["misses"]
    assert "- **springs**: misses slab, deep" in md
    assert f"springs misses slab, deep, lesion (deep press {springs['of_fem']:.2f} of the FEM" in md  # the summary's point
    assert cases["lesion"]["fem_ratio"] > 1.2  # E x5 under the probe: measured 1.50
    assert cases["lesion"]["laws"]["neo-hookean"]["ratio_of_fem"] == pytest.approx(1.0, abs=0.10)  # measured 0.93


@pytest.mark.parametrize("law", list(LAWS))
def test_every_registered_law_is_in_the_depth_layers_section(quick, law):
    """Every law of tissue.laws.LAWS: a cell in each case, its local regions and global model on the deep press
    (the speed-accuracy figure's points; the global model against itself exact), a column of results.md."""
    _, results, md, _ = quick
    d = results["depth_layers"]
    assert law in d["laws"] and law in d["summary"]
    for case in d["cases"]:
        assert law in case["laws"]
    rows = [r for r in d["regions"] if r["law"] == law]
    assert [r["rings"] for r in rows] == [*SETTINGS["quick"].depth.rings, "global"]
    glob = rows[-1]
    if "error" not in glob:
        assert glob["error_vs_global_pct"] == 0.0 and glob["step_us"] > 0
        assert glob["force_N"] == pytest.approx((1 + glob["error_vs_fem_pct"] / 100) * next(c for c in d["cases"] if c["case"] == "deep")["fem_N"])
    header = next(line for line in md.splitlines() if line.startswith("| case | vertices / tets | FEM |"))
    assert f" {law} |" in header
    assert f"- **{law}**: " in md


def _press(displacement, release_step, depth=0.01, dt=1e-3):
    return PressResult(vertex=0, depth=depth, dt=dt, release_step=release_step, force=np.zeros(len(displacement)), displacement=np.asarray(displacement))


def test_classify_against_closed_form_motions():
    t = np.arange(0, 0.6, 1e-3)
    rel = 100
    after = t[rel:] - t[rel]
    w = 2 * math.pi * 20.0
    damped = 0.01 * np.abs(np.exp(-30.0 * after) * np.cos(w * after))  # a damped oscillator: settles
    undamped = 0.01 * np.abs(np.cos(w * after))  # swings for ever
    dent = np.full(len(after), 0.004)  # rests away from rest
    drift = 0.004 + 0.02 * after  # drifts away, no swing
    head = np.full(rel, 0.01)
    assert classify(_press(np.r_[head, damped], rel)) == STABLE
    assert classify(_press(np.r_[head, undamped], rel)) == OSCILLATING
    assert classify(_press(np.r_[head, dent], rel)) == NOT_RECOVERED
    assert classify(_press(np.r_[head, drift], rel)) == NOT_RECOVERED


def test_extra_points_format_and_errors(tmp_path):
    good = tmp_path / "rows.json"
    good.write_text(json.dumps([{"scene": "liver", "integrator": "implicit", "rings": "global", "step_us": 40.0, "device": "cuda:0"}]))
    points = read_extra_points(good)
    assert points == [{"scene": "liver", "integrator": "implicit", "rings": "global", "step_us": 40.0, "device": "cuda:0"}]
    rows = [{"scene": "liver", "integrator": "implicit", "rings": "global", "device": "cpu", "step_us": 900.0, "disp_error_mm": 0.0}]
    assert join_extra_points(points, rows) == [{**rows[0], "step_us": 40.0, "device": "cuda:0"}]
    for bad in ('{"rows": 3}', "[1]", '[{"rings": 4}]', '[{"rings": 4, "mesh": "x", "step_us": -1}]', "not json"):
        (tmp_path / "bad.json").write_text(bad)
        with pytest.raises(InputError, match="bad.json"):
            read_extra_points(tmp_path / "bad.json")


def test_bad_input_is_one_line_exit_2_and_writes_nothing(tmp_path, capsys):
    (tmp_path / "bad.json").write_text('{"single": [{"mesh": "stomach"}]}')
    for args, words in (
        (["evaluate", "--quick", "--out", str(tmp_path / "missing")], "no such folder"),
        (["evaluate", "--quick", "--out", str(tmp_path), "--extra-json", str(tmp_path / "bad.json")], "row 0 needs"),
        (["evaluate", "--quick", "--out", str(tmp_path), "--extra-json", str(tmp_path / "none.json")], "cannot read"),
        (["evaluate", "--quick", "--out", str(tmp_path), "--device", "tpu:3"], "unknown device"),
    ):
        code = main(args)
        err = capsys.readouterr().err
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, (args, err)
        assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.json"]


def test_hold_press_errors_against_the_global_reference(device):
    """The speed-accuracy measurement on each device: the global model against itself is exact, and
    the error of a local model falls with its rings (anchors damp the deformation within a few rings)
    and stays inside its region's reach: outside the region nothing moves, so the largest
    displacement error is at most the global model's largest displacement outside the region."""
    from almsdm_warp.evaluation.common import hold_press, top_vertex
    from almsdm_warp.evaluation.common import shipped_scene
    from almsdm_warp.protocol.palpation import Palpation

    scene, mesh = shipped_scene("paper_stomach")  # the paper's anchors: the figures below are theirs
    v = top_vertex(mesh)
    glob = Palpation(mesh, scene.tissue, rings="global", integrator="explicit", device=device)
    glob.touch(v)
    f_ref, peak_ref, q_ref, force, target = hold_press(glob, hold=0.1)
    assert target[-1] == pytest.approx(0.01) and force[-1] == f_ref and peak_ref == force.max()
    rest = mesh.vertices
    errors = []
    for rings in (1, 2, 4):
        pal = Palpation(mesh, scene.tissue, rings=rings, integrator="explicit", device=device)
        pal.touch(v)
        _, peak, q, _, _ = hold_press(pal, hold=0.1)
        inside = np.zeros(mesh.vertex_count, bool)
        inside[pal.region.vertices()] = True
        np.testing.assert_allclose(q[~inside], rest[~inside].astype(np.float32), atol=1e-7)  # untouched outside
        err = np.linalg.norm(q - q_ref, axis=1)
        outside_ref = np.linalg.norm(q_ref - rest, axis=1)[~inside].max()
        assert err[~inside].max() == pytest.approx(outside_ref, abs=1e-6)
        errors.append((abs(peak - peak_ref), err.max()))
    assert errors[0][0] > errors[1][0] > errors[2][0] and errors[0][1] > errors[1][1] > errors[2][1]
    assert errors[2][0] < 1e-3 * peak_ref and errors[2][1] < 1e-4  # 4 rings: within 0.1% and 0.1 mm
