"""`almsdm palpate --usd/--usd-every/--png/--png-at-s`: the files are written, complete and right;
bad paths and values end with exit code 2 and leave nothing behind. CPU; no timing asserts."""

import re
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT
from test_cli import run_cli

from almsdm_warp.cli.main import main

SHORT = ("--ramp-s", "0.05", "--hold-s", "0.02", "--settle-s", "0.05")  # 120 steps


def test_usd_and_png_from_one_run(tmp_path, capsys):
    usd, png = tmp_path / "press.usda", tmp_path / "press.png"
    assert main(["palpate", *SHORT, "--usd", str(usd), "--usd-every", "50", "--png", str(png)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {usd} (4 frames, every 50 steps)" in out  # steps 0, 50, 100, 120
    assert f"wrote {png} (t = 0.070 s)" in out  # the end of the hold: the deepest frame
    assert sorted(p.name for p in tmp_path.iterdir()) == ["press.png", "press.usda"]  # no temporary left

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(usd))
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Palpation/Organ")).GetPointsAttr()
    assert points.GetTimeSamples() == [0.0, 50.0, 100.0, 120.0]
    assert stage.GetEndTimeCode() == 120

    import matplotlib.image

    img = matplotlib.image.imread(str(png))
    assert img.shape[0] > 300 and img.shape[1] > 600
    assert img[..., :3].std() > 0.05  # not blank
    assert displaced_pixels(img) > 50  # the dent, in the colours of a large displacement
    assert png.stat().st_size < 200_000


def displaced_pixels(img):
    """Pixels of the organ (left of the colour bar) in magma's red-to-purple: displaced > ~3 mm.

    Tissue at rest is pale yellow, the outline black and the probe grey: none has red far above green."""
    rgb = img[:, : int(0.75 * img.shape[1]), :3]
    return int((rgb[..., 0] - rgb[..., 1] > 0.3).sum())


def test_png_at_a_chosen_time_before_the_press_shows_no_displacement(tmp_path, capsys):
    import matplotlib.image

    rest, deep = tmp_path / "rest.png", tmp_path / "deep.png"
    assert main(["palpate", *SHORT, "--png", str(rest), "--png-at-s", "0"]) == 0
    assert f"wrote {rest} (t = 0.000 s)" in capsys.readouterr().out
    assert main(["palpate", *SHORT, "--png", str(deep)]) == 0
    assert displaced_pixels(matplotlib.image.imread(str(rest))) == 0
    assert displaced_pixels(matplotlib.image.imread(str(deep))) > 50


@pytest.mark.parametrize(
    "args, message",
    [
        (("--usd", "{tmp}/missing/out.usda"), "folder .*missing does not exist"),
        (("--usd", "{tmp}/out.abc"), r"unknown USD suffix '\.abc'"),
        (("--png", "{tmp}/out.jpg"), r"unknown PNG suffix '\.jpg' \(allowed: \.png\)"),
        (("--png-at-s", "0.1"), "--png-at-s needs --png"),
        (("--png", "{tmp}/out.png", "--png-at-s", "9"), "--png-at-s 9 is after the last step"),
        (("--usd", "{tmp}/out.usdc", "--usd-every", "0"), "must be >= 1"),
    ],
)
def test_bad_recording_arguments_exit_2_and_write_nothing(tmp_path, capsys, args, message):
    argv = [a.format(tmp=tmp_path) for a in args]
    assert main(["palpate", *SHORT, *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("almsdm: error: ") and err.count("\n") == 1
    assert re.search(message, err), err
    assert list(tmp_path.iterdir()) == []


def test_a_folder_as_usd_target(tmp_path, capsys):
    (tmp_path / "stage.usda").mkdir()
    assert main(["palpate", *SHORT, "--usd", str(tmp_path / "stage.usda")]) == 2
    assert "is a folder, not a file" in capsys.readouterr().err
    assert [p.name for p in tmp_path.iterdir()] == ["stage.usda"] and not any((tmp_path / "stage.usda").iterdir())


def test_a_run_that_fails_midway_leaves_no_stage(tmp_path, capsys, monkeypatch):
    # the simulation diverges from step 100 on, after the stage was opened (and again at the first step of
    # each press again at more substeps, REPRESSES): exit 2, no file
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.solvers.stepper import REPRESSES

    step = Palpation.step
    calls = []

    def diverging(self):
        calls.append(1)
        if len(calls) >= 100:
            self.diverged(len(calls))
        return step(self)

    monkeypatch.setattr(Palpation, "step", diverging)
    out = tmp_path / "out.usdc"
    assert main(["palpate", *SHORT, "--usd", str(out), "--png", str(tmp_path / "p.png")]) == 2
    assert len(calls) == 100 + REPRESSES
    assert "diverged" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_bad_usd_path_from_a_real_process(tmp_path):
    r = run_cli("palpate", "--usd", str(tmp_path / "nope" / "out.usda"))
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_recording_does_not_change_the_physics(tmp_path, capsys):
    # the same press with and without the hook: the same printed force and recovery
    assert main(["palpate", *SHORT]) == 0
    plain = [line for line in capsys.readouterr().out.splitlines() if line.startswith("press 1:")]
    assert main(["palpate", *SHORT, "--usd", str(tmp_path / "a.usdc"), "--usd-every", "3"]) == 0
    recorded = [line for line in capsys.readouterr().out.splitlines() if line.startswith("press 1:")]
    assert plain == recorded and len(plain) == 1
    assert np.isfinite(float(plain[0].split("peak force ")[1].split(" N")[0]))


def test_usd_and_matplotlib_are_imported_only_when_asked_for(tmp_path):
    code = (
        "import sys; from almsdm_warp.cli.main import main; "
        "rc = main(['palpate', '--settle-s', '0.05'] + sys.argv[1:]); "
        "print('modules', rc, 'pxr' in sys.modules, 'matplotlib' in sys.modules)"
    )

    def loaded(*args):
        r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=ROOT, timeout=300)
        assert r.returncode == 0, r.stderr
        return r.stdout.splitlines()[-1]

    assert loaded() == "modules 0 False False"
    assert loaded("--usd", str(tmp_path / "a.usdc"), "--png", str(tmp_path / "a.png")) == "modules 0 True True"
