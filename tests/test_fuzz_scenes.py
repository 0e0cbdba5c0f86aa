"""Fuzzing scene files (hypothesis): the shipped scenes with values replaced (NaN, inf, zero,
negative, huge, wrong types), keys removed or misspelt, and random bytes; loaded with
load_scene and run through the command line. Each ends in a scene (or a result) or one line
that names the file; never another exception, a traceback, or a half-written output."""

import math
import shutil
import tempfile
from pathlib import Path

import pytest
from conftest import SCENES
from fuzzing import check_outcome, corruptions, fuzz_settings, record, run_main
from helpers import load_or_record_error
from hypothesis import given
from hypothesis import strategies as st

from almsdm_warp.errors import InputError
from almsdm_warp.scene.loader import SCHEMA, Scene, load_scene

KEYS = [(section, key) for section, keys in SCHEMA.items() for key in keys]
TOML_VALUES = ["nan", "-nan", "inf", "-inf", "0", "0.0", "-0.0", "-1", "-1e-300", "1e-300", "5e-324", "1e300", "1.7976931348623157e308",
               "1e-9", "1", "1000000", "9223372036854775807", "-9223372036854775808", '"10"', "true", "[1, 2]", "{ a = 1 }",
               "1979-05-27", '""', '"stomach.obj"', '"/no/such.obj"', '"."']


def scene_text(name):
    return (SCENES / f"paper_{name}.toml").read_text()  # the paper model: KEYS edits its [tissue] keys


def set_value(text, section, key, value):
    """The scene text with `key` in [section] set to `value` (a TOML literal), added if absent."""
    lines = text.splitlines()
    current = None
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped.startswith("["):
            current = stripped.strip("[]")
        elif current == section and stripped.split("=")[0].strip() == key:
            lines[i] = f"{key} = {value}"
            return "\n".join(lines) + "\n"
    return text + f"\n[{section}]\n{key} = {value}\n" if f"[{section}]" not in text else text.replace(
        f"[{section}]", f"[{section}]\n{key} = {value}", 1)


def drop_key(text, section, key):
    lines, current, out = text.splitlines(), None, []
    for line in lines:
        stripped = line.strip()
        if stripped.startswith("["):
            current = stripped.strip("[]")
        if current == section and stripped.split("=")[0].strip() == key:
            continue
        out.append(line)
    return "\n".join(out) + "\n"


@st.composite
def edited_scenes(draw):
    """(description, scene text) for one to three edits of a shipped scene."""
    name = draw(st.sampled_from(["stomach", "liver"]))
    text = scene_text(name)
    edits = []
    for _ in range(draw(st.integers(1, 3))):
        section, key = draw(st.sampled_from(KEYS))
        action = draw(st.sampled_from(["value", "value", "value", "drop", "typo", "unknown section"]))
        if action == "value":
            value = draw(st.sampled_from(TOML_VALUES) | st.floats(allow_nan=False).map(lambda x: repr(x).replace("inf", "inf")))
            text = set_value(text, section, key, value)
            edits.append(f"{key}={value}")
        elif action == "drop":
            text = drop_key(text, section, key)
            edits.append(f"no {key}")
        elif action == "typo":
            text = text.replace(f"\n{key} ", f"\n{key[:-1]} ", 1)
            edits.append(f"typo {key}")
        else:
            text += "\n[tisue]\nx = 1\n"
            edits.append("unknown section")
    return f"{name}: " + ", ".join(edits), text


def write_scene(folder: Path, name: str, text) -> Path:
    for mesh in ("stomach.obj", "liver.vtu"):
        shutil.copy(SCENES / mesh, folder / mesh)
    path = folder / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def load_or_error(path, test, case):
    """load_scene(path): a scene with sane values or a one-line InputError naming the file."""
    scene = load_or_record_error(load_scene, path, test, case)
    if scene is None:
        return None
    assert isinstance(scene, Scene)
    t, p = scene.tissue, scene.press
    for value in (t.density, t.thickness, t.edge_stiffness, t.edge_damping, t.anchor_stiffness, t.anchor_damping,
                  p.depth, p.ramp, p.hold, p.settle, scene.scale_mm):
        assert math.isfinite(value) and value >= 0
    assert t.density > 0 and t.edge_stiffness > 0 and p.depth > 0 and isinstance(scene.rings, int) and scene.rings >= 1
    record(test, case, "ok")
    return scene


@fuzz_settings(60)
@given(edit=edited_scenes())
def test_edited_scene_files_load_or_fail_clearly(edit):
    description, text = edit
    with tempfile.TemporaryDirectory() as tmp:
        load_or_error(write_scene(Path(tmp), "scene.toml", text), "scene_edit", description.split(":")[1].split("=")[0].strip())


