"""Rows for learning (batch/records.py): the force curve along the ramp, the contact patch and the tactile
map at the end of the hold, the lesion labels; each against an answer of its own, and the press without
them unchanged."""

import numpy as np
import pytest

from almsdm_warp import BatchPalpation
from almsdm_warp.batch.records import Records, curve_steps, footprint_frame, lesion_labels
from almsdm_warp.cli.main import main
from almsdm_warp.mesh.tissue_mesh import TissueMesh
from almsdm_warp.tissue.params import TissueParams
from conftest import SCENES, load_cached

PRESS = dict(depth=4e-3, ramp=0.04, hold=0.0, settle=0.01)


@pytest.fixture(scope="module")
def stomach():
    return load_cached(SCENES / "stomach.obj")


def plate(size_mm=30.0, n=31):
    """A flat square surface of n x n vertices in the plane z = 0, facing +z (mm in, metres out)."""
    xs = np.linspace(-size_mm / 2, size_mm / 2, n)
    x, y = np.meshgrid(xs, xs, indexing="xy")
    vertices = np.column_stack([x.ravel(), y.ravel(), np.zeros(n * n)])
    k = np.arange(n - 1)
    corner = (k[None, :] + n * k[:, None]).ravel()
    triangles = np.concatenate([np.column_stack([corner, corner + 1, corner + n + 1]), np.column_stack([corner, corner + n + 1, corner + n])])
    return TissueMesh.from_arrays(vertices, triangles)


@pytest.mark.parametrize("kernel", ["exact", "fast", "implicit"])
@pytest.mark.parametrize("radius", [0.0, 5e-3])
def test_the_curve_ends_at_the_peak_of_a_monotone_ramp_and_changes_no_bit(stomach, device, radius, kernel):
    # with no hold the peak is the ramp's largest force: on a ramp whose force only grows, its last sample;
    # the samples are those of the every-step curve at curve_steps; peak and hold as without records
    vertices = np.arange(3, 1000, 111)
    path = {"integrator": "implicit"} if kernel == "implicit" else {"kernel": kernel}

    def press(records):
        b = BatchPalpation(stomach, TissueParams(), rings=2, device=device, probe_radius=radius, records=records, **path)
        return b, b.touch(vertices, PRESS["depth"]).press(**PRESS)

    batch, every = press(Records(curve_points=40))
    assert batch.ramp_steps == 40 and (batch.integrator == "implicit" if kernel == "implicit" else batch.kernel == kernel)
    curve = every.records["force_curve"]
    assert (np.diff(curve, axis=1) >= 0).all()  # monotone here: the claim's premise
    np.testing.assert_array_equal(curve[:, -1], every.peak_force)
    _, five = press(Records(curve_points=5))
    np.testing.assert_array_equal(five.records["force_curve"], curve[:, curve_steps(40, 5)])
    np.testing.assert_allclose(five.records["curve_depth"][0], PRESS["depth"] * np.arange(1, 6) / 5, rtol=1e-15)
    _, plain = press(None)
    assert plain.records == {}
    for name in ("peak_force", "hold_force", "recovery_error"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(every, name))


def test_curve_steps_is_the_first_step_past_each_fraction():
    for ramp, n in ((40, 5), (37, 7), (10, 10), (100, 3), (5, 1)):
        steps = curve_steps(ramp, n)
        for k, s in enumerate(steps):  # brute force: the first step whose depth fraction (s + 1) / ramp reaches (k + 1) / n
            assert s == next(t for t in range(ramp) if (t + 1) * n >= (k + 1) * ramp)
        assert steps[-1] == ramp - 1


