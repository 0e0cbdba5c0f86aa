"""Fuzzing the command line (hypothesis), in-process through almsdm_warp.cli.main.main: extreme and
impossible parameters, probes far from the mesh, unwritable and odd output paths. Every run ends
in a result (exit 0, complete JSON) or one line on stderr with exit code 2 (no JSON, no
temporary file left); never a traceback or a hang. A few runs in a real process check that
nothing prints a traceback there either.
"""

import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import ROOT
from fuzzing import check_outcome, fuzz_settings, record, run_main
from hypothesis import given
from hypothesis import strategies as st

# short presses: a fuzz run is about the input, not the physics
FAST = ["--ramp-s", "0.01", "--hold-s", "0.005", "--settle-s", "0.01"]


def extreme_floats():
    return st.one_of(
        st.sampled_from(["0", "-0", "-1", "1e-320", "5e-324", "1e-9", "1e9", "1e300", "1e309", "nan", "inf", "-inf", "x", "", "1e",
                         "0x10", "1_000", "٣"]),
        st.floats(allow_nan=False, allow_infinity=False).map(repr),
        st.floats(1e-3, 1e2).map(lambda x: f"{x:.6g}"),
    )


def flag_values():
    """(flag, value) pairs of the palpate command, with extreme values."""
    number = extreme_floats()
    integer = st.one_of(st.integers(-3, 12).map(str), st.sampled_from(["1000000", "-1", "99999999999999999999", "2.5", "global", "x"]))
    return st.one_of(
        st.tuples(st.just("--depth-mm"), number),
        st.tuples(st.just("--dt-ms"), number),
        st.tuples(st.just("--ramp-s"), number),
        st.tuples(st.just("--hold-s"), number),
        st.tuples(st.just("--settle-s"), number),
        st.tuples(st.just("--scale-mm"), number),
        st.tuples(st.just("--rings"), st.one_of(integer, st.sampled_from(["global", "global-free"]))),
        st.tuples(st.just("--presses"), st.sampled_from(["0", "1", "2", "-1", "1e9", "x"])),
        st.tuples(st.just("--vertex"), integer),
        st.tuples(st.just("--integrator"), st.sampled_from(["explicit", "implicit", "rk4", ""])),
        st.tuples(st.just("--device"), st.sampled_from(["cpu", "cuda:9", "tpu", ""])),
    )


def probe_values():
    coordinate = st.one_of(st.floats(-200, 200).map(lambda x: f"{x:.3f}"),
                           st.sampled_from(["1e6", "-1e6", "1e30", "1e38", "1e39", "nan", "inf", "0"]))
    return st.lists(coordinate, min_size=3, max_size=3)


def json_target(folder: Path, kind: str) -> str:
    if kind == "ok":
        return str(folder / "out.json")
    if kind == "missing folder":
        return str(folder / "no" / "such" / "out.json")
    if kind == "a folder":
        return str(folder)
    if kind == "read-only folder":
        ro = folder / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        return str(ro / "out.json")
    if kind == "/proc":
        return "/proc/almsdm-fuzz.json"
    if kind == "long name":
        return str(folder / ("x" * 300 + ".json"))
    return str(folder / "out.json")


JSON_KINDS = ["ok", "ok", "ok", "ok", "missing folder", "a folder", "read-only folder", "/proc", "long name"]


def run_checked(argv, folder, json_path, test, case):
    code, out, err = run_main(argv, fuzz_limits=True)
    outcome = check_outcome(code, out, err, json_path, folder)
    record(test, case, outcome, err.strip().splitlines()[-1] if err.strip() else "")
    return outcome, out, err


