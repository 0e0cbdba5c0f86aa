"""`almsdm palpate` (the default command): force, recovery and speed of presses, as JSON; bad input
as one line and exit code 2 with nothing written. CPU; no timing asserts."""

import io
import json
import math
import re

import pytest
from conftest import SHARED_MESHES
from test_cli import run_cli

from almsdm_warp.cli.main import main
from almsdm_warp.progress import Progress

_runs = {}


def palpate(tmp_path_factory, *args):
    """JSON of `almsdm palpate ARGS --json ...` (in-process), each distinct run once per session."""
    if args not in _runs:
        out = tmp_path_factory.mktemp("palpate") / "out.json"
        assert main(["palpate", *args, "--json", str(out)]) == 0
        _runs[args] = json.loads(out.read_text())
    return _runs[args]


SHORT = ("paper_stomach", "--settle-s", "0.3")  # the paper's preset: the figures below are its calibration's


def test_no_arguments_runs_palpate_on_the_default_stomach(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0].startswith("stomach.obj: ")
    assert "model: 1 ring around vertex" in out and "explicit integrator, dt 1 ms" in out  # the scene's [region] rings
    assert "press 1: peak force" in out and "steps/s" in out and "press 2:" not in out
    assert list(tmp_path.iterdir()) == []  # no --json: nothing written