@fuzz_settings(40)
@given(data=st.data())
def test_corrupted_scene_bytes(data):
    name = data.draw(st.sampled_from(["stomach", "liver"]))
    description, corrupted, _ = data.draw(corruptions(scene_text(name).encode(), {".toml"}))
    with tempfile.TemporaryDirectory() as tmp:
        kind = description.split()[0] if not description[0].isdigit() else description.split()[1]
        load_or_error(write_scene(Path(tmp), "scene.toml", corrupted), "scene_bytes", f".toml {kind}")


@fuzz_settings(8)
@given(edit=edited_scenes(), integrator=st.sampled_from(["explicit", "implicit"]))
def test_edited_scene_through_the_command_line(edit, integrator):
    """Palpate an edited scene (its own protocol, shortened where it would run long)."""
    description, text = edit
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        path = write_scene(folder, "scene.toml", text)
        out = folder / "out.json"
        argv = ["palpate", str(path), "--integrator", integrator, "--json", str(out), "--rings", "2"]
        scene = None
        try:
            scene = load_scene(path)
        except InputError:
            pass
        if scene is not None and (scene.press.ramp + scene.press.hold + scene.press.settle) > 0.05:
            argv += ["--ramp-s", "0.01", "--hold-s", "0.01", "--settle-s", "0.02"]
        code, stdout, err = run_main(argv, fuzz_limits=True)
        outcome = check_outcome(code, stdout, err, out, folder)
        record("scene_cli", description.split(":")[1].strip()[:60], outcome, err.strip().splitlines()[-1] if err.strip() else "")


# -- regressions found by the fuzzing above ---------------------------------------------------

@pytest.mark.parametrize(
    "key, value",
    [
        ("edge_stiffness_N_per_m", "1e300"),  # float32 overflow: a RuntimeWarning on stderr, "critical step 2e-149 ms"
        ("density_kg_per_m3", "1e-300"),  # masses of 0 in float32: NaN from the first step
        ("anchor_damping_Ns_per_m", "5e-324"),
        ("thickness_mm", "1e40"),
    ],
)
def test_scene_values_beyond_float32_are_one_line_errors(key, value, tmp_path):
    section = next(s for s, keys in SCHEMA.items() if key in keys)
    path = write_scene(tmp_path, "scene.toml", set_value(scene_text("stomach"), section, key, value))
    with pytest.raises(InputError, match=rf"^{path}: \[{section}\] {key} must be 0 or of magnitude 1e-12 to 1e\+12"):
        load_scene(path)
    out = tmp_path / "out.json"
    code, stdout, err = run_main(["palpate", path, "--json", out])
    check_outcome(code, stdout, err, out, tmp_path)
    assert code == 2 and "Warning" not in err


def test_si_check_names_the_scene_file(tmp_path):
    """thickness_mm = 1e-11 passes in mm but is 1e-14 m in SI, below the bound: the error from the
    SI check now starts with the file's path like every other scene error."""
    path = write_scene(tmp_path, "scene.toml", set_value(scene_text("stomach"), "tissue", "thickness_mm", "1e-11"))
    with pytest.raises(InputError, match=rf"^{path}: TissueParams.thickness must be 0 or of magnitude"):
        load_scene(path)


def test_zero_anchor_and_damping_still_run(tmp_path):
    """The bound leaves 0 where the schema allows it: no anchors, no damping is a valid scene (the
    paper's free surface), and it runs."""
    text = scene_text("stomach")
    for key in ("anchor_stiffness_N_per_m", "anchor_damping_Ns_per_m", "edge_damping_Ns_per_m"):
        text = set_value(text, "tissue", key, "0.0")
    path = write_scene(tmp_path, "scene.toml", text)
    scene = load_scene(path)
    assert scene.tissue.anchor_stiffness == 0 and scene.tissue.edge_damping == 0
    code, stdout, err = run_main(["palpate", path, "--integrator", "implicit", "--ramp-s", "0.02", "--hold-s", "0", "--settle-s", "0.02"])
    assert code == 0, err


def test_scene_with_more_rings_than_vertices(tmp_path):
    """rings = 2^63 - 1 in a scene passed every check and crashed in Region (an OverflowError
    from a list of that many empty rings): the command line now refuses more rings than vertices."""
    path = write_scene(tmp_path, "scene.toml", set_value(scene_text("stomach"), "region", "rings", "9223372036854775807"))
    assert load_scene(path).rings == 2**63 - 1  # a valid scene: an integer >= 1
    out = tmp_path / "out.json"
    code, stdout, err = run_main(["palpate", path, "--json", out])
    check_outcome(code, stdout, err, out, tmp_path)
    assert code == 2 and "the scene's [region] rings 9223372036854775807 is more than the mesh's 1002 vertices" in err