@fuzz_settings(12)
@given(
    command=st.sampled_from(["palpate", "touch"]),
    flags=st.lists(flag_values(), max_size=3, unique_by=lambda fv: fv[0]),
    probe=st.none() | probe_values(),
    scene=st.sampled_from([None, "liver", "stomach"]),
    json_kind=st.sampled_from(JSON_KINDS),
)
def test_cli_extreme_parameters(command, flags, probe, scene, json_kind):
    """Palpate or touch with up to three extreme flags, a probe anywhere, and an output path
    that may not be writable."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        json_path = json_target(folder, json_kind)
        argv = [command] + ([scene] if scene else [])
        if command == "palpate":
            argv += FAST
            for flag, value in flags:
                argv += [flag, value] if not (value.startswith("-") and value[1:2].isdigit()) else [f"{flag}={value}"]
        else:
            argv += ["--rings", "2"] if not flags or flags[0][0] != "--rings" else [f"--rings={flags[0][1]}"]
        if probe is not None and not (command == "palpate" and any(f == "--vertex" for f, _ in flags)):
            argv += ["--probe-mm", *[p if not p.startswith("-") else f" {p}" for p in probe]]
        argv += ["--json", json_path]
        case = f"{command} {' '.join(f for f, _ in flags) or '(scene defaults)'}{' --probe-mm' if probe else ''} json:{json_kind}"
        try:
            run_checked(argv, folder, json_path, "cli_extreme", case)
        finally:
            for p in folder.rglob("*"):
                if p.is_dir():
                    p.chmod(0o700)


# -- regressions found by fuzzing --------------------------------------------------------------
@pytest.mark.parametrize(
    "argv, message",
    [
        # a hang: 1.3e12 steps (and arrays of that many floats) from one typo
        (["--dt-ms", "1e-9"], "the run would take 1.3e+12 steps"),
        (["--hold-s", "1e12"], "--hold-s 1e+12 is more than the largest duration [s]"),
        (["--presses", "100000000"], "more than the 10,000,000"),
        # OverflowError: int(round(inf)) steps
        (["--ramp-s", "1e300", "--dt-ms", "1e-300"], "--ramp-s: must be 0 or of magnitude 1e-12 to 1e+12, got 1e+300"),
        (["--ramp-s", "1e9", "--dt-ms", "1e-9"], "--ramp-s 1e+09 is more than the largest duration [s]"),
        # the magnitude every physical parameter is held to (checks.check_value), as a scene's
        (["--dt-ms", "1e-308"], "--dt-ms: must be 0 or of magnitude 1e-12 to 1e+12, got 1e-308"),
        (["--dt-ms", "1e-322"], "--dt-ms: must be 0 or of magnitude"),
        (["--youngs-modulus-kpa", "1e300"], "--youngs-modulus-kpa: must be 0 or of magnitude"),
        (["--youngs-modulus-kpa", "1e11"], "--youngs-modulus-kpa: Material.youngs_modulus must be 0 or of magnitude"),
        # a dt longer than the ramp: the implicit run "diverged ... dt exceeds the critical step"
        (["--dt-ms", "1e9", "--integrator", "implicit"], "is longer than the ramp"),
        # a 1 m press into a 13 cm stomach: "diverged: dt = 1 ms exceeds the critical step of 1.6 ms"
        (["--depth-mm", "1e3", "--integrator", "implicit"], "more than the mesh's extent"),
        (["--depth-mm", "1e300"], "--depth-mm/--depth: must be 0 or of magnitude"),  # was a RuntimeWarning on stderr
        (["--depth-mm", "1e9"], "more than the mesh's extent"),
        # a probe beyond the contact query's reach: "seed vertex -1 is outside the mesh"
        (["--probe-mm", "1e30", "0", "0"], "more than 1e+06 mm from the origin"),
        (["touch", "--probe-mm", "1e38", "1e38", "1e38"], "more than 1e+06 mm from the origin"),  # was a ValueError traceback
        (["--rings", "99999999999999999999"], "is more than the mesh's 1002 vertices"),  # was an OverflowError in Region
        (["touch", "a\0b.obj"], "cannot hold a NUL byte"),  # was ValueError: embedded null byte
        (["touch", "/tmp/" + "a" * 300 + ".obj"], "File name too long"),  # was an OSError traceback
    ],
)
def test_impossible_parameters_are_one_line_errors(argv, message, tmp_path):
    out = tmp_path / "out.json"
    code, stdout, err = run_main([*argv, "--json", str(out)] if "\0" not in argv[-1] else argv)
    check_outcome(code, stdout, err, out, tmp_path)
    assert code == 2 and message in err, err


# sweep and bench check what palpate checks (checks.py): each of these was a traceback, and the
# sweep's ones left OUT.parts/plan.json behind, which refused the corrected rerun
CRAFTED = [
    (["sweep", "--ramp-s", "1e308"], "--ramp-s: must be 0 or of magnitude 1e-12 to 1e+12, got 1e+308"),
    (["sweep", "--settle-s", "1e9"], "--settle-s 1e+09 is more than the largest duration [s]"),
    (["sweep", "--dt-ms", "1e-308"], "--dt-ms: must be 0 or of magnitude"),
    (["sweep", "--dt-ms", "1e-11"], "the run would take 1.3e+14 steps"),
    (["sweep", "--depth-mm", "1e-308"], "--depth-mm/--depth: must be 0 or of magnitude"),  # was a stiffness of 2e298
    (["sweep", "--probe-radius-mm", "1e12"], "probe_radius 1e+09 m is more than 100 x the mesh's extent"),
    (["sweep", "--rings", "1000000"], "--rings 1000000 is more than the mesh's 1002 vertices"),
    (["sweep", "--points", "100000000000"], "--points 1e+11 is more than the largest points"),
    (["sweep", "--points", "10", "--max-region-steps", "1000"], "more than the 1e+03 allowed; give --max-region-steps"),
    (["bench", "--rings", "5000"], "--rings 5000 is more than the mesh's 1002 vertices"),
    (["bench", "--batch", "10000000000"], "--batch 1e+10 is more than the largest batch"),
    (["palpate", "--png", "{tmp}/p.png", "--png-at-s", "1e9"], "--png-at-s 1e+09 is after the last step"),
    (["sweep", "{tmp}/lesion.toml"], "[lesion] stiffness_factor 1e+308 is more than the largest lesion stiffness factor"),
]


@pytest.mark.parametrize("argv, message", CRAFTED, ids=[" ".join(a) for a, _ in CRAFTED])
def test_crafted_inputs_are_one_line_and_leave_nothing(argv, message, tmp_path):
    """One line, exit 2, and nothing in the output's folder (no table, no parts, no plan.json): the
    validation fails before any simulation, so a corrected rerun starts clean."""
    lesion = (ROOT / "scenes" / "stomach_lesion.toml").read_text()
    lesion = lesion.replace('path = "stomach.obj"', f'path = "{ROOT / "scenes" / "stomach.obj"}"')
    (tmp_path / "lesion.toml").write_text(lesion.replace("stiffness_factor = 5.0", "stiffness_factor = 1e308"))
    out = tmp_path / "out" / "table.csv"
    out.parent.mkdir()
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    extra = ["--out", str(out)] if argv[0] == "sweep" else []
    code, stdout, err = run_main([*argv, *extra])
    assert code == 2 and err.count("\n") == 1 and message in err, err
    assert "Traceback" not in err
    assert list(out.parent.iterdir()) == [] and not (tmp_path / "p.png").exists()


@pytest.mark.parametrize("rings", ["1000000", "99999999999999999999"])
def test_touch_with_more_rings_than_the_mesh_holds(rings, tmp_path):
    """touch built every ring count from 1 to --rings: 1e6 full-mesh builds (a hang, and 2 GB of
    rows) or for ever. It now stops where the region covers the mesh component, which is the
    breadth-first depth of the mesh from the contact (scipy), plus the one empty ring that shows it."""
    import json

    import numpy as np
    import scipy.sparse as sp
    from scipy.sparse.csgraph import shortest_path

    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    out = tmp_path / "touch.json"
    code, stdout, err = run_main(["touch", "--rings", rings, "--probe-radius-mm", "0", "--json", out])  # rings from one vertex
    check_outcome(code, stdout, err, out, tmp_path)
    assert code == 0, err
    data = json.loads(out.read_text())
    mesh = resolve_scene_or_mesh(None).load_mesh()
    e = mesh.edges
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(mesh.vertex_count,) * 2)
    depth = int(shortest_path(g, directed=False, unweighted=True, indices=data["contact"]["vertex"]).max())
    assert [row["rings"] for row in data["regions"]] == list(range(1, depth + 2))
    assert data["regions"][-1]["region_vertices"] == data["regions"][-2]["region_vertices"] == mesh.vertex_count
    assert f"rings {depth + 2}..{rings}: the same region" in stdout


def test_far_probe_within_reach_still_touches(tmp_path):
    """A probe 1.7 km away is refused, one 1 km away along an axis still finds the nearest vertex
    (the contact query reaches 1e6 m)."""
    out = tmp_path / "touch.json"
    code, stdout, err = run_main(["touch", "--rings", "1", "--probe-mm", "0", "0", "1e6", "--json", out])
    assert code == 0, err
    import json

    import numpy as np

    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    mesh = resolve_scene_or_mesh(None).load_mesh()
    got = json.loads(out.read_text())["contact"]["vertex"]
    sv = mesh.surface_vertices
    d = np.linalg.norm(mesh.vertices[sv] - [0, 0, 1e3], axis=1)
    assert math.isclose(np.linalg.norm(mesh.vertices[got] - [0, 0, 1e3]), d.min(), rel_tol=1e-6)


def _subprocess(*args):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    return subprocess.run([sys.executable, "-m", "almsdm_warp.cli.main", *args], capture_output=True, text=True, cwd=ROOT, env=env,
                          timeout=300)


@pytest.mark.parametrize(
    "argv",
    [
        ["--dt-ms", "1e-9"],
        ["touch", "--probe-mm", "1e38", "1e38", "1e38"],
        ["--depth-mm", "1e300"],
    ],
    ids=["hang", "far-probe", "deep"],
)
def test_no_traceback_from_a_real_process(argv):
    r = _subprocess(*argv)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("almsdm: error: ")


# -- scenes nested deeply, suffixes, units, the version, evaluate's folder --------------------
@given(depth=st.integers(min_value=1, max_value=200_000), kind=st.sampled_from(["array", "table"]))
@fuzz_settings(6)
def test_deeply_nested_scene_is_one_line(depth, kind):
    """A TOML value nested `depth` levels (a RecursionError traceback before): a scene or one line."""
    with tempfile.TemporaryDirectory() as d:
        scene = Path(d) / "deep.toml"
        value = "[" * depth + "]" * depth if kind == "array" else "{a=" * depth + "1" + "}" * depth
        scene.write_text(f"[mesh]\npath = {value}\n")
        code, stdout, err = run_main(["touch", scene, "--rings", "1"])
        record("deeply_nested_scene", f"{kind} {depth}", check_outcome(code, stdout, err), err)
        assert code == 2  # no depth makes a mesh path


def test_png_suffix_is_png(tmp_path):
    """One table says which suffixes a picture takes: --png x.svg is refused, not PNG bytes in an .svg."""
    code, stdout, err = run_main(["palpate", "--png", tmp_path / "x.svg"])
    check_outcome(code, stdout, err, folder=tmp_path)
    assert code == 2 and "'.svg' (allowed: .png)" in err and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("scale_mm, hint", [(1e-3, "not an organ's size"), (1.0, None), (100.0, "not an organ's size")])
def test_units_hint(tmp_path, scale_mm, hint):
    """A mesh read at a --scale-mm that makes it spans under 15 mm or over 2 m gets a note (the stomach spans 128 mm)."""
    code, stdout, err = run_main(["sweep", ROOT / "scenes" / "stomach.obj", "--scale-mm", scale_mm, "--points", "1",
                                  "--out", tmp_path / "s.csv", "--ramp-s", "0.002", "--hold-s", "0", "--settle-s", "0"])
    notes = [ln for ln in err.splitlines() if "the mesh spans" in ln]
    if hint is None:
        assert notes == []
    else:
        import re

        import trimesh

        span = float(trimesh.load(ROOT / "scenes" / "stomach.obj", process=False).extents.max()) * scale_mm
        said = float(re.search(r"spans (\S+) mm", notes[0]).group(1))
        assert len(notes) == 1 and hint in notes[0] and math.isclose(said, span, rel_tol=1e-3), err


def test_version():
    import tomllib

    import almsdm_warp

    r = _subprocess("--version")
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert r.returncode == 0 and r.stdout.strip() == f"almsdm {version}" == f"almsdm {almsdm_warp.__version__}"


def test_evaluate_keeps_docs_unless_told(tmp_path, monkeypatch):
    """Without --out, evaluate writes to a folder of its own in the working folder, not docs/."""
    import almsdm_warp.evaluation.evaluate as ev

    seen = []
    monkeypatch.setattr(ev, "run_evaluation", lambda out, *a, **k: seen.append(out) or {"figures": [], "elapsed_s": 0.0})
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run_main(["evaluate", "--settings", "tiny"])
    assert code == 0 and seen == [Path("evaluation_results")] and (tmp_path / "evaluation_results").is_dir(), err
    code, stdout, err = run_main(["evaluate", "--settings", "tiny", "--out", "docs"])
    assert code == 2 and "--out docs: no such folder" in err
