"""`almsdm sweep --dataset`: several scenes and a lesion grid in one run, one table, resumable."""

import json

import numpy as np
import pytest

from almsdm_warp.batch import dataset as ds
from almsdm_warp.batch.sweep_store import Parts
from almsdm_warp.cli.main import main
from almsdm_warp.protocol.palpation import Palpation
from almsdm_warp.scene.loader import resolve_scene_or_mesh
from almsdm_warp.tissue.lesion import Lesion
from conftest import SCENES

POINTS = 6
SPEC = f"""
[dataset]
scenes = ["stomach", "{SCENES / 'paper_liver.toml'}"]  # a scene file (the liver on the paper's constants: every point pressable)
points = {POINTS}
dt_ms = 0.25  # one explicit step a frame even in the 6x lesion (see the palpation check below)
chunk = 3
maps = "none"
csv = true
parquet = true
[press]
ramp_s = 0.05
hold_s = 0.05
settle_s = 0.05
[lesions]
count = 1
depth_mm = 5.0
radii_mm = [15.0]
stiffness_factors = [3.0, 6.0]
"""


def spec_file(folder, text=SPEC):
    path = folder / "spec.toml"
    path.write_text(text)
    return path


def run(spec, out):
    return main(["sweep", "--dataset", str(spec), "--out", str(out)])


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """The dataset of SPEC in one run: (its folder, its table)."""
    folder = tmp_path_factory.mktemp("whole")
    assert run(spec_file(folder), folder / "out") == 0
    return folder / "out", ds.DATASET_TABLE.read(folder / "out" / "table.npz")


def test_one_table_of_every_item_and_point(whole):
    out, table = whole
    # 2 scenes x (baseline + 1 centre x 1 radius x 2 factors) items of POINTS points each
    assert len(table["vertex"]) == 2 * 3 * POINTS
    assert table["scene"].tolist() == ["stomach"] * 3 * POINTS + ["paper_liver"] * 3 * POINTS
    np.testing.assert_array_equal(table["lesion_id"], np.tile(np.repeat([0, 1, 2], POINTS), 2))
    np.testing.assert_array_equal(table["point"], np.tile(np.arange(POINTS), 6))
    base = table["lesion_id"] == 0
    assert np.isnan(table["lesion_x_mm"][base]).all() and (table["lesion_factor"][base] == 1.0).all()
    np.testing.assert_array_equal(np.unique(table["lesion_factor"][~base]), [3.0, 6.0])
    # every item of a scene presses the same points; the CSV copy holds the same numbers
    for scene in ("stomach", "paper_liver"):
        xyz = np.column_stack([table[c][table["scene"] == scene] for c in ("x_mm", "y_mm", "z_mm")]).reshape(3, POINTS, 3)
        np.testing.assert_array_equal(xyz[0], xyz[1])
        np.testing.assert_array_equal(xyz[0], xyz[2])
    text, arrow = ds.DATASET_TABLE.read(out / "table.csv"), ds.DATASET_TABLE.read(out / "table.parquet")
    for c in ds.DATASET_COLUMNS:
        np.testing.assert_array_equal(text[c], table[c])
        np.testing.assert_array_equal(arrow[c], table[c])
    with np.load(out / "table.npz", allow_pickle=False) as z:  # numpy alone reads it, schema included
        schema = json.loads(z["schema"].item())["columns"]
    assert list(schema) == list(ds.DATASET_COLUMNS) and schema["peak_force_N"]["unit"] == "N"
    assert table["scene"].dtype.kind == "U" and table["vertex"].dtype == np.int64
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "items", "table.csv", "table.npz", "table.parquet"]


def test_the_parquet_table_says_what_made_it(whole):
    # each scene's mesh hash, material and law, each item's lesion, the package's version, the units
    from almsdm_warp import __version__
    from almsdm_warp.batch.sweep_plan import mesh_sha256
    from almsdm_warp.export.parquet import read_info

    pytest.importorskip("pyarrow")
    info = read_info(whole[0] / "table.parquet")
    assert info["version"] == __version__ and info["format"] == ds.FORMAT and list(info["scenes"]) == ["stomach", "paper_liver"]
    for name, scene in info["scenes"].items():
        mesh = resolve_scene_or_mesh(name if name == "stomach" else str(SCENES / "paper_liver.toml")).load_mesh()
        assert scene["mesh"]["sha256"] == mesh_sha256(mesh) and scene["law"] and scene["material"]["type"]
    assert [(x["scene"], x["lesion_id"]) for x in info["lesions"]] == [(s, k) for s in info["scenes"] for k in range(3)]
    assert info["lesions"][1]["lesion"]["radius_mm"] == 15.0 and info["lesions"][0]["lesion"] is None


