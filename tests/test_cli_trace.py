"""`almsdm trace`: the trace's columns and units against the path it was given, the local region
against the global model on a short stroke, bad path files (exit 2, nothing written), outputs
written whole or not at all, and the coupling's flags. CPU, strokes of a tenth of a second."""

import json

import numpy as np
import pytest
from conftest import SCENES

from almsdm_warp.cli.main import main
from almsdm_warp.cli.trace import COLUMNS, DEVICE_COLUMNS, read_path, resample
from almsdm_warp.errors import InputError

R_MM = 10.0
# the tests that read forces press paper_stomach (the paper's constants: about 1 N at these presses),
# the shipped stomach's soft material gives a few hundredths of a newton


@pytest.fixture(scope="module")
def top_mm():
    """The stomach's top vertex [mm] (where a press from above lands)."""
    from almsdm_warp.region.contact import top_vertex
    from almsdm_warp.scene.loader import load_scene

    mesh = load_scene(SCENES / "stomach.toml").load_mesh()
    return mesh.vertices[top_vertex(mesh)] * 1e3


def write_path(path, rows):
    path.write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(",".join(repr(float(v)) for v in r) + "\n" for r in rows))
    return path


def press_and_slide(top, depth=4.0, slide=3.0):
    """Touch down above `top` [mm], press `depth` mm in 0.06 s, slide `slide` mm along x in 0.04 s."""
    c = np.asarray(top) + [0.0, 0.0, R_MM]
    return [(0.0, *c), (0.06, *(c - [0, 0, depth])), (0.1, *(c - [-slide, 0, depth]))]


def read_csv(path):
    with open(path) as f:
        header = f.readline().strip().split(",")
    return header, np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)


def test_the_trace_holds_the_path_at_each_step_and_the_force_in_newtons(tmp_path, top_mm, capsys):
    rows = press_and_slide(top_mm)
    path, out, js = write_path(tmp_path / "p.csv", rows), tmp_path / "t.csv", tmp_path / "t.json"
    assert main(["trace", "paper_stomach", "--path", str(path), "--out", str(out), "--json", str(js), "--report-every", "7",
                 "--probe-radius-mm", str(R_MM)]) == 0
    header, data = read_csv(out)
    assert header == list(COLUMNS)
    t = data[:, 0]
    np.testing.assert_allclose(t * 1e3, sorted(set(range(0, 101, 7)) | {100}), atol=1e-6)  # 1 ms steps, every 7th and the last
    want = np.column_stack([np.interp(t, [r[0] for r in rows], [r[k] for r in rows]) for k in (1, 2, 3)])
    np.testing.assert_allclose(data[:, 1:4], want, atol=1e-9)  # millimetres, the path interpolated
    f = data[:, 4:7]
    assert np.all(f[0] == 0.0) or np.abs(f[0]).max() < 1e-6  # touching, not pressing
    k = int(np.argmin(np.abs(t - 0.063)))
    assert 0.5 < f[k, 2] < 5.0  # newtons: pressed 4 mm from above, the tissue pushes the sphere up
    assert np.all(data[:, 7] > 10) and np.all(data[:, 7] == np.round(data[:, 7]))  # region vertices, an integer
    assert data[-1, 8] >= 0 and np.all(np.diff(data[:, 8]) >= 0)  # relocations, counted up
    record = json.loads(js.read_text())
    assert record["rows"] == len(t) and record["relocations"] == int(data[-1, 8])
    assert record["peak_force_N"] == pytest.approx(np.linalg.norm(f, axis=1).max(), rel=1e-6)


