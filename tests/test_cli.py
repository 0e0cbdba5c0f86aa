"""The command line: the main job on the default scene, and bad input as one line with exit code 2."""

import json
import os
import subprocess
import sys

import pytest
from conftest import ROOT, SHARED_MESHES

from almsdm_warp.cli.main import main


def run_cli(*args, cwd=None):
    """Run `python -m almsdm_warp.cli.main` in a fresh process, as a user would."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    return subprocess.run(
        [sys.executable, "-m", "almsdm_warp.cli.main", *args], capture_output=True, text=True, cwd=cwd or ROOT, env=env, timeout=300
    )


def test_touch_default_scene_writes_json(tmp_path):
    out = tmp_path / "touch.json"
    r = run_cli("touch", "--rings", "3", "--json", str(out))
    assert r.returncode == 0, r.stderr
    data = json.loads(out.read_text())
    assert data["mesh"]["vertices"] > 0 and data["contact"]["vertex"] >= 0
    regions = data["regions"]
    assert [row["rings"] for row in regions] == [1, 2, 3]
    sizes = [row["region_vertices"] for row in regions]
    assert sizes == sorted(sizes) and sizes[0] >= 4
    assert "region at vertex" in r.stdout
    assert not [p for p in tmp_path.iterdir() if p.name != "touch.json"]  # no temporary left behind


@pytest.mark.parametrize(
    "args, message",
    [
        (["touch", "no/such/mesh.obj"], "no such file"),
        (["touch", "--rings", "-1"], "touch: argument --rings: must be >= 1"),
        (["touch", "--rings", "two"], "unknown value 'two'"),
        (["touch", "--json", "/no/such/folder/out.json"], "does not exist"),
        (["touch", "--device", "tpu:7"], "unknown device"),
        (["touch", "--probe-mm", "nan", "0", "0"], "--probe-mm must be finite"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_broken_mesh_file_from_a_real_process(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    out = tmp_path / "out.json"
    r = run_cli("touch", str(bad), "--json", str(out))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "broken.obj" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]


def test_touch_a_shared_volume_mesh(tmp_path, capsys):
    path = SHARED_MESHES / "sofa_liver2_tets.vtu"
    if not path.exists():
        pytest.skip(f"{path} absent")
    out = tmp_path / "liver.json"
    assert main(["touch", str(path), "--rings", "2", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["mesh"]["tetrahedra"] == 1493 and data["mesh"]["vertices"] == 507


@pytest.mark.parametrize("case", ["plain", "thread", "profiler"])
def test_the_process_ends_at_once_with_its_output_whole(tmp_path, case):
    # the command line's run() ends the process without the interpreter's teardown (an atexit handler does
    # not run), its table whole and its exit status kept; with a thread still running or a profiler on, it
    # exits as usual (the handler runs)
    flag, out = tmp_path / "teardown", tmp_path / "s.csv"
    code = "\n".join([
        "import atexit, sys, threading, time",
        f"atexit.register(lambda: open({str(flag)!r}, 'w').close())",
        "wait = lambda: [time.sleep(0.01) for _ in iter(threading.main_thread().is_alive, False)]",  # till main ends
        "if sys.argv[1] == 'thread': threading.Thread(target=wait).start()",
        "if sys.argv[1] == 'profiler': sys.setprofile(lambda *a: None)",
        "sys.argv = ['almsdm', 'sweep', 'stomach', '--points', '64', '--ramp-s', '0.02', '--hold-s', '0.02',"
        f" '--settle-s', '0.02', '--no-progress', '--out', {str(out)!r}]",
        "from almsdm_warp.cli.main import run",
        "run()",
    ])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    r = subprocess.run([sys.executable, "-c", code, case], capture_output=True, text=True, cwd=ROOT, env=env, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout
    lines = out.read_text().splitlines()
    assert len(lines) == 65 and len(lines[-1].split(",")) == len(lines[0].split(","))  # a header and 64 rows
    assert flag.exists() == (case != "plain")
    bad = subprocess.run([sys.executable, "-c", code.replace("'64'", "'-3'"), case], capture_output=True, text=True, cwd=ROOT,
                         env=env, timeout=300)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1, bad.stderr