def test_no_arguments_from_a_real_process(tmp_path):
    r = run_cli(cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stderr == ""  # no bar: stderr is not a terminal
    assert "press 1: peak force" in r.stdout and "us per step" in r.stdout


def test_json_keys_and_types(tmp_path_factory):
    data = palpate(tmp_path_factory, *SHORT)
    assert data["scene"].endswith("stomach.toml")
    assert data["device"] == "cpu"
    mesh = data["mesh"]
    assert mesh["path"].endswith("stomach.obj")
    assert all(isinstance(mesh[k], int) for k in ("vertices", "triangles", "tetrahedra", "edges"))
    assert mesh["tetrahedra"] == 0 and mesh["vertices"] > 0
    model = data["model"]
    assert model["rings"] == 4 and model["integrator"] == "explicit"
    assert isinstance(model["region_vertices"], int) and isinstance(model["region_springs"], int)
    assert 0 < model["free_vertices"] < model["region_vertices"] < mesh["vertices"]
    assert model["dt_s"] == pytest.approx(1e-3)
    assert isinstance(model["critical_dt_s"], float) and model["critical_dt_s"] > model["dt_s"]
    contact = data["contact"]
    assert isinstance(contact["vertex"], int) and len(contact["point_mm"]) == 3
    assert data["press"] == {"depth_mm": pytest.approx(10.0), "ramp_s": 0.1, "hold_s": 0.2, "settle_s": 0.3}
    (press,) = data["presses"]
    assert set(press) == {"peak_force_N", "hold_force_N", "inverted_tets", "recovery_error_mm", "recovery_time_s", "substeps",
                          "pressed_again", "ring_gap_mm"}
    assert press["inverted_tets"] is None  # a surface mesh: no tets to count
    assert press["substeps"] == data["model"]["substeps"] and press["pressed_again"] == 0  # not pressed again
    assert all(isinstance(v, float) for k, v in press.items() if k not in ("inverted_tets", "substeps", "pressed_again", "ring_gap_mm"))
    assert 0 < press["hold_force_N"] <= press["peak_force_N"] and model["law"] == "springs" and data["tissue"]["law"] == "springs"
    assert isinstance(data["step_us_median"], float) and data["step_us_median"] > 0
    assert data["steps_per_s"] == pytest.approx(1e6 / data["step_us_median"])
    assert isinstance(data["timing_steps"], int) and data["timing_steps"] > 0


def test_peak_force_of_a_10mm_press_with_4_rings(tmp_path_factory):
    data = palpate(tmp_path_factory, *SHORT)
    assert data["press"]["depth_mm"] == pytest.approx(10.0) and data["model"]["rings"] == 4
    assert 1.5 <= data["presses"][0]["peak_force_N"] <= 3.5


def test_explicit_and_implicit_agree_on_peak_force(tmp_path_factory):
    explicit = palpate(tmp_path_factory, *SHORT)["presses"][0]["peak_force_N"]
    implicit = palpate(tmp_path_factory, *SHORT, "--integrator", "implicit")["presses"][0]["peak_force_N"]
    assert implicit == pytest.approx(explicit, rel=0.05)


def test_global_free_recovers_worse_than_4_rings(tmp_path_factory):
    local = palpate(tmp_path_factory, *SHORT)
    free = palpate(tmp_path_factory, *SHORT, "--rings", "global-free")
    assert free["model"]["rings"] == "global-free"
    assert free["model"]["region_vertices"] == free["mesh"]["vertices"]
    assert free["presses"][0]["recovery_error_mm"] > local["presses"][0]["recovery_error_mm"]
    # it never settles: an infinite recovery time is written as null
    assert free["presses"][0]["recovery_time_s"] is None


def test_three_presses_give_three_entries(tmp_path_factory, capsys):
    data = palpate(tmp_path_factory, *SHORT, "--presses", "3")
    assert len(data["presses"]) == 3
    assert all(math.isfinite(p["peak_force_N"]) for p in data["presses"])


def test_protocol_flags_override_the_scene(tmp_path_factory):
    data = palpate(tmp_path_factory, "--depth-mm", "5", "--ramp-s", "0.05", "--hold-s", "0", "--settle-s", "0.2", "--dt-ms", "0.5")
    assert data["press"] == {"depth_mm": pytest.approx(5.0), "ramp_s": 0.05, "hold_s": 0.0, "settle_s": 0.2}
    assert data["model"]["dt_s"] == pytest.approx(5e-4)
    assert data["presses"][0]["peak_force_N"] < palpate(tmp_path_factory, *SHORT)["presses"][0]["peak_force_N"]


def test_contact_by_probe_and_by_vertex(tmp_path_factory):
    top = palpate(tmp_path_factory, *SHORT)["contact"]
    above = [top["point_mm"][0], top["point_mm"][1], top["point_mm"][2] + 5.0]
    probed = palpate(tmp_path_factory, *SHORT, "--probe-mm", *map(str, above))["contact"]
    assert probed["vertex"] == top["vertex"]
    assert probed["distance_mm"] == pytest.approx(5.0, abs=0.5)
    other = palpate(tmp_path_factory, *SHORT, "--vertex", "0")
    assert other["contact"]["vertex"] == 0 and other["presses"][0]["peak_force_N"] > 0


def test_a_scene_name_without_the_command(tmp_path, capsys):
    out = tmp_path / "liver.json"
    assert main(["liver", "--settle-s", "0.2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["scene"].endswith("liver.toml") and data["mesh"]["tetrahedra"] > 0
    # a tet law's model line names its tets, not the springs it has none of
    tets = data["model"]["region_tets"]
    assert isinstance(tets, int) and 0 < tets <= data["mesh"]["tetrahedra"]
    assert f"{tets} tets (neo-hookean)" in capsys.readouterr().out


def test_a_tet_law_counts_the_tets_its_region_integrates():
    # against the law's own entries: the distinct tets among the free vertices' incident tets
    import numpy as np

    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.scene.loader import default_scene_path, load_scene

    scene = load_scene(default_scene_path("liver"))
    mesh = scene.load_mesh()
    top = int(np.argmax(mesh.vertices[:, 2]))
    for law in ("neo-hookean", "springs"):
        pal = Palpation(mesh, scene.tissue, rings=2, fixed_below=scene.fixed_below, device="cpu", law=law)
        pal.touch(top)
        if law == "springs":
            assert pal.region_tets is None
            continue
        free = pal.solver.free_vertex.numpy()[: pal.solver.free_count]
        offsets, topology = pal.model.entry_offsets.numpy(), pal.model.entry_topology.numpy()
        tets = {tuple(sorted(topology[k])) for v in free for k in range(offsets[v], offsets[v + 1])}
        assert pal.region_tets == len(tets) > 20


def test_a_shared_mesh_file_takes_default_tissue(tmp_path, capsys):
    path = SHARED_MESHES / "sofa_liver2_tets.vtu"
    if not path.exists():
        pytest.skip(f"{path} absent")
    out = tmp_path / "out.json"
    # the file is in decimetres (2.1 units long); at 0.5 ms the explicit scheme is stable on it
    args = [str(path), "--scale-mm", "100", "--dt-ms", "0.5", "--rings", "2", "--settle-s", "0.2"]
    assert main(["palpate", *args, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["scene"] is None and data["model"]["rings"] == 2 and data["mesh"]["tetrahedra"] == 1493
    assert data["presses"][0]["peak_force_N"] > 0


def test_explicit_past_its_critical_step_substeps(tmp_path_factory):
    """dt 5 ms is about 3 x the region's critical step: the explicit integrator takes the frame in
    substeps of under 0.9 x that step and its force agrees with the implicit integrator's at 5 ms."""
    data = palpate(tmp_path_factory, *SHORT, "--integrator", "explicit", "--dt-ms", "5")
    model = data["model"]
    assert model["substeps"] == math.ceil(model["dt_s"] / (0.9 * model["critical_dt_s"])) >= 2
    implicit = palpate(tmp_path_factory, *SHORT, "--integrator", "implicit", "--dt-ms", "5")
    assert implicit["model"]["substeps"] == 1
    assert math.isclose(data["presses"][0]["peak_force_N"], implicit["presses"][0]["peak_force_N"], rel_tol=0.05)


def test_substeps_said_from_a_real_process(tmp_path):
    r = run_cli("palpate", *SHORT, "--integrator", "explicit", "--dt-ms", "5")
    assert r.returncode == 0, r.stderr
    assert re.search(r"explicit integrator, dt 5 ms in \d+ substeps of [\d.]+ ms \(explicit critical step", r.stdout), r.stdout


def test_implicit_is_stable_where_explicit_diverges(tmp_path_factory):
    data = palpate(tmp_path_factory, *SHORT, "--integrator", "implicit", "--dt-ms", "5")
    assert data["model"]["dt_s"] > data["model"]["critical_dt_s"]
    assert 1.5 <= data["presses"][0]["peak_force_N"] <= 3.5


@pytest.mark.parametrize(
    "args, message",
    [
        (["--rings", "glob"], "allowed: an integer >= 1, 'auto', 'global' or 'global-free'"),
        (["--rings", "0"], "must be >= 1"),
        (["--rings", "-2"], "must be >= 1"),
        (["--presses", "0"], "--presses: must be >= 1"),
        (["--presses", "two"], "not an integer"),
        (["--dt-ms", "0"], "--dt-ms: must be > 0"),
        (["--dt-ms", "-1"], "--dt-ms: must be > 0"),
        (["--dt-ms", "nan"], "--dt-ms: must be finite"),
        (["--dt-ms", "inf"], "--dt-ms: must be finite"),
        (["--depth", "0"], "must be > 0"),
        (["--depth-mm", "-5"], "must be > 0"),
        (["--depth-mm", "nan"], "must be finite"),
        (["--ramp-s", "-0.1"], "--ramp-s: must be >= 0"),
        (["--hold-s", "-1"], "--hold-s: must be >= 0"),
        (["--settle-s", "-1"], "--settle-s: must be >= 0"),
        (["--integrator", "rk4"], "invalid choice"),
        (["--device", "tpu:7"], "unknown device"),
        (["no/such/mesh.obj"], "no such file"),
        (["--vertex", "100000"], "outside the mesh"),
        (["--probe-mm", "nan", "0", "0"], "--probe-mm must be finite"),
        (["--vertex", "0", "--probe-mm", "0", "0", "0"], "not allowed with"),
        (["--scale-mm", "10"], "--scale-mm is for a mesh file"),
        (["--scale-mm", "0"], "--scale-mm: must be > 0"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_no_file(args, message, tmp_path, capsys):
    out = tmp_path / "out.json"
    assert main(["palpate", *args, "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert err.startswith("almsdm: error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_unwritable_json_is_found_before_running(tmp_path, capsys):
    assert main(["palpate", "--json", str(tmp_path / "no" / "such" / "out.json")]) == 2
    captured = capsys.readouterr()
    assert "does not exist" in captured.err and captured.err.count("\n") == 1
    assert captured.out == ""  # nothing ran
    assert list(tmp_path.iterdir()) == []


def test_broken_mesh_exits_2_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    out = tmp_path / "out.json"
    assert main(["palpate", str(bad), "--json", str(out)]) == 2
    err = capsys.readouterr().err
    assert "broken.obj" in err and err.count("\n") == 1 and "Traceback" not in err
    assert list(tmp_path.iterdir()) == [bad]


def test_bad_input_from_a_real_process(tmp_path):
    out = tmp_path / "out.json"
    r = run_cli("palpate", "--rings", "everything", "--json", str(out), cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "'global-free'" in r.stderr and "Traceback" not in r.stderr
    assert r.stdout == "" and list(tmp_path.iterdir()) == []


def test_touch_is_still_a_command_and_unknown_commands_are_errors(capsys):
    assert main(["touch", "--rings", "1"]) == 0
    assert "region at vertex" in capsys.readouterr().out
    assert main(["frobnicate"]) == 2
    assert "invalid choice" in capsys.readouterr().err


def test_no_bar_for_a_short_run_even_when_forced(capsys):
    assert main(["--settle-s", "0.2", "--progress"]) == 0
    assert capsys.readouterr().err == ""


def test_progress_bar_draws_and_ends_its_line():
    stream = io.StringIO()
    with Progress(1000, enabled=True, stream=stream, label="press 1/1", min_expected_s=0.0, interval_s=0.0) as bar:
        for _ in range(1000):
            bar.advance()
            if bar.done == 1:
                import time

                time.sleep(0.3)  # past the 0.25 s it waits for a stable rate
    text = stream.getvalue()
    assert text.startswith("\rpress 1/1 [") and "100%" in text and text.endswith("\n")
    assert "\n" not in text[:-1]  # one line, redrawn with carriage returns
    silent = io.StringIO()
    with Progress(10, stream=silent) as bar:  # not a terminal, not forced: nothing
        for _ in range(10):
            bar.advance()
    assert silent.getvalue() == ""


def test_json_output_gets_the_mode_of_a_new_file(tmp_path):
    # written through a private temporary file, published with the umask's mode (not owner-only)
    import os

    from almsdm_warp.export.output import write_json

    out = write_json(tmp_path / "r.json", {"a": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert (out.stat().st_mode & 0o777) == (0o666 & ~mask)


def test_palpate_feels_the_lesion_of_a_lesion_scene(tmp_path_factory):
    # the same press at the lesion's centre: every spring and anchor there is stiffer (x5 inside the
    # sphere), so the force grows, by at most the factor (the static force is linear in a common scale)
    args = ("--probe-mm", "-27", "56", "0", "--integrator", "implicit", "--settle-s", "0.3")
    plain = palpate(tmp_path_factory, "stomach", *args)
    hard = palpate(tmp_path_factory, "stomach_lesion", *args)
    assert plain["contact"]["vertex"] == hard["contact"]["vertex"]
    ratio = hard["presses"][0]["peak_force_N"] / plain["presses"][0]["peak_force_N"]
    assert 2.0 < ratio <= 5.0 * 1.05


def _auto_scene(tmp_path, tol_line="tol_mm = 0.03\n"):
    from conftest import SCENES

    text = (SCENES / "paper_stomach.toml").read_text()  # auto rings size a one-vertex probe's region
    text = text.replace('path = "stomach.obj"', f"path = {str(SCENES / 'stomach.obj')!r}")
    text = text.replace("\nrings = 4 ", f'\nrings = "auto"\n{tol_line}# was: rings = 4 ')
    path = tmp_path / "auto.toml"
    path.write_text(text)
    return str(path)


def test_auto_rings_from_a_scene_are_the_flags(tmp_path_factory):
    # [region] rings = "auto", tol_mm = T in a scene runs exactly as --rings auto --tol-mm T
    short = ("--ramp-s", "0.05", "--hold-s", "0.1", "--settle-s", "0.05", "--dt-ms", "0.5")
    scene = _auto_scene(tmp_path_factory.mktemp("scene"))
    by_scene = palpate(tmp_path_factory, scene, *short)
    by_flags = palpate(tmp_path_factory, "paper_stomach", "--rings", "auto", "--tol-mm", "0.03", *short)
    assert by_scene["model"]["rings"] == "auto" and by_scene["model"]["tol_mm"] == pytest.approx(0.03)
    assert by_scene["model"]["rings_chosen"] == by_flags["model"]["rings_chosen"] >= 3  # docs/adaptive.md: 4, 4, 3
    for key in ("rings_chosen", "auto_reason", "auto_events", "region_vertices"):
        assert by_scene["model"][key] == by_flags["model"][key], key
    assert by_scene["presses"] == by_flags["presses"]  # the same bits
    # flags override the scene: a fixed ring count drops its tol_mm; --tol-mm replaces it
    fixed = palpate(tmp_path_factory, scene, "--rings", "2", *short)
    assert fixed["model"]["rings"] == 2 and "tol_mm" not in fixed["model"]
    assert fixed["presses"] == palpate(tmp_path_factory, "paper_stomach", "--rings", "2", *short)["presses"]
    loose = palpate(tmp_path_factory, scene, "--tol-mm", "1", *short)
    assert loose["model"]["tol_mm"] == 1.0 and loose["model"]["rings_chosen"] < by_scene["model"]["rings_chosen"]


def test_auto_scene_without_tol_takes_the_default_and_tol_needs_auto(tmp_path, capsys):
    from almsdm_warp.cli.palpate import AUTO_TOL_MM

    scene = _auto_scene(tmp_path, "")
    out = tmp_path / "o.json"
    assert main(["palpate", scene, "--ramp-s", "0.05", "--hold-s", "0", "--settle-s", "0.05", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["model"]["tol_mm"] == AUTO_TOL_MM
    capsys.readouterr()
    out.unlink()
    assert main(["palpate", "--tol-mm", "0.1", "--json", str(out)]) == 2  # the stomach scene's rings = 1
    err = capsys.readouterr().err
    assert "--tol-mm is for --rings auto" in err and "the scene's [region] rings = 1" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
    assert main(["touch", scene]) == 0  # touch sizes an auto region as palpate does
    assert "auto rings:" in capsys.readouterr().out
