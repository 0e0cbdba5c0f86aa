"""The surfaces of issue 24 under hostile input: trace paths, dataset specs, material and probe
magnitudes, the Python facade's arguments, interrupted and damaged outputs. Every case ends in a sane
result or one clear line (exit 2, nothing left behind) / a ValueError naming the argument; the
campaign with many more cases in fresh processes is scripts/fuzz_surfaces.py (docs/reliability.md)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from almsdm_warp.batch import dataset as ds
from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
from almsdm_warp.batch.sweep_store import Parts, file_sha256
from almsdm_warp.cli import trace
from almsdm_warp.cli.main import main
from almsdm_warp.errors import InputError
from almsdm_warp.export.output import atomic_write_text
from almsdm_warp.mesh import primitives
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.protocol.schedule import check_press
from almsdm_warp.protocol.stroke import ProbeStroke
from almsdm_warp.sim.model import PROBE_DISPLACEMENT
from almsdm_warp.solvers.stepper import SimulationDiverged
from almsdm_warp.tissue.material import Material
from almsdm_warp.tissue.params import TissueParams
from conftest import ROOT

R = 10e-3


def one_line(capsys, code, words=""):
    """The command ended with exit 2 and exactly one line 'almsdm: error: ...' holding `words`."""
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("almsdm: error: ") and words in err, err
    return err


# -- trace: its path file --------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["fifo", "dev_zero", "folder", "rows", "bytes"])
def test_a_path_that_is_no_bounded_regular_file_is_one_line(tmp_path, capsys, monkeypatch, kind):
    path = tmp_path / "p.csv"
    if kind == "fifo":
        os.mkfifo(path)  # read without a bound this blocked for ever
    elif kind == "dev_zero":
        path.symlink_to("/dev/zero")  # this read 6 GB in 37 s
    elif kind == "folder":
        path.mkdir()
    elif kind == "rows":
        monkeypatch.setattr(trace, "MAX_PATH_ROWS", 10)
        path.write_text("t_s,x_mm,y_mm,z_mm\n" + "".join(f"{i},0,0,100\n" for i in range(12)))
    else:
        monkeypatch.setattr(trace, "MAX_PATH_BYTES", 100)
        path.write_text("t_s,x_mm,y_mm,z_mm\n" + "0,0,0,100\n" * 20)
    words = {"fifo": "FIFO", "dev_zero": "character device", "folder": "directory", "rows": "more than 10 rows",
             "bytes": "more than the 100 bytes"}[kind]
    one_line(capsys, main(["trace", "--path", str(path), "--out", str(tmp_path / "t.csv")]), words)
    assert not (tmp_path / "t.csv").exists()


def top_path(mesh_top, start=2.0, depth=5.0, seconds=0.05, n=3):
    x, y, z = mesh_top
    return "t_s,x_mm,y_mm,z_mm\n" + "".join(
        f"{seconds * i / (n - 1)!r},{x!r},{y!r},{z + 10.0 + start - (start + depth) * i / (n - 1)!r}\n" for i in range(n))


@pytest.fixture(scope="module")
def stomach_top():
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    v = resolve_scene_or_mesh("stomach").load_mesh().vertices * 1e3
    return [float(c) for c in v[np.argmax(v[:, 2])]], float(v[:, 2].min())


def test_a_path_through_the_organ_in_one_step_is_refused_before_any_step(tmp_path, capsys, stomach_top):
    (x, y, z), zmin = stomach_top
    path = tmp_path / "p.csv"
    path.write_text(f"t_s,x_mm,y_mm,z_mm\n0,{x},{y},{z + 12}\n0.001,{x},{y},{zmin - 12}\n0.002,{x},{y},{zmin - 12}\n")
    one_line(capsys, main(["trace", "stomach", "--path", str(path), "--out", str(tmp_path / "t.csv")]), "through the organ")
    assert not (tmp_path / "t.csv").exists()


def test_a_trace_at_a_magnitude_no_tissue_has_is_refused_not_all_zero(tmp_path, capsys, stomach_top):
    path = tmp_path / "p.csv"
    path.write_text(top_path(stomach_top[0]))
    for flag in ("--youngs-modulus-kpa", "--thickness-mm", "--rayleigh-alpha-per-s", "--damping-ratio", "--probe-radius-mm"):
        one_line(capsys, main(["trace", "stomach", "--path", str(path), flag, "1e300", "--out", str(tmp_path / "t.csv")]),
                 f"{flag}: must be 0 or of magnitude 1e-12 to 1e+12, got 1e+300")
    one_line(capsys, main(["trace", "stomach", "--path", str(path), "--coupling-stiffness-n-per-mm", "1e300",
                           "--device-damping-ns-per-m", "1", "--out", str(tmp_path / "t.csv")]), "--coupling-stiffness-n-per-mm")
    # and a sane one presses: a force where the path presses 5 mm
    assert main(["trace", "stomach", "--path", str(path), "--out", str(tmp_path / "t.csv")]) == 0
    table = trace.TRACE_TABLE.read(tmp_path / "t.csv")
    assert np.linalg.norm([table[f"force_{a}_N"][-1] for a in "xyz"]) > 0.01


# -- the stroke (the facade of trace) --------------------------------------------------------------
@pytest.fixture(scope="module")
def ball():
    return primitives.icosphere(40.0, 2)


def test_a_stroke_refuses_a_start_inside_a_jump_through_and_the_support(ball):
    top = ball.vertices[np.argmax(ball.vertices[:, 2])]
    stroke = ProbeStroke(ball, probe_radius=R, rings=2)
    with pytest.raises(ValueError, match="starts .* inside the organ"):
        stroke.step(np.zeros(3))  # the centre of the ball
    stroke = ProbeStroke(ball, probe_radius=R, rings=2)
    above = top + [0.0, 0.0, R + 1e-3]
    stroke.step(above)
    pressed = above - [0.0, 0.0, 4e-3]
    for k in range(1, 5):
        stroke.step(above + (pressed - above) * k / 4)
    with pytest.raises(ValueError, match="while it touches the organ"):
        stroke.step(pressed + [0.0, 0.05, 0.0])  # 50 mm sideways in one step, pressing
    with pytest.raises(ValueError, match="into the organ"):
        stroke.step(pressed - [0.0, 0.0, 0.05])  # 50 mm down in one step
    # a press onto the supported bottom: refused in words (it was an IndexError in the relocation)
    held = ProbeStroke(ball, probe_radius=R, rings=2, fixed_below=-0.02)
    bottom = ball.vertices[np.argmin(ball.vertices[:, 2])]
    with pytest.raises(ValueError, match="held by the support"):
        for k in range(40):
            held.step(bottom - [0.0, 0.0, R + 2e-3 - 0.5e-3 * k])


def test_a_stroke_that_runs_away_raises_where_its_force_read_zero(ball):
    # the paper's constants at a step 40 x the critical one, one substep: the state blows up
    stroke = ProbeStroke(ball, TissueParams(edge_stiffness=1e5, anchor_stiffness=1e5), probe_radius=R, rings=2,
                         substeps=1, dt=5e-3)
    top = ball.vertices[np.argmax(ball.vertices[:, 2])]
    with pytest.raises(SimulationDiverged):
        for k in range(200):
            stroke.step(top + [0.0, 0.0, R - min(k, 8) * 1e-3])


# -- magnitudes and the facade's arguments ---------------------------------------------------------
@pytest.mark.parametrize("value", [1e300, 1e-300, float("nan"), float("inf")])
def test_every_material_parameter_has_the_scene_files_magnitude(value):
    for name in ("youngs_modulus", "density", "thickness", "foundation", "rayleigh_alpha", "rayleigh_beta", "damping_ratio"):
        kw = {"youngs_modulus": 1e3, name: value}
        with pytest.raises(ValueError, match=f"Material.{name}"):
            Material(**kw)


def test_the_facade_names_every_bad_argument(ball):
    with pytest.raises(ValueError, match="probe_radius .* mesh's extent"):
        Palpation(ball, rings=2, probe_radius=1e9)  # 0 N before
    pal = Palpation(ball, rings=2)
    pal.touch(0)
    for call, words in ((lambda: pal.set_probe(99, [0.0, 0.0, 0.0]), "mode must be one of"),
                        (lambda: pal.set_probe(PROBE_DISPLACEMENT, [np.nan, 0.0, 0.0]), r"target \[m\]"),
                        (lambda: pal.set_probe_force([0.0, 0.0, np.inf]), r"force \[N\]"),
                        (lambda: pal.press(depth=0.0), "press depth must be > 0"),
                        (lambda: pal.press(depth=1e-308), "press depth must be 0 or of magnitude"),
                        (lambda: pal.press(0.005, ramp=-1.0), "press ramp must be >= 0"),
                        (lambda: pal.touch(10**9), "contact vertex 1000000000 is outside the mesh"),
                        (lambda: Palpation(ball, dt=float("nan")), r"dt \[s\] must be finite")):
        with pytest.raises(ValueError, match=words):
            call()
    for bad in (0.0, float("nan")):
        with pytest.raises(ValueError, match="press depth"):
            check_press(depth=bad, ramp=0.1, hold=0.1, settle=0.1)


def test_a_lesions_factors_and_a_far_probe_are_refused(ball):
    from almsdm_warp.region.contact import find_contacts
    from almsdm_warp.sim.model import Model

    for name, n in (("edge_scale", ball.edge_count), ("anchor_scale", ball.vertex_count)):
        for bad in (np.nan, 1e300, -1.0, 1e-300):
            with pytest.raises(ValueError, match=f"{name} must be finite factors"):
                Model(ball, None, "cpu", **{name: np.full(n, bad)})
    with pytest.raises(ValueError, match="more than 1000 m from the origin"):
        find_contacts(ball, [1e30, 0.0, 0.0])


def test_a_batch_names_its_bad_arguments(ball):
    from almsdm_warp.batch.batch_palpation import BatchPalpation

    with pytest.raises(ValueError, match="probe_radius"):
        BatchPalpation(ball, rings=2, probe_radius=1e9)
    batch = BatchPalpation(ball, rings=2).touch([0, 5])
    with pytest.raises(ValueError, match="press depth must be > 0"):
        batch.press(depth=0.0)  # inf N/mm before


# -- sweeps and datasets ---------------------------------------------------------------------------
SPEC = (ROOT / "scenes" / "datasets" / "tiny.toml").read_text()
"""The smallest dataset (a baseline and one lesion of 3 points each)."""


def dataset(tmp_path, text=SPEC, *extra):
    (tmp_path / "spec.toml").write_text(text)
    return main(["sweep", "--dataset", str(tmp_path / "spec.toml"), "--out", str(tmp_path / "ds"), *extra])


@pytest.mark.parametrize("edit, words", [
    (("[dataset]\n", "[dataset]\nx = " + "[" * 3000 + "]" * 3000 + "\n"), "nested too deeply"),
    (("count = 1", "count = 9223372036854775807"), "[lesions] count 9.22337e+18 is more than the largest points"),
    (("count = 1", "count = 1000000000"), "[lesions] count 1e+09"),
    (("settle_s = 0.02", "settle_s = 1000000"), "the dataset would take at least"),
    (("depth_mm = 5.0\nramp", "depth_mm = 1e-308\nramp"), "[press] depth_mm must be 0 or of magnitude"),
])
def test_a_bad_dataset_spec_is_one_line_before_any_planning(tmp_path, capsys, monkeypatch, edit, words):
    monkeypatch.setattr(ds, "plan_items", lambda *a, **k: pytest.fail("planned before the spec was checked"))
    one_line(capsys, dataset(tmp_path, SPEC.replace(*edit)), words)
    assert not (tmp_path / "ds").exists()


@pytest.mark.parametrize("flag", [["--points", "9"], ["--probe-radius-mm", "3"], ["--fixed-below-mm", "0"],
                                  ["--integrator", "implicit"], ["--integrator", "explicit"]])
def test_sweep_dataset_refuses_the_flags_its_spec_decides(tmp_path, capsys, flag):
    one_line(capsys, dataset(tmp_path, SPEC, *flag), f"{flag[0]} is decided by the dataset spec")
    assert not (tmp_path / "ds").exists()


def test_a_sweep_on_ray_without_ray_leaves_nothing(tmp_path, capsys):
    pytest.importorskip("pytest")
    try:
        import ray  # noqa: F401
        pytest.skip("Ray is installed")
    except ImportError:
        pass
    one_line(capsys, main(["sweep", "--points", "3", "--ray", "--out", str(tmp_path / "s.csv")]), "--ray needs Ray")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    folder = tmp_path_factory.mktemp("reference")
    assert dataset(folder) == 0
    return folder / "ds", dict(np.load(folder / "ds" / "table.npz"))


def same_table(out, reference):
    table = dict(np.load(out / "table.npz"))
    for c in ("vertex", "peak_force_N", "hold_force_N", "lesion_id"):
        np.testing.assert_array_equal(table[c], reference[1][c])


def without_last_item(tmp_path, reference, plan_json=None):
    """A copy of the reference dataset as a run killed in its last item left it: that item not in
    dataset.json, its table gone, its parts folder holding a chunk (and `plan_json`, when given)."""
    import shutil

    shutil.copytree(reference[0], tmp_path / "ds")
    out = tmp_path / "ds"
    manifest = json.loads((out / "dataset.json").read_text())
    name = sorted(manifest["items"])[-1]
    del manifest["items"][name]
    (out / "dataset.json").write_text(json.dumps(manifest))
    (out / "table.npz").unlink()
    table = SWEEP_TABLE.read(out / "items" / f"{name}.npz")
    parts = out / "items" / f"{name}.npz.parts"
    parts.mkdir()
    SWEEP_TABLE.write(parts / "chunk_000000.npz", {k: v[:2] for k, v in table.items()})
    if plan_json is not None:
        (parts / "plan.json").write_text(plan_json)
    (out / "items" / f"{name}.npz").unlink()
    return out


@pytest.mark.parametrize("damage", ["parts without plan.json", "truncated plan.json", "truncated dataset.json"])
def test_a_damaged_dataset_resumes_to_the_uninterrupted_table(tmp_path, capsys, reference, damage):
    (tmp_path / "spec.toml").write_text(SPEC)
    if damage == "truncated dataset.json":
        import shutil

        shutil.copytree(reference[0], tmp_path / "ds")
        text = (tmp_path / "ds" / "dataset.json").read_text()
        (tmp_path / "ds" / "dataset.json").write_text(text[:40])
        (tmp_path / "ds" / "table.npz").unlink()
    else:  # a kill while the parts folder was removed (plan.json went first), or a truncated plan.json
        without_last_item(tmp_path, reference, None if damage == "parts without plan.json" else '{"key": "ab')
    capsys.readouterr()
    assert dataset(tmp_path) == 0  # was: "holds parts of a different sweep" / "not a dataset folder", every run
    assert "note: " in capsys.readouterr().err
    same_table(tmp_path / "ds", reference)


def test_a_dataset_resumed_with_other_chunks_ends_in_the_same_table(tmp_path, capsys, reference):
    out = without_last_item(tmp_path, reference)
    (tmp_path / "spec.toml").write_text(SPEC.replace("chunk = 2", "chunk = 1"))
    parts = next((out / "items").glob("*.parts"))
    # the parts of the old chunking, with their plan.json as the old run wrote it
    item = ds.plan_items(ds.load_spec(tmp_path / "spec.toml"))[-1]
    item.plan.chunk = 2
    store = Parts(out / "items" / f"{item.name}.npz", item.plan)
    sums = {"0": file_sha256(parts / "chunk_000000.npz")}
    (parts / "plan.json").write_text(json.dumps({"key": store.key, "base": store.base_key, "points": 3, "chunks": sums}))
    assert main(["sweep", "--dataset", str(tmp_path / "spec.toml"), "--out", str(out)]) == 0
    assert "cut into other chunks" in capsys.readouterr().err
    same_table(out, reference)


def test_parts_are_removed_with_plan_json_last(tmp_path, monkeypatch):
    """A kill while the parts folder is removed leaves plan.json beside the chunks still there."""
    from pathlib import Path

    parts = tmp_path / "o.csv.parts"
    parts.mkdir()
    for i in range(3):
        (parts / f"chunk_{i:06d}.npz").write_bytes(b"x")
    (parts / "plan.json").write_text("{}")
    removed = []
    real = Path.unlink

    def unlink(self, missing_ok=False):
        if removed:
            raise KeyboardInterrupt  # killed after the first file
        removed.append(self.name)
        real(self, missing_ok=missing_ok)

    monkeypatch.setattr(Path, "unlink", unlink)
    with pytest.raises(KeyboardInterrupt):
        Parts(tmp_path / "o.csv", None).remove()
    assert removed != ["plan.json"] and (parts / "plan.json").exists()


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / f".out.json.{int(gone.stdout)}.abcd.tmp"
    stale.write_text("half")
    alive = tmp_path / f".out.json.{os.getpid()}.efgh.tmp"  # this process's own: kept
    alive.write_text("mine")
    atomic_write_text(tmp_path / "out.json", "{}")
    assert not stale.exists() and alive.exists() and (tmp_path / "out.json").read_text() == "{}"


# -- quiet: every error one line, the facade silent --------------------------------------------------
def test_warp_says_nothing_unless_asked(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("ALMSDM_VERBOSE", None)
    code = ("import sys, almsdm_warp; almsdm_warp.Palpation\n"  # the facade starts Warp, quietly
            "from almsdm_warp.cli.main import main; sys.exit(main(['trace', '--dt-ms', '1e9']))")
    quiet = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert quiet.returncode == 2 and quiet.stdout == "" and quiet.stderr.count("\n") == 1, quiet.stderr
    code = "from almsdm_warp.warp_init import init_warp; init_warp()"
    loud = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env={**env, "ALMSDM_VERBOSE": "1"})
    assert "Warp" in loud.stdout