def test_lesion_stiffens_the_points_over_it_as_one_palpation_finds(whole):
    _, table = whole
    scene = resolve_scene_or_mesh("stomach")
    mesh = scene.load_mesh()
    rows = (table["scene"] == "stomach") & (table["lesion_id"] == 2)
    centre = np.array([table[f"lesion_{a}_mm"][rows][0] for a in "xyz"]) * 1e-3
    radius = table["lesion_radius_mm"][rows][0] * 1e-3
    xyz = np.column_stack([table[c][rows] for c in ("x_mm", "y_mm", "z_mm")]) * 1e-3
    over = np.flatnonzero(np.linalg.norm(xyz - centre, axis=1) < radius)
    assert len(over) >= 1
    k = over[0]
    base = table["peak_force_N"][(table["scene"] == "stomach") & (table["lesion_id"] == 0)]
    assert table["peak_force_N"][rows][k] > 2.0 * base[k]
    # beyond the lesion and four rings of ~10 mm edges, the region holds no stiffened spring: the same force
    far = np.linalg.norm(xyz - centre, axis=1) > radius + 0.06
    assert far.sum() >= 1
    np.testing.assert_array_equal(table["peak_force_N"][rows][far], base[far])
    # the same press, one palpation at a time, on a model stiffened by the lesion the table names
    lesion = Lesion(tuple(centre), radius, 6.0)
    edge_scale, anchor_scale = lesion.scales(mesh, scene.tissue)
    palpation = Palpation(mesh, scene.tissue, rings=int(table["rings"][rows][k]), dt=0.25e-3, device="cpu",
                          edge_scale=edge_scale, anchor_scale=anchor_scale, probe_radius=scene.probe_radius,
                          fixed_below=scene.fixed_below)
    palpation.touch(int(table["vertex"][rows][k]), scene.press.depth)
    assert palpation.substeps == 1
    result = palpation.press(depth=scene.press.depth, ramp=0.05, hold=0.05, settle=0.05)
    np.testing.assert_allclose(table["peak_force_N"][rows][k], result.peak_force_N, rtol=1e-5)


