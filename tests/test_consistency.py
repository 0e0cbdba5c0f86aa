"""One behaviour everywhere: the same region from touch and palpate, the unit-suffix names (old spellings
still taken, not listed), floats written at the precision they carry, trace's step times, the mesh's
quality in one line. CPU."""

import argparse
import json

import meshio
import numpy as np
import pytest

from almsdm_warp.cli.main import build_parser, main
from almsdm_warp.mesh.io import load_mesh
from almsdm_warp.mesh.topology import tet_quality


def test_touch_grows_the_region_palpate_presses(tmp_path):
    """The stomach scene's 10 mm sphere: touch's region is palpate's (ring 0 the sphere's patch)."""
    touched, pressed = tmp_path / "t.json", tmp_path / "p.json"
    assert main(["touch", "--json", str(touched)]) == 0
    assert main(["palpate", "--ramp-s", "0.02", "--hold-s", "0", "--settle-s", "0", "--json", str(pressed)]) == 0
    t, p = json.loads(touched.read_text()), json.loads(pressed.read_text())
    assert t["contact"]["vertex"] == p["contact"]["vertex"]
    last = t["regions"][-1]
    assert (last["rings"], last["region_vertices"], last["region_springs"]) == (
        p["model"]["rings"], p["model"]["region_vertices"], p["model"]["region_springs"])


def subparser(name):
    parser = build_parser()
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices[name]


@pytest.mark.parametrize("command, old, new, dest", [
    ("palpate", "--density-kg-m3", "--density-kg-per-m3", "density_kg_per_m3"),
    ("trace", "--coupling-stiffness-N-per-mm", "--coupling-stiffness-n-per-mm", "coupling_k"),
    ("trace", "--device-damping-Ns-per-m", "--device-damping-ns-per-m", "device_b"),
])
def test_old_spellings_are_taken_and_not_listed(command, old, new, dest):
    p = subparser(command)
    assert getattr(p.parse_args([old, "2"]), dest) == getattr(p.parse_args([new, "2"]), dest) == 2.0
    text = p.format_help()
    assert new in text and old not in text
    assert new == new.lower()  # one rule: flags in lower case, the scene key's words


def test_floats_at_the_precision_they_carry(tmp_path):
    """A sweep's coordinates are the mesh file's millimetres (-23.2598, not the -23.259800000000002 of metres x
    1000), and every float reads back as written (repr: the shortest text of the value)."""
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
    from almsdm_warp.export.tables import millimetres

    assert repr(float(np.array(-0.0232598) * 1e3)) == "-23.259800000000002"
    assert repr(float(millimetres(-0.0232598))) == "-23.2598"
    out = tmp_path / "s.csv"
    assert main(["sweep", "--points", "2", "--ramp-s", "0.01", "--hold-s", "0", "--settle-s", "0", "--out", str(out)]) == 0
    first = out.read_text().splitlines()[1].split(",")
    assert first[:3] == ["-23.2598", "19.4361", "33.9907"]  # vertex 693 as scenes/stomach.obj writes it
    table = SWEEP_TABLE.read(out)
    assert table["peak_force_N"][0] == float(first[4])


def test_trace_reports_its_step_times(tmp_path, capsys):
    path = tmp_path / "p.csv"
    path.write_text("t_s,x_mm,y_mm,z_mm\n0,-23.26,19.44,44\n0.05,-23.26,19.44,40\n")
    out = tmp_path / "t.json"
    assert main(["trace", "--path", str(path), "--rings", "1", "--json", str(out)]) == 0
    step = json.loads(out.read_text())["step_us"]
    assert step["steps"] == 50 and 0 < step["p50_us"] <= step["p99_us"] <= step["max_us"]  # 51 steps, the first left out
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("step:"))
    assert f"p50 {step['p50_us']:.1f} us" in line and f"max {step['max_us']:.1f} us over 50 steps" in line


def test_one_quality_line_counts_the_faults_and_names_the_worst(tmp_path):
    """A regular tet, one inverted (reoriented) and one sliver: one line with both counts and the worst."""
    v = np.array([[0, 0, 0], [10, 0, 0], [5, 8.66, 0], [5, 2.89, 8.16], [5, 2.89, -8.16], [5, 0.96, 2.72]], dtype=float)
    tets = np.array([[0, 1, 2, 3], [0, 2, 1, 4], [0, 1, 5, 3]])  # the second wound inside out; the third flat (5 near the face 0 1 3)
    path = tmp_path / "q.vtu"
    meshio.write(path, meshio.Mesh(v, [("tetra", tets)]))
    mesh = load_mesh(path)
    q = tet_quality(mesh.vertices, mesh.tetrahedra)
    [line] = [n for n in mesh.notes if "quality" in n]
    assert line.startswith(f"{int((q < 0.02).sum())} sliver tetrahedron of 3") and "1 inverted reoriented" in line
    assert f"quality {q.min():.3g}" in line and f"median quality {np.median(q):.3g}" in line