def test_local_and_global_models_give_close_forces_on_a_short_stroke(tmp_path, top_mm):
    path = write_path(tmp_path / "p.csv", press_and_slide(top_mm, depth=5.0, slide=4.0))
    forces = {}
    for rings in ("4", "global"):
        out = tmp_path / f"{rings}.csv"
        assert main(["trace", "paper_stomach", "--path", str(path), "--out", str(out), "--rings", rings, "--probe-radius-mm", str(R_MM)]) == 0
        forces[rings] = read_csv(out)[1][:, 4:7]
    local, ref = forces["4"], forces["global"]
    peak = np.linalg.norm(ref, axis=1).max()
    assert peak > 0.5
    assert np.abs(local - ref).max() < 0.05 * peak  # the cost of being local, within 5% of the peak


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "empty file (0 bytes)"),
        ("t,x,y,z\n0,0,0,0\n1,0,0,0\n", "line 1: the header must be t_s,x_mm,y_mm,z_mm"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n", "at least 2 rows, got 1"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n1,0,0\n", "line 3: 3 values, expected 4"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n1,0,abc,0\n", "line 3: not a number: 'abc'"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n1,nan,0,0\n", "line 3: x_mm must be finite"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n2,0,0,0\n1,0,0,0\n", "line 4: t_s must increase, got 1.0 after 2.0"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n0,1,0,0\n", "line 3: t_s must increase, got 0.0 after 0.0"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,1e300\n1,0,0,0\n", "line 2: the point [0.0, 0.0, 1e+300] mm is more than 1e+06 mm"),
        ("t_s,x_mm,y_mm,z_mm\n0,0,0,0\n0.0005,0,0,0\n", "lasts 0.0005 s, less than one step of --dt-ms 1"),
    ],
)
def test_a_bad_path_file_is_one_line_and_exit_2_with_nothing_written(tmp_path, capsys, text, message):
    path = tmp_path / "p.csv"
    path.write_text(text)
    out = tmp_path / "out"
    out.mkdir()
    assert main(["trace", "--path", str(path), "--out", str(out / "t.csv"), "--png", str(out / "t.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and "Traceback" not in err
    assert list(out.iterdir()) == []


def test_a_path_file_that_is_not_there_or_not_text_is_exit_2(tmp_path, capsys):
    assert main(["trace", "--path", str(tmp_path / "none.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "bin.csv").write_bytes(b"\xff\xfe\x00")
    assert main(["trace", "--path", str(tmp_path / "bin.csv")]) == 2
    assert "not a text file" in capsys.readouterr().err


def test_a_path_file_is_read_in_metres_its_comments_and_blank_lines_skipped(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("# a stroke\nt_s, x_mm, y_mm, z_mm\n\n0.5,1,2,3\n0.75,-4,5.5,6e1\n")
    t, c = read_path(path)
    np.testing.assert_array_equal(t, [0.5, 0.75])
    np.testing.assert_allclose(c, [[1e-3, 2e-3, 3e-3], [-4e-3, 5.5e-3, 60e-3]])


def test_resample_takes_each_step_and_the_last_time():
    t, c = np.array([0.0, 0.0025]), np.array([[0.0, 0.0, 0.0], [0.0025, 0.0, -0.005]])
    times, centres = resample(t, c, 1e-3)
    np.testing.assert_allclose(times, [0.0, 1e-3, 2e-3, 2.5e-3])
    np.testing.assert_allclose(centres[:, 0], times)  # x = t
    np.testing.assert_allclose(centres[:, 2], -2 * times)
    with pytest.raises(InputError, match="more than 10,000,000"):
        resample(np.array([0.0, 1e5]), c, 1e-3)


def test_every_output_written_whole_and_none_left_from_a_run_that_fails(tmp_path, top_mm, capsys, monkeypatch):
    path = write_path(tmp_path / "p.csv", press_and_slide(top_mm))
    out = tmp_path / "out"
    out.mkdir()
    files = {"--out": out / "t.csv", "--png": out / "t.png", "--usd": out / "t.usda", "--json": out / "t.json"}
    args = ["trace", "--path", str(path), "--probe-radius-mm", str(R_MM), "--usd-every", "20"]
    for flag, p in files.items():
        args += [flag, str(p)]
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in files.values())  # no temporary left

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(files["--usd"]))
    probe = UsdGeom.Sphere(stage.GetPrimAtPath("/Palpation/Probe"))
    op = probe.GetOrderedXformOps()[0]
    assert op.GetTimeSamples() == [0.0, 20.0, 40.0, 60.0, 80.0, 100.0]
    rows = press_and_slide(top_mm)
    np.testing.assert_allclose(op.Get(0.0), rows[0][1:], atol=1e-4)  # the sphere's centre on its path, in mm
    np.testing.assert_allclose(op.Get(100.0), rows[2][1:], atol=1e-4)
    assert probe.GetRadiusAttr().Get() == pytest.approx(R_MM)
    data = stage.GetPrimAtPath("/Palpation").GetCustomData()
    assert data["probe"] == "stroke" and "contact_vertex" not in data  # no one vertex for a stroke: the path is the Probe's

    # a run that fails half way leaves no file and no temporary
    from almsdm_warp.solvers.stepper import SimulationDiverged
    from almsdm_warp.protocol.stroke import ProbeStroke

    for p in files.values():
        p.unlink()
    calls = []
    real = ProbeStroke.step

    def failing(self, centres):
        calls.append(1)
        if len(calls) > 30:
            raise SimulationDiverged("the explicit integrator diverged (a test)")
        return real(self, centres)

    monkeypatch.setattr(ProbeStroke, "step", failing)
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "at t = 0.03 s" in err and "diverged" in err and err.count("\n") == 1
    assert list(out.iterdir()) == []


def test_coupling_flags(tmp_path, top_mm, capsys):
    path = write_path(tmp_path / "p.csv", press_and_slide(top_mm))
    base = ["trace", "paper_stomach", "--path", str(path), "--probe-radius-mm", str(R_MM)]
    assert main([*base, "--coupling-stiffness-n-per-mm", "1"]) == 2
    assert "needs --device-damping-ns-per-m" in capsys.readouterr().err
    assert main([*base, "--coupling-stiffness-n-per-mm", "1", "--device-damping-ns-per-m", "0.4"]) == 2
    assert "not passive at T 1 ms" in capsys.readouterr().err  # b 0.4 <= k_c T / 2 = 0.5 N s/m
    out = tmp_path / "c.csv"
    assert main([*base, "--coupling-stiffness-n-per-mm", "0.5", "--coupling-damping-ns-per-m", "0.05",
                 "--device-damping-ns-per-m", "0.4", "--out", str(out)]) == 0
    header, data = read_csv(out)
    assert header == [*COLUMNS, *DEVICE_COLUMNS]
    device, tool, felt = data[:, 9:12], data[:, 1:4], data[:, 4:7]
    rows = press_and_slide(top_mm)
    want = np.column_stack([np.interp(data[:, 0], [r[0] for r in rows], [r[k] for r in rows]) for k in (1, 2, 3)])
    np.testing.assert_allclose(device, want, atol=1e-9)
    # the force sent to the device is the coupling spring-damper's: k_c (x_t - x_d) + b_c (v_t - v_d);
    # at the end of the slide (both moving at the path's speed) the spring's part dominates
    spring = 0.5 * (tool[-1] - device[-1])  # N/mm x mm
    np.testing.assert_allclose(felt[-1], spring, atol=0.15 * np.abs(spring).max() + 0.02)
    assert felt[-1, 2] > 0.3  # the tool rides above the device: the tissue holds it up


BAD_FLAGS = {
    "--rings global-free": "unknown value 'global-free'",
    "--probe-radius-mm 0": "--probe-radius-mm must be > 0",
    "--usd t.txt": "unknown USD suffix",
    "--out t.json": "unknown table suffix",
    "--coupling-damping-ns-per-m 1": "need --coupling-stiffness-n-per-mm",
    "--dt-ms 1e-308": "--dt-ms: must be 0 or of magnitude 1e-12 to 1e+12, got 1e-308",
    "--dt-ms 1e-9": "the built-in stroke lasts 3.9 s: 3.9e+12 steps",
    "--youngs-modulus-kpa 1e300": "must be 0 or of magnitude 1e-12 to 1e+12, got 1e+300",
    "--rings 1000000": "--rings 1000000 is more than the mesh's 1002 vertices",
}
"""Flags a trace refuses -> what its one line says."""


@pytest.mark.parametrize("flags", list(BAD_FLAGS))
def test_bad_flags_are_one_line_and_exit_2(tmp_path, capsys, monkeypatch, flags):
    monkeypatch.chdir(tmp_path)
    message = BAD_FLAGS[flags]
    assert main(["trace", *flags.split()]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def test_a_lesion_under_the_stroke_shows_as_a_force_rise(tmp_path):
    # a stroke from 40 mm off the lesion of stomach_lesion.toml straight over it; the same path on
    # the plain stomach is the reference: the force rises over the lesion, and not where the
    # sphere's contact (about sqrt(2 R d) = 11 mm across) is clear of it
    from almsdm_warp.protocol.stroke import builtin_stroke
    from almsdm_warp.scene.loader import load_scene

    scene = load_scene(SCENES / "stomach_lesion.toml")
    mesh = scene.load_mesh()
    surface = mesh.surface_vertices
    x = mesh.vertices[surface]
    hit = x[np.argmin(np.linalg.norm(x - np.asarray(scene.lesion.center), axis=1))]
    start = surface[np.argmin(np.abs(np.linalg.norm(x - hit, axis=1) - 40e-3))]
    p = builtin_stroke(mesh, R_MM * 1e-3, depth=6e-3, length=50e-3, speed=50e-3, vertex=int(start),
                       direction=hit - mesh.vertices[start])
    path = write_path(tmp_path / "p.csv", np.column_stack([p.t, p.centre * 1e3]))
    force = {}
    for name in ("stomach_lesion", "stomach"):
        out = tmp_path / f"{name}.csv"
        assert main(["trace", name, "--path", str(path), "--out", str(out), "--probe-radius-mm", str(R_MM)]) == 0
        force[name] = np.linalg.norm(read_csv(out)[1][:, 4:7], axis=1)
    d = np.linalg.norm(p.centre - hit, axis=1)
    slide = p.phase == 1
    over, away = slide & (d < 10e-3), slide & (d > scene.lesion.radius + 12e-3)
    assert over.sum() > 10 and away.sum() > 10
    rise = force["stomach_lesion"][over].mean() / force["stomach"][over].mean()
    assert rise > 2.0  # 5x stiffer tissue under the sphere
    np.testing.assert_allclose(force["stomach_lesion"][away].mean(), force["stomach"][away].mean(), rtol=0.05)


def test_the_loop_leaves_the_heap_made_before_it_out_of_collections(tmp_path, top_mm, monkeypatch):
    # a collection of the oldest generations walks every object (1.2-1.5 ms measured on the stroke's loop,
    # one step's worth of a max): inside the loop the objects made before it are frozen, after it no longer
    import gc

    from almsdm_warp.protocol.stroke import ProbeStroke

    seen = []
    step = ProbeStroke.step
    monkeypatch.setattr(ProbeStroke, "step", lambda self, c: seen.append(gc.get_freeze_count()) or step(self, c))
    path = write_path(tmp_path / "p.csv", press_and_slide(top_mm))
    assert main(["trace", "paper_stomach", "--path", str(path), "--probe-radius-mm", str(R_MM), "--out", str(tmp_path / "t.csv")]) == 0
    assert len(seen) == 101 and min(seen) > 10_000  # the modules, Warp and the model: tens of thousands of objects
    assert gc.get_freeze_count() == 0