def test_interrupted_dataset_resumes_to_the_same_table(whole, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    real_write = Parts.write
    calls = []

    def write_then_stop(self, i, columns):  # stop in the third item, after its first chunk
        if len(calls) == 5:
            raise KeyboardInterrupt
        calls.append(i)
        real_write(self, i, columns)

    monkeypatch.setattr(Parts, "write", write_then_stop)
    assert run(spec_file(tmp_path), out) == 130
    assert not (out / "table.npz").exists()
    assert sorted(p.name for p in (out / "items").iterdir()) == ["stomach_L000.npz", "stomach_L001.npz", "stomach_L002.npz.parts"]
    assert not list(out.rglob(".*.tmp"))  # nothing half-written
    monkeypatch.setattr(Parts, "write", real_write)
    capsys.readouterr()
    assert run(spec_file(tmp_path), out) == 0
    assert "2 item(s) already in" in capsys.readouterr().out
    assert (out / "table.csv").read_text() == (whole[0] / "table.csv").read_text()
    assert not list((out / "items").glob("*.parts"))


def test_a_changed_spec_is_not_resumed_into_the_old_folder(whole, tmp_path, capsys):
    changed = spec_file(tmp_path, SPEC.replace("radii_mm = [15.0]", "radii_mm = [16.0]"))
    before = sorted(p.name for p in (whole[0] / "items").iterdir())
    assert run(changed, whole[0]) == 2
    err = capsys.readouterr().err.strip()
    assert "different spec" in err and "[lesions]" in err and len(err.splitlines()) == 1
    assert sorted(p.name for p in (whole[0] / "items").iterdir()) == before


@pytest.mark.parametrize("edit, words", [
    (("points = 6", "points = 6\npoint_count = 3"), "unknown key 'point_count' in [dataset]"),
    (("radii_mm = [15.0]", "radii_mm = [-2.0]"), "radii_mm value must be > 0"),
    (("radii_mm = [15.0]", "radii_mm = [1.0]"), "holds no vertex, spring or tet"),  # 1 mm at 5 mm under a shell
    (("[lesions]", "[lesion]"), "unknown section 'lesion'"),
])
def test_a_bad_spec_exits_2_with_one_line(tmp_path, capsys, edit, words):
    assert run(spec_file(tmp_path, SPEC.replace(*edit)), tmp_path / "out") == 2
    captured = capsys.readouterr()
    assert words in captured.err and len(captured.err.strip().splitlines()) == 1
    assert "Traceback" not in captured.err
    assert not (tmp_path / "out").exists()


def test_sweep_options_the_spec_decides_are_refused_beside_it(tmp_path, capsys):
    spec = spec_file(tmp_path)
    assert main(["sweep", "stomach", "--dataset", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert main(["sweep", "--dataset", str(spec), "--depth-mm", "5", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "SCENE is decided by the dataset spec" in err[0] and "--depth-mm is decided" in err[1]
    assert not (tmp_path / "out").exists()


# -- items pressed together: the bits of each item pressed as a sweep of its own -------------------
LIVER = """
[dataset]
scenes = ["liver"]  # neo-Hookean tets over a support: one explicit step a frame, two in the 8x lesion
points = 3
rings = 2
dt_ms = 1.0
maps = "none"
[press]
depth_mm = 4.0
ramp_s = 0.02
hold_s = 0.01
settle_s = 0.01
[lesions]
count = 1
depth_mm = 5.0
radii_mm = [60.0]
stiffness_factors = [8.0]
"""


RECORDS = SPEC.replace(f'scenes = ["stomach", "{SCENES / "paper_liver.toml"}"]', 'scenes = ["stomach"]').replace(
    "csv = true", "csv = true\ncurve_points = 3\ntactile_size = 2\nlesion_labels = true")
"""SPEC on the stomach (a sphere: the tactile map needs one) with every row for learning."""


def pressed(spec_path, out, devices, together):
    spec = ds.load_spec(spec_path)
    items = ds.plan_items(spec)
    folder = ds.DatasetFolder(out, items, spec)
    ds.press_dataset(folder, folder.open(), devices, together=together)
    return folder.gather()


@pytest.mark.parametrize("text, devices", [
    (SPEC, ["cpu"]),  # a sphere on a membrane, the paper's constants on tet edges; chunks of 3
    (SPEC.replace('dt_ms = 0.25', 'dt_ms = 0.25\nintegrator = "implicit"'), ["cpu"]),
    (LIVER, ["cpu"]),  # a tet law: the lesion's item needs more substeps than the baseline's
    (SPEC.replace("chunk = 3", "chunk = 2"), ["cpu", "cpu"]),  # two devices, each pressing some items of each chunk
    (RECORDS, ["cpu"]),  # the rows for learning: force curves, contact patches and tactile maps, lesion labels
])
def test_items_pressed_together_give_the_bits_of_each_pressed_alone(tmp_path, text, devices):
    spec = spec_file(tmp_path, text)
    alone = pressed(spec, tmp_path / "alone", ["cpu"], together=False)
    together = pressed(spec, tmp_path / "together", devices, together=True)
    assert list(together) == list(alone) and set(ds.DATASET_COLUMNS) <= set(alone)
    assert ("tactile_map_kPa" in alone) == (text is RECORDS)
    for c in alone:
        np.testing.assert_array_equal(together[c], alone[c], err_msg=c)
    assert len(together["vertex"]) > 0


def test_the_liver_items_take_the_substeps_each_needs(tmp_path):
    """The liver spec above groups its items by substeps: the baseline's and the lesion's differ (the
    test above then holds each group to its own sweep's bits)."""
    from almsdm_warp.batch.dataset_press import DeviceStack, ItemWork, stacks_of
    from almsdm_warp.batch.sweep_times import SweepTimes

    items = ds.plan_items(ds.load_spec(spec_file(tmp_path, LIVER)))
    stack = stacks_of([ItemWork(item, None, {0}) for item in items])[0]
    device = DeviceStack(stack, "cpu")
    p = stack.plan
    groups = device.substep_groups(int(p.point_rings[0]), p.vertices, range(len(items)), SweepTimes())
    substeps = {k: key[1] for key, members in groups.items() for k in members}
    # each item's own batch of the same presses, as its sweep plans it
    from almsdm_warp.batch.sweep_lanes import RingBatches
    from almsdm_warp.batch.sweep_plan import sweep_critical_dt

    for k, item in enumerate(items):
        batch = RingBatches(item.plan, item.plan.model("cpu"), sweep_critical_dt(item.plan)).get(int(p.point_rings[0]))
        batch.touch(p.vertices, p.depth)
        assert batch.substeps == substeps[k]
    assert substeps[1] > substeps[0]


@pytest.mark.parametrize("devices, points, chunk", [(1, 6, 3), (2, 6, 6), (4, 40000, 40000), (1, 40000, 40000)])
def test_units_press_each_items_missing_chunks_once(devices, points, chunk):
    """units_of: every (item, chunk) still to press in exactly one unit, none over LAUNCH_PRESSES presses,
    and on several devices at least two units a device where the items allow."""
    from types import SimpleNamespace

    from almsdm_warp.batch.dataset_press import LAUNCH_PRESSES, SceneStack, units_of

    plan = SimpleNamespace(chunks=[(b, min(b + chunk, points)) for b in range(0, points, chunk)])
    todo = [set(range(len(plan.chunks))), {len(plan.chunks) - 1}, set(), set(range(len(plan.chunks)))] * 4
    works = [SimpleNamespace(item=SimpleNamespace(plan=plan), todo=t) for t in todo]
    units = units_of([SceneStack(works)], devices)
    pressed = sorted((k, c) for _, c, members in units for k in members)
    assert pressed == sorted((k, c) for k, w in enumerate(works) for c in w.todo)
    assert all(len(m) * (plan.chunks[c][1] - plan.chunks[c][0]) <= LAUNCH_PRESSES for _, c, m in units)
    assert len(units) >= min(2 * devices, sum(len(w.todo) for w in works))


def test_a_scene_of_more_items_than_a_stack_holds_gives_the_same_bits(tmp_path, monkeypatch):
    """A scene's items cut into stacks (each its own StackedModel: a large organ's) press as each alone."""
    from almsdm_warp.batch import dataset_press

    monkeypatch.setattr(dataset_press, "stack_limit", lambda mesh: 2)
    spec = spec_file(tmp_path, SPEC.replace("chunk = 3", "chunk = 6"))
    alone = pressed(spec, tmp_path / "alone", ["cpu"], together=False)
    together = pressed(spec, tmp_path / "together", ["cpu"], together=True)
    for c in ds.DATASET_COLUMNS:
        np.testing.assert_array_equal(together[c], alone[c], err_msg=c)


@pytest.mark.parametrize("items, points, gpus, volumetric", [(13, 40000, 2, False), (13, 100000, 2, False), (26, 100000, 2, False),
                                                             (13, 100000, 4, False), (13, 60000, 3, False), (13, 3100, 2, True),
                                                             (13, 1000, 2, True), (13, 3100, 4, True)])
def test_units_on_several_gpus_split_evenly(items, points, gpus, volumetric):
    """The default chunks of several GPUs (item_chunk) and units_of's order: the GPUs, each taking the next
    unit when free (a unit's time its presses), finish within 2% of an even split; one chunk an item (one
    GPU's default, and several GPUs' for small items) would leave 13 items on two GPUs at 7 against 6. A
    tet law's items are cut from far fewer points (the liver's 3,100 of the example at 10,000 a scene)."""
    import heapq
    from types import SimpleNamespace

    from almsdm_warp.batch.dataset import item_chunk, split_points
    from almsdm_warp.batch.dataset_press import SceneStack, units_of

    def makespan(chunk):
        plan = SimpleNamespace(chunks=[(b, min(b + chunk, points)) for b in range(0, points, chunk)])
        works = [SimpleNamespace(item=SimpleNamespace(plan=plan), todo=set(range(len(plan.chunks)))) for _ in range(items)]
        free = [0.0] * gpus
        for _, c, members in units_of([SceneStack(works)], gpus):
            heapq.heappush(free, heapq.heappop(free) + len(members) * (plan.chunks[c][1] - plan.chunks[c][0]))
        return max(free)

    assert makespan(item_chunk(points, True, gpus, volumetric)) <= 1.02 * items * points / gpus
    if (items, gpus) == (13, 2):
        assert makespan(item_chunk(points, True, 1, volumetric)) == 7 * points
    small = split_points(volumetric) * gpus - 1
    assert item_chunk(small, True, gpus, volumetric) == small  # small items stay whole
    if volumetric:  # a springs item of as many points stays whole: its presses are some 100x cheaper
        assert item_chunk(points, True, gpus, False) == points