def test_patch_and_map_of_a_sphere_on_a_winkler_plate(device):
    # a plate on stiff independent anchors (weak springs): each vertex stays where the sphere leaves it, so the
    # patch is the spherical cap's, pi (2 R d - d^2), and every vertex inside the sphere is in contact
    mesh = plate()
    R, d, n = 20e-3, 2e-3, 8
    tissue = TissueParams(edge_stiffness=0.01, anchor_stiffness=400.0, edge_damping=0.0, anchor_damping=0.2)
    centre_vertex = int(np.argmin(np.linalg.norm(mesh.vertices, axis=1)))
    batch = BatchPalpation(mesh, tissue, rings=2, device=device, probe_radius=R, dt=2.5e-4,
                           records=Records(tactile_size=n))
    result = batch.touch([centre_vertex], d).press(d, 0.02, 0.01, 0.0)
    area = result.records["patch_area"][0]
    from almsdm_warp.tissue.material import vertex_areas

    inside = np.linalg.norm(mesh.vertices - np.array([0.0, 0.0, R - d]), axis=1) < R  # brute force: rest inside
    np.testing.assert_allclose(area, vertex_areas(mesh.vertices, mesh.triangles)[inside].sum(), rtol=0.02)
    np.testing.assert_allclose(area, np.pi * (2 * R * d - d * d), rtol=0.08)
    # the map: its integral is the force along the press; symmetric plate, centred press: centred pressure
    side = 2 * R / n
    tactile = result.records["tactile"][0].reshape(n, n)
    direction = -batch.model.vertex_normal_rest[centre_vertex]
    along = -float(np.dot(batch.hold_reaction.numpy()[0].astype(np.float64), direction))
    np.testing.assert_allclose(tactile.sum() * side * side, along, rtol=1e-5)  # float32 sums (CUDA: 1.03e-6 apart)
    c = (np.arange(n) + 0.5) * side - R
    assert abs((tactile.sum(0) * c).sum() / tactile.sum()) < side / 4 and abs((tactile.sum(1) * c).sum() / tactile.sum()) < side / 4
    assert tactile[0].max() == 0 and tactile[n // 2 - 1 : n // 2 + 1, n // 2 - 1 : n // 2 + 1].min() > 0  # rim empty, centre loaded


def test_the_map_integrates_to_the_hold_force_on_an_organ(stomach, device):
    batch = BatchPalpation(stomach, TissueParams(), rings=3, device=device, probe_radius=8e-3, records=Records(tactile_size=5))
    vertices = np.arange(10, 1000, 140)
    result = batch.touch(vertices, 5e-3).press(5e-3, 0.05, 0.02, 0.01)
    side = 2 * 8e-3 / 5
    directions = -batch.model.vertex_normal_rest[vertices]
    along = -np.einsum("ij,ij->i", batch.hold_reaction.numpy().astype(np.float64), directions)
    np.testing.assert_allclose(result.records["tactile"].sum(axis=1) * side * side, along, rtol=1e-5)
    assert (result.records["patch_area"] > 0).all()


def test_footprint_frame_is_orthonormal_and_normal_to_the_press():
    rng = np.random.default_rng(0)
    for d in [*rng.normal(size=(20, 3)), [1.0, 0, 0], [0, 0, -1.0]]:
        d = np.asarray(d) / np.linalg.norm(d)
        e1, e2 = footprint_frame(d)
        np.testing.assert_allclose(np.array([e1, e2, d]) @ np.array([e1, e2, d]).T, np.eye(3), atol=1e-12)


def test_lesion_labels_against_brute_force():
    # in the footprint: one of many points sampled in the ball lies in the half-cylinder of the probe's radius
    # around the press axis, from the contact inward (cases where a 5% larger or smaller ball answers otherwise
    # are at the edge, within the sampling: skipped); the distance: the nearest sampled point of the sphere
    rng = np.random.default_rng(3)
    u = rng.normal(size=(8000, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    ball = u * rng.random(8000)[:, None] ** (1 / 3)

    def hit(p, d, centre, radius, probe):
        x = centre + radius * ball - p
        t = x @ d
        return bool(((t >= 0) & (np.linalg.norm(x - t[:, None] * d, axis=1) <= probe)).any())

    checked, seen = 0, set()
    for _ in range(150):
        p, d = rng.normal(size=3) * 10e-3, rng.normal(size=3)
        d /= np.linalg.norm(d)
        centre, radius, probe = rng.normal(size=3) * 10e-3, rng.uniform(2e-3, 6e-3), rng.choice([1e-3, 4e-3])
        inside, distance = lesion_labels(p[None], d[None], centre, radius, probe)
        sign = -1.0 if np.linalg.norm(p - centre) < radius else 1.0
        np.testing.assert_allclose(distance[0], sign * np.linalg.norm(centre + radius * u - p, axis=1).min(), atol=0.05 * radius)
        answers = {hit(p, d, centre, radius * f, probe) for f in (0.95, 1.0, 1.05)}
        if len(answers) == 1:
            answer = answers.pop()
            assert bool(inside[0]) == answer
            checked, seen = checked + 1, seen | {answer}
    assert checked > 100 and seen == {True, False}


def test_a_sweep_and_a_dataset_write_the_rows(tmp_path, capsys):
    from almsdm_warp.batch import dataset as ds
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE

    fast = ["--ramp-s", "0.02", "--hold-s", "0.01", "--settle-s", "0.01", "--dt-ms", "0.5"]
    rows = ["sweep", "stomach", "--points", "8", "--chunk", "3", *fast, "--curve-points", "4", "--tactile-size", "3"]
    assert main([*rows, "--out", str(tmp_path / "s.csv")]) == 0
    text = (tmp_path / "s.csv").read_text().splitlines()[0].split(",")
    assert text[-18:] == [*(f"force_curve_N[{k}]" for k in range(4)), *(f"force_curve_depth_mm[{k}]" for k in range(4)), "patch_area_mm2",
                          *(f"tactile_map_kPa[{k}]" for k in range(9))]
    for suffix in (".npz", ".parquet"):  # each written as its chunks come (NpzRows, ParquetRows): the CSV's numbers
        assert main([*rows, "--out", str(tmp_path / f"s{suffix}")]) == 0
    layout = SWEEP_TABLE.__class__(SWEEP_TABLE.name, {**SWEEP_TABLE.dtypes, **Records(4, 3).dtypes()})
    tables = [layout.read(tmp_path / f"s{suffix}") for suffix in (".csv", ".npz", ".parquet")]
    assert tables[0]["force_curve_N"].shape == (8, 4) and tables[0]["tactile_map_kPa"].shape == (8, 9)
    for c in layout.dtypes:
        np.testing.assert_array_equal(tables[1][c], tables[0][c])
        np.testing.assert_array_equal(tables[2][c], tables[0][c])
    for suffix in (".npz", ".parquet"):
        (tmp_path / f"s{suffix}").unlink()
    assert main(["sweep", "paper_stomach", "--points", "8", *fast, "--tactile-size", "3", "--out", str(tmp_path / "p.csv")]) == 2
    assert "--tactile-size 3: the patch and tactile map need a spherical probe" in capsys.readouterr().err
    assert main(["sweep", "stomach", "--points", "8", *fast, "--curve-points", "50", "--out", str(tmp_path / "p.csv")]) == 2
    assert "--curve-points 50: the ramp has only 40 frame(s)" in capsys.readouterr().err
    assert main(["sweep", "stomach", "--points", "8", *fast, "--lesion-labels", "--out", str(tmp_path / "p.csv")]) == 2
    assert "--lesion-labels: scene stomach has no [lesion]" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv"]
    # a scene's lesion labels its sweep's presses: the distance's sign says which contact vertices lie inside it
    from almsdm_warp.scene.loader import resolve_scene_or_mesh

    assert main(["sweep", "stomach_lesion", "--points", "30", *fast, "--lesion-labels", "--out", str(tmp_path / "l.npz")]) == 0
    lesion = resolve_scene_or_mesh("stomach_lesion").lesion
    labelled = SWEEP_TABLE.__class__(SWEEP_TABLE.name, {**SWEEP_TABLE.dtypes, **Records(lesion_labels=True).dtypes(lesion=True)}).read(tmp_path / "l.npz")
    mesh = load_cached(SCENES / "stomach.obj")
    np.testing.assert_array_equal(labelled["lesion_distance_mm"] < 0, lesion.vertex_inside(mesh.vertices[labelled["vertex"]]))
    assert 0 < labelled["lesion_in_footprint"].sum() < 30 and (labelled["lesion_in_footprint"][labelled["lesion_distance_mm"] < 0] == 1).all()
    (tmp_path / "l.npz").unlink()
    spec = tmp_path / "spec.toml"
    spec.write_text('[dataset]\nscenes = ["stomach"]\npoints = 5\nmaps = "none"\ncsv = true\ncurve_points = 3\ntactile_size = 2\n'
                    'lesion_labels = true\n[press]\nramp_s = 0.03\nhold_s = 0.01\nsettle_s = 0.01\n'
                    '[lesions]\ncount = 1\ndepth_mm = 5.0\nradii_mm = [15.0]\nstiffness_factors = [4.0]\n')
    assert main(["sweep", "--dataset", str(spec), "--out", str(tmp_path / "d")]) == 0
    layout = ds.dataset_layout(Records(3, 2, True))
    npz, csv = layout.read(tmp_path / "d" / "table.npz"), layout.read(tmp_path / "d" / "table.csv")
    assert list(npz) == list(layout.dtypes) and npz["force_curve_N"].shape == (10, 3) and npz["tactile_map_kPa"].shape == (10, 4)
    for c in layout.dtypes:
        np.testing.assert_array_equal(csv[c], npz[c])
    base = npz["lesion_id"] == 0
    assert (npz["lesion_in_footprint"][base] == 0).all() and np.isnan(npz["lesion_distance_mm"][base]).all()
    mesh = load_cached(SCENES / "stomach.obj")
    centre = np.array([npz[f"lesion_{a}_mm"][~base][0] for a in "xyz"]) * 1e-3
    inside = np.linalg.norm(mesh.vertices[npz["vertex"][~base]] - centre, axis=1) < 15e-3
    np.testing.assert_array_equal(npz["lesion_distance_mm"][~base] < 0, inside)
    # the item tables are sweep tables with the record columns; a default dataset's table is unchanged
    assert SWEEP_TABLE.dtypes.items() <= ds.dataset_layout(Records()).dtypes.items()
    assert ds.dataset_layout(Records()) is ds.DATASET_TABLE
