"""`almsdm sweep`: points spread over the surface, files that round-trip, resuming, the lesion found."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from almsdm_warp.batch.sampling import Sampling, area_uniform_points, farthest_points, pressable_points, sample_points
from almsdm_warp.batch.sweep import SweepDevice, run_local
from almsdm_warp.batch.sweep_lanes import Lane, RingBatches, press_chunk
from almsdm_warp.batch.sweep_plan import COLUMNS, SWEEP_TABLE, SweepPlan, default_chunk, default_tail, sweep_critical_dt
from almsdm_warp.batch.sweep_store import Parts
from almsdm_warp.batch.sweep_times import SweepTimes, union_length
from almsdm_warp.cli.main import main
from almsdm_warp.scene.loader import resolve_scene_or_mesh
from conftest import SCENES, load_cached
from helpers import stop_after_writes

FAST = ["--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05", "--dt-ms", "0.5"]


@pytest.fixture(scope="module")
def stomach():
    return load_cached(SCENES / "stomach.obj")


def test_points_spread_evenly_over_the_vertices(stomach):
    points, vertices = sample_points(stomach, 50)
    assert len(np.unique(vertices)) == 50
    np.testing.assert_array_equal(points, stomach.vertices[vertices])
    # farthest-point sampling: every surface vertex is no farther from a chosen point than the
    # closest two chosen points are from each other (the greedy covering guarantee)
    tree = cKDTree(points)
    covering = tree.query(stomach.vertices[stomach.surface_vertices])[0].max()
    separation = tree.query(points, k=2)[0][:, 1].min()
    assert covering <= separation + 1e-12


def brute_farthest_points(p, n, start):
    # farthest-point sampling as written in the textbook: every point's distance to the chosen set
    # updated after each choice
    d = p - p[start]
    chosen, d2 = [start], np.einsum("ij,ij->i", d, d)
    for _ in range(1, n):
        chosen.append(k := int(np.argmax(d2)))
        d = p - p[k]
        d2 = np.minimum(d2, np.einsum("ij,ij->i", d, d))
    return np.array(chosen)


@pytest.mark.parametrize("tree", [True, False])
def test_farthest_points_as_every_point_updated_each_time(stomach, monkeypatch, tree):
    # the k-d tree's balls (only the points a choice can bring nearer) choose the same points, in the
    # same order, as updating every point: on a dense area sample of the stomach, on clusters with
    # exact duplicates and equal distances (a grid), and asking for every point
    monkeypatch.setattr("almsdm_warp.batch.sampling.TREE_WORK", 0 if tree else 10**18)
    monkeypatch.setattr("almsdm_warp.batch.sampling.TREE_MIN", 0)
    rng = np.random.default_rng(3)
    dense = area_uniform_points(stomach.vertices, stomach.triangles, 3000, 0)
    grid = np.stack(np.meshgrid(*[np.arange(6.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3) * 1e-3
    clusters = np.concatenate([rng.normal(c, 1e-3, (150, 3)) for c in rng.uniform(-0.05, 0.05, (4, 3))])
    clusters = np.concatenate([clusters, clusters[:40]])
    for p, n in ((dense, 1000), (grid, len(grid)), (clusters, len(clusters))):
        np.testing.assert_array_equal(farthest_points(p, n, 7), brute_farthest_points(p, n, 7))


def test_more_points_than_vertices_snap_to_the_nearest(stomach):
    points, vertices = sample_points(stomach, 1500)
    assert len(points) == 1500
    # each point lies in some triangle: on its plane, with barycentric coordinates in [0, 1]
    t = stomach.vertices[stomach.triangles]
    a, e1, e2 = t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    n = np.cross(e1, e2)
    d = points[:, None, :] - a[None]
    off_plane = np.abs(np.einsum("ptk,tk->pt", d, n)) / np.linalg.norm(n, axis=1)
    g = np.stack([np.einsum("tk,tk->t", e1, e1), np.einsum("tk,tk->t", e1, e2), np.einsum("tk,tk->t", e2, e2)])
    r1, r2 = np.einsum("ptk,tk->pt", d, e1), np.einsum("ptk,tk->pt", d, e2)
    det = g[0] * g[2] - g[1] ** 2
    u, w = (g[2] * r1 - g[1] * r2) / det, (g[0] * r2 - g[1] * r1) / det
    inside = (off_plane < 1e-9) & (u >= -1e-9) & (w >= -1e-9) & (u + w <= 1 + 1e-9)
    assert inside.any(axis=1).all()
    d = np.linalg.norm(points[:, None, :] - stomach.vertices[None, :, :], axis=2)
    np.testing.assert_allclose(np.linalg.norm(points - stomach.vertices[vertices], axis=1), d.min(axis=1))


def test_sampling_behind_the_caller_gives_trimeshs_points_snapped(stomach, monkeypatch):
    # the area-uniform path sampled block by block on threads: trimesh's points for the seed, each
    # snapped to its nearest surface vertex (brute force), the first blocks usable before the last
    import trimesh

    monkeypatch.setattr(Sampling, "BLOCK", 1000)
    n = 25000
    sampling = Sampling(stomach, n)
    sampling.wait(3000)
    tm = trimesh.Trimesh(vertices=stomach.vertices, faces=stomach.triangles, process=False)
    expected = trimesh.sample.sample_surface(tm, n, seed=0)[0]
    np.testing.assert_array_equal(sampling.points[:3000], expected[:3000])
    sampling.wait()
    assert sampling.seconds > 0
    np.testing.assert_array_equal(sampling.points, expected)
    surface = stomach.vertices[stomach.surface_vertices]
    for b in range(0, n, 5000):
        d = np.linalg.norm(expected[b : b + 5000, None, :] - surface[None], axis=2)
        np.testing.assert_array_equal(sampling.vertices[b : b + 5000], stomach.surface_vertices[d.argmin(axis=1)])


def test_a_sweep_pressing_while_its_points_are_sampled_writes_the_same_table(tmp_path, monkeypatch):
    # more points than the surface's vertices on the area-uniform path: chunks start while later blocks
    # are sampled, regions come from a table of every surface vertex, the key is hashed on the writer's
    # thread; the table equals that of a plan whose points were all sampled first
    fast = ["sweep", "--points", "1100", "--chunk", "256", "--rings", "1", "--ramp-s", "0.004", "--hold-s", "0",
            "--settle-s", "0.004", "--dt-ms", "1", "--no-progress"]
    monkeypatch.setattr("almsdm_warp.batch.sampling.FPS_MAX", 100)
    monkeypatch.setattr(Sampling, "BLOCK", 128)
    behind = tmp_path / "behind.npz"
    assert main([*fast, "--out", str(behind)]) == 0
    monkeypatch.setattr("almsdm_warp.batch.sampling.start_sampling", lambda mesh, n, fixed_below=None: (*pressable_points(mesh, n, fixed_below), None))
    first = tmp_path / "first.npz"
    assert main([*fast, "--out", str(first)]) == 0
    a, b = SWEEP_TABLE.read(behind), SWEEP_TABLE.read(first)
    for c in COLUMNS:
        np.testing.assert_array_equal(a[c], b[c], err_msg=c)


def test_area_uniform_points_are_trimeshs_and_uniform(stomach):
    # the same points as trimesh's sampler for the same seed (so a sweep's plan, and its resume, are
    # unchanged), and uniform by area: each triangle's share of points against its share of the area
    import trimesh

    tm = trimesh.Trimesh(vertices=stomach.vertices, faces=stomach.triangles, process=False)
    for n, seed in ((1, 0), (4097, 3)):
        np.testing.assert_array_equal(area_uniform_points(stomach.vertices, stomach.triangles, n, seed),
                                      trimesh.sample.sample_surface(tm, n, seed=seed)[0])
    n = 200000
    points = area_uniform_points(stomach.vertices, stomach.triangles, n, 1)
    # the z-band below the median height holds the share of area below it (areas of the triangles'
    # pieces are not needed: triangles wholly below or above the band's edge bound the share)
    t = stomach.vertices[stomach.triangles]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    z = np.median(points[:, 2])
    below, above = area[t[:, :, 2].max(axis=1) <= z].sum(), area[t[:, :, 2].min(axis=1) > z].sum()
    share = np.mean(points[:, 2] <= z) * area.sum()
    assert below - 0.01 * area.sum() <= share <= area.sum() - above + 0.01 * area.sum()


def test_tables_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    cols = {c: rng.normal(size=9) for c in COLUMNS}
    cols["vertex"] = rng.integers(0, 1000, size=9)
    cols["rings"] = rng.integers(1, 9, size=9)
    cols["recovery_error_mm"][3] = np.nan
    for suffix in (".csv", ".npz"):
        back = SWEEP_TABLE.read(SWEEP_TABLE.write(tmp_path / f"t{suffix}", cols))
        for c in COLUMNS:
            np.testing.assert_array_equal(back[c], cols[c])  # exact: CSV floats are written with repr
        assert back["vertex"].dtype == np.int64 and back["rings"].dtype == np.int64
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv", "t.npz"]  # no temporary left
    # a table of issue 6 (no rings column) still reads
    old = tmp_path / "old.csv"
    text = (tmp_path / "t.csv").read_text().splitlines()
    old.write_text("\n".join(line.rsplit(",", 1)[0] for line in text) + "\n")
    back = SWEEP_TABLE.read(old)
    assert "rings" not in back
    np.testing.assert_array_equal(back["peak_force_N"], cols["peak_force_N"])


def test_sweep_finds_the_lesion(tmp_path, capsys):
    # the same points and step with and without the lesion: far from it, the same numbers; the
    # stiffest point of the lesion scene is inside the lesion and stiffer than anything without it
    lesion_out, plain_out = tmp_path / "lesion.csv", tmp_path / "plain.npz"
    assert main(["sweep", "stomach_lesion", "--points", "48", "--out", str(lesion_out), *FAST]) == 0
    assert main(["sweep", "stomach", "--points", "48", "--out", str(plain_out), *FAST]) == 0
    a, b = SWEEP_TABLE.read(lesion_out), SWEEP_TABLE.read(plain_out)
    np.testing.assert_array_equal(a["vertex"], b["vertex"])
    lesion = resolve_scene_or_mesh("stomach_lesion").lesion
    xyz = np.column_stack([a["x_mm"], a["y_mm"], a["z_mm"]]) * 1e-3
    dist = np.linalg.norm(xyz - np.array(lesion.center), axis=1)
    k = int(np.argmax(a["stiffness_N_per_mm"]))
    assert dist[k] <= lesion.radius
    assert a["stiffness_N_per_mm"][k] > 2 * b["stiffness_N_per_mm"].max()
    far = dist > lesion.radius + 0.06  # beyond 4 rings of ~10 mm edges, and some
    assert far.sum() > 10
    np.testing.assert_array_equal(a["stiffness_N_per_mm"][far], b["stiffness_N_per_mm"][far])
    assert "stiffest at vertex" in capsys.readouterr().out


def test_interrupted_sweep_resumes_to_the_same_file(tmp_path, monkeypatch, capsys):
    whole = tmp_path / "whole.csv"
    assert main(["sweep", "--points", "20", "--chunk", "6", "--out", str(whole), *FAST]) == 0
    out = tmp_path / "resumed.csv"
    real_write = stop_after_writes(monkeypatch, 2)
    assert main(["sweep", "--points", "20", "--chunk", "6", "--out", str(out), *FAST]) == 130
    assert not out.exists()
    assert len(list((tmp_path / "resumed.csv.parts").glob("chunk_*.npz"))) == 2
    monkeypatch.setattr(Parts, "write", real_write)
    capsys.readouterr()
    assert main(["sweep", "--points", "20", "--chunk", "6", "--out", str(out), *FAST]) == 0
    assert "resuming: 2 of 4 chunks" in capsys.readouterr().out
    assert out.read_text() == whole.read_text()
    assert not (tmp_path / "resumed.csv.parts").exists()
    # parts of another sweep are not mixed in
    (tmp_path / "other.csv.parts").mkdir()
    (tmp_path / "other.csv.parts" / "plan.json").write_text('{"key": "0000"}')
    assert main(["sweep", "--points", "20", "--out", str(tmp_path / "other.csv"), *FAST]) == 2
    assert "different sweep" in capsys.readouterr().err


def test_pipelined_sweep_gives_the_serial_bits(stomach, tmp_path):
    # the pipeline (two chunks in flight a device, read-back and writing on the side), on one device
    # or split over two, against the serial path: chunk after chunk, each read and written in turn;
    # per-point ring counts make chunks of several batches
    points, vertices = sample_points(stomach, 12)
    from almsdm_warp.tissue.params import TissueParams

    rings = np.array([3, 2, 3, 3, 2, 2, 3, 3, 3, 2, 3, 3])
    plan = SweepPlan(stomach, TissueParams(), None, None, rings, 5e-4, 0.01, 0.05, 0.05, 0.05, points, vertices, 5)
    results = []
    for devices, pipeline in ((["cpu"], False), (["cpu"], True), (["cpu", "cpu"], True)):
        parts = Parts(tmp_path / f"x{len(devices)}{pipeline}.npz", plan)
        parts.open()
        times = SweepTimes()
        run_local(plan, parts, [0, 1, 2], devices, pipeline=pipeline, times=times)
        results.append(parts.gather())
        assert len(times.host_per_chunk) == (3 if pipeline else 0)
    for other in results[1:]:
        for c in COLUMNS:
            np.testing.assert_array_equal(other[c], results[0][c])
    np.testing.assert_array_equal(results[0]["rings"], rings)


def test_a_tail_of_small_chunks_gives_the_same_table(stomach, tmp_path, device):
    # a GPU sweep's last points in chunks of a quarter (SweepPlan.tail): the chunks cover the points in
    # order, and the pipelined lanes (whose device arrays are then views of the larger chunks') press the
    # same bits as the same plan in whole chunks, on the same device
    from dataclasses import replace

    from almsdm_warp.tissue.params import TissueParams

    points, vertices = sample_points(stomach, 20)
    whole = SweepPlan(stomach, TissueParams(), None, None, 2, 5e-4, 0.01, 0.02, 0.02, 0.02, points, vertices, 8)
    tail = replace(whole, tail=9)
    assert tail.chunks == [(0, 8), (8, 11), (11, 13), (13, 15), (15, 17), (17, 19), (19, 20)]
    assert tail.key() != whole.key()
    tables = []
    for plan in (whole, tail):
        parts = Parts(tmp_path / f"t{plan.tail}.npz", plan)
        parts.open()
        run_local(plan, parts, list(range(len(plan.chunks))), [device], pipeline=True, times=SweepTimes())
        tables.append(parts.gather())
    for c in COLUMNS:
        np.testing.assert_array_equal(tables[1][c], tables[0][c])


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_writers_on_several_threads_write_the_table_and_its_parts(stomach, tmp_path, suffix):
    # a sweep on several GPUs writes with a thread a device (sweep.Writer): chunks handed over in any order
    # give the table's rows in place, each part file with its checksum, and the same table as np.savez's
    from almsdm_warp.batch.sweep import Writer
    from almsdm_warp.tissue.params import TissueParams

    if suffix == ".parquet":
        pytest.importorskip("pyarrow")
    n, rng = 4000, np.random.default_rng(3)
    points, vertices = sample_points(stomach, n)
    plan = SweepPlan(stomach, TissueParams(), None, None, 2, 5e-4, 0.01, 0.02, 0.02, 0.02, points, vertices, 400, tail=1200)
    table = {c: (rng.integers(0, 1 << 40, n) if c in ("vertex", "rings") else rng.random(n)) for c in COLUMNS}
    out = tmp_path / f"t{suffix}"
    parts = Parts(out, plan)
    parts.open()
    parts.rows_file = plan.table.rows(out, n)
    writer = Writer(parts, SweepTimes(), threads=3)
    for i in rng.permutation(len(plan.chunks)):
        b, e = plan.chunks[i]
        writer.put(int(i), {c: v[b:e] for c, v in table.items()})
    writer.close()
    if parts.rows_file is not None:
        parts.rows_file.finish(parts.gather())
    else:
        plan.table.write(out, parts.gather())
    assert sorted(parts.sums) == list(range(len(plan.chunks)))
    again = Parts(out, plan)
    assert sorted(again.open()) == list(range(len(plan.chunks)))  # every part verified by its checksum
    got = SWEEP_TABLE.read(out)
    for c in COLUMNS:
        np.testing.assert_array_equal(got[c], table[c])


def test_ray_actor_presses_the_serial_bits(stomach, tmp_path):
    # what a Ray actor of one device runs (here in process, on the CPU): the serial path's columns
    points, vertices = sample_points(stomach, 10)
    from almsdm_warp.tissue.params import TissueParams

    plan = SweepPlan(stomach, TissueParams(), None, None, 2, 5e-4, 0.01, 0.05, 0.05, 0.05, points, vertices, 4)
    actor = SweepDevice(plan, False, sweep_critical_dt(plan))
    serial = RingBatches(plan, plan.model("cpu"))
    for i, (begin, end) in enumerate(plan.chunks):
        expected = press_chunk(serial, plan, begin, end)()
        got = actor.press(i)
        for c in COLUMNS:
            np.testing.assert_array_equal(got[c], expected[c])


def test_stream_lanes_read_back_the_finished_press(stomach, monkeypatch):
    # the CUDA branch of a Lane (events, its stream, results copied into host buffers and turned into
    # columns by BatchPalpation.result_from) run on the CPU with the stream calls stubbed: the columns
    # of the serial path, which reads through finish_press
    import time
    import warp as wp
    from almsdm_warp.tissue.params import TissueParams

    class Event:
        def __init__(self, *args, **kw):
            self.t = None

    class Stream:
        def record_event(self, event):
            event.t = time.perf_counter()
            return event

    empty, copy, copies = wp.empty, wp.copy, []
    monkeypatch.setattr(wp, "Event", Event)
    monkeypatch.setattr(wp, "get_stream", lambda device: None)
    monkeypatch.setattr(wp, "set_stream", lambda stream, device, sync=False: None)
    monkeypatch.setattr(wp, "synchronize_stream", lambda stream: None)
    monkeypatch.setattr(wp, "synchronize_event", lambda event: None)
    monkeypatch.setattr(wp, "get_event_elapsed_time", lambda a, b: (b.t - a.t) * 1e3)
    monkeypatch.setattr(wp, "empty", lambda *a, pinned=False, **kw: empty(*a, **kw))
    monkeypatch.setattr(wp, "copy", lambda dst, src, stream=None: (copies.append(stream), copy(dst, src)))
    points, vertices = sample_points(stomach, 14)
    plan = SweepPlan(stomach, TissueParams(), None, None, np.array([2, 3] * 7), 5e-4, 0.01, 0.02, 0.02, 0.02, points, vertices, 5)
    model = plan.model("cpu")
    lanes = [Lane(RingBatches(plan, model), SweepTimes()) for _ in range(2)]
    for lane in lanes:
        lane.stream = Stream()
    origin = lanes[0].clock_origin()
    serial = RingBatches(plan, plan.model("cpu"))
    from almsdm_warp.batch.batch_palpation import BatchPalpation

    calls = []

    def recorded(name):
        method = getattr(BatchPalpation, name)

        def call(self, *args, **kw):
            calls.append(name)
            return method(self, *args, **kw)
        return call

    for name in ("plan", "start_press"):  # a chunk's batches all planned before the first is launched (Lane.launch)
        monkeypatch.setattr(BatchPalpation, name, recorded(name))
    for i, (begin, end) in enumerate(plan.chunks):
        calls.clear()
        lanes[i % 2].start(plan, i, None, origin)
        assert calls == ["plan", "plan", "start_press", "start_press"]  # a plan reads back on the lane's stream: after a press, it would wait for it
        got = lanes[i % 2].finish(plan, origin)
        expected = press_chunk(serial, plan, begin, end)()
        for c in COLUMNS:
            np.testing.assert_array_equal(got[c], expected[c])
    assert sum(s is lanes[0].stream for s in copies) == 3 * 2 * 2  # 3 results x 2 ring counts x chunks 0, 2
    assert all(origin[1] <= b <= e <= time.perf_counter() for b, e in lanes[1].busy)  # on the host's clock


def test_the_timeline_of_presses():
    # two devices' presses on the host's clock: the first start, the idle time between the first and the
    # last press (no device pressing) and the tail, against the intervals worked out by hand
    times = SweepTimes()
    t0 = times.t0
    times.add_press([(t0 + 0.5, t0 + 1.0), (t0 + 1.2, t0 + 2.0)])  # one device: idle 1.0..1.2
    times.add_press([(t0 + 0.9, t0 + 1.1), (t0 + 2.5, t0 + 3.0)])  # another: covers 1.0..1.1, adds 2.0..2.5 idle
    assert times.press_s == pytest.approx(0.5 + 0.8 + 0.2 + 0.5)
    got = times.timeline(4.0)
    assert got["before_first_press_s"] == pytest.approx(0.5)
    assert got["idle_between_presses_s"] == pytest.approx(0.1 + 0.5)
    assert got["after_last_press_s"] == pytest.approx(1.0)
    assert SweepTimes().timeline(1.0) == {}


def test_one_substep_from_the_whole_mesh_bound(stomach):
    # where the whole mesh's critical step allows one substep, a batch given it as its bound takes
    # one without estimating its own; the batch's own estimate (the independent answer) agrees
    from almsdm_warp.batch.batch_palpation import BatchPalpation
    from almsdm_warp.tissue.params import TissueParams

    for dt, substeps in ((1e-3, 1), (2e-3, 2)):
        plain = BatchPalpation(stomach, TissueParams(), rings=3, dt=dt, device="cpu")
        bounded = BatchPalpation(model=plain.model, rings=3, dt=dt)
        bounded.critical_dt_bound = plain.model.critical_dt()
        plain.touch(stomach.surface_vertices[::40])
        bounded.touch(stomach.surface_vertices[::40])
        assert plain.substeps == bounded.substeps == substeps
        assert plain.critical_dt >= bounded.critical_dt_bound * (1 - 1e-6)


def test_union_length_against_a_fine_grid():
    rng = np.random.default_rng(3)
    begin = rng.uniform(0, 90, 40)
    intervals = list(zip(begin, begin + rng.uniform(0, 10, 40)))
    grid = (np.arange(1_000_000) + 0.5) * 1e-4
    covered = np.zeros(len(grid), dtype=bool)
    for b, e in intervals:
        covered |= (grid >= b) & (grid < e)
    assert abs(union_length(intervals) - covered.sum() * 1e-4) < 40 * 2e-4
    assert union_length([]) == 0.0


def test_default_chunk_fills_the_devices():
    assert default_chunk(10_000, ["cpu"]) == 64
    assert default_chunk(200, ["cuda:0"]) == 200  # all in one launch
    assert default_chunk(1_000_000, ["cuda:0"]) == 65536  # 16 chunks: the next is built while one presses
    assert default_chunk(1_000_000, ["cuda:0", "cuda:1"]) == 65536  # 8 chunks a device
    assert default_chunk(200_000, ["cuda:0", "cuda:1"]) == 25000  # 4 chunks a device
    assert default_chunk(100_000, ["cuda:0"]) == 25000
    # on several GPUs the last two chunks a device in quarters, where a quarter keeps a launch's fill (16,384 points)
    assert default_tail(4_000_000, 65536, ["cuda:0", "cuda:1"]) == 4 * 65536
    assert default_tail(1_000_000, 65536, ["cuda:0"]) == 0  # one GPU: nothing to balance
    assert default_tail(200_000, 25000, ["cuda:0", "cuda:1"]) == 0 and default_tail(10_000, 64, ["cpu", "cpu"]) == 0


def test_sweep_on_ray_gives_the_same_file(tmp_path):
    ray = pytest.importorskip("ray")
    local, distributed = tmp_path / "local.csv", tmp_path / "ray.csv"
    args = ["sweep", "--points", "12", "--chunk", "4", "--rings", "2", *FAST]
    assert main([*args, "--out", str(local)]) == 0
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        assert main([*args, "--out", str(distributed), "--ray"]) == 0
    finally:
        ray.shutdown()
    assert distributed.read_text() == local.read_text()


def test_sweep_implicit_matches_the_batch(tmp_path, stomach):
    # the command's implicit sweep is BatchPalpation's implicit press at the same points
    out = tmp_path / "imp.npz"
    assert main(["sweep", "paper_stomach", "--points", "6", "--rings", "2", "--integrator", "implicit", "--out", str(out), *FAST]) == 0
    table = SWEEP_TABLE.read(out)
    from almsdm_warp.batch.batch_palpation import BatchPalpation

    res = BatchPalpation(stomach, rings=2, dt=5e-4, device="cpu", integrator="implicit").touch(table["vertex"]).press(0.01, 0.05, 0.05, 0.05)
    np.testing.assert_array_equal(table["peak_force_N"], res.peak_force)
    np.testing.assert_array_equal(table["recovery_error_mm"], res.recovery_error * 1e3)


def test_sweep_png(tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "map.png"
    assert main(["sweep", "--points", "8", "--rings", "1", "--out", str(tmp_path / "m.npz"), "--png", str(png), *FAST]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "args,message",
    [
        (["--out", "x.txt"], "--out x.txt: unknown table suffix '.txt' (allowed: .csv, .npz, .parquet)"),
        (["--out", "/nonexistent/x.csv"], "does not exist"),
        (["--out", "x.csv", "--device", "tpu"], "unknown device"),
        (["--out", "x.csv", "--points", "0"], "must be >= 1"),
        (["--out", "x.csv", "--depth-mm", "-1"], "must be > 0"),
        (["--out", "x.csv", "--rings", "automatic"], "allowed: an integer >= 1 or 'auto'"),
        (["--out", "x.csv", "--rings", "3", "--tol-mm", "0.1"], "--tol-mm is for --rings auto"),
        (["--out", "x.csv", "--rings", "auto", "--tol-mm", "0"], "must be > 0"),
    ],
)
def test_sweep_bad_input(tmp_path, monkeypatch, capsys, args, message):
    monkeypatch.chdir(tmp_path)
    assert main(["sweep", *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_lesion_scene_and_its_errors(tmp_path):
    from almsdm_warp.errors import InputError
    from almsdm_warp.sim.model import Model
    from almsdm_warp.tissue.params import TissueParams
    from almsdm_warp.scene.loader import load_scene

    scene = resolve_scene_or_mesh("stomach_lesion")
    lesion = scene.lesion
    assert lesion.center == (-0.027, 0.056, 0.0) and lesion.radius == 0.018 and lesion.stiffness_factor == 5.0
    assert scene.as_dict()["lesion"]["radius_mm"] == 18.0
    mesh = scene.load_mesh()
    # on the paper's constants (the scene's is a material: tests/test_tissue_material_model.py)
    paper = TissueParams()
    edge_scale, anchor_scale = lesion.scales(mesh, paper)
    model = Model(mesh, paper, "cpu", edge_scale=edge_scale, anchor_scale=anchor_scale)
    inside = np.linalg.norm(mesh.vertices - np.array(lesion.center), axis=1) <= lesion.radius
    assert 0 < inside.sum() < 100
    np.testing.assert_allclose(model.anchor_ke.numpy(), np.where(inside, 5.0, 1.0) * paper.anchor_stiffness, rtol=1e-6)
    mid = mesh.vertices[mesh.edges].mean(axis=1)
    stiff_edges = np.linalg.norm(mid - np.array(lesion.center), axis=1) <= lesion.radius
    np.testing.assert_allclose(model.spring_ke.numpy(), np.where(stiff_edges, 5.0, 1.0) * paper.edge_stiffness, rtol=1e-6)
    assert resolve_scene_or_mesh("stomach").lesion is None
    for table, message in [
        ("center_mm = [0, 0]\nradius_mm = 5", "center_mm must be 3 finite numbers"),
        ("center_mm = [0, 0, 0]\nradius_mm = -5", "radius_mm must be a finite number > 0"),
        ("center_mm = [0, 0, 0]", "needs radius_mm"),
        ("center_mm = [0, 0, 0]\nradius_mm = 5\nhardness = 3", "unknown key 'hardness'"),
    ]:
        path = tmp_path / "l.toml"
        path.write_text(f'[mesh]\npath = "{SCENES / "stomach.obj"}"\n[lesion]\n{table}\n')
        with pytest.raises(InputError, match=message):
            load_scene(path)


def test_auto_sweep_agrees_with_the_global_reference(tmp_path, stomach):
    # --rings auto sizes each point's region as almsdm palpate --rings auto does, then presses it with that
    # many fixed rings: its peak forces are those of a global-accurate ring count within the 1% force bound
    from almsdm_warp.protocol.adaptive import AdaptivePalpation
    from almsdm_warp.evaluation.adaptive_accuracy import hold_press
    from almsdm_warp.protocol.palpation import Palpation
    from almsdm_warp.tissue.params import TissueParams

    press = ["--points", "6", "--ramp-s", "0.1", "--hold-s", "0.2", "--settle-s", "0.01", "--dt-ms", "1"]
    # the paper's preset: the reference below is its constants (TissueParams)
    assert main(["sweep", "paper_stomach", *press, "--rings", "auto", "--tol-mm", "0.1", "--out", str(tmp_path / "auto.npz")]) == 0
    assert main(["sweep", "paper_stomach", *press, "--rings", "8", "--out", str(tmp_path / "eight.csv")]) == 0
    auto, eight = SWEEP_TABLE.read(tmp_path / "auto.npz"), SWEEP_TABLE.read(tmp_path / "eight.csv")
    for c in ("x_mm", "y_mm", "z_mm", "vertex"):
        np.testing.assert_array_equal(auto[c], eight[c])
    assert set(auto["rings"]) == {2, 3} and set(eight["rings"]) == {8}  # docs/adaptive.md: 3 or 2 at 0.1 mm
    # the global anchored model (no ring boundary) under the same press: the independent answer
    reference = Palpation(stomach, TissueParams(), rings="global", dt=1e-3, device="cpu")
    peaks = []
    for v in auto["vertex"]:
        reference.touch(int(v))
        peaks.append(hold_press(reference, 0.01, 0.1, 0.2)[0])
        for s in reference.states:  # the next press from rest (the global model's touch keeps the state)
            s.particle_q.assign(reference.model.particle_q_rest)
            s.particle_qd.zero_()
    np.testing.assert_allclose(eight["peak_force_N"], peaks, rtol=1e-3)  # 8 rings: the global reference's
    np.testing.assert_allclose(auto["peak_force_N"], eight["peak_force_N"], rtol=0.01)
    np.testing.assert_allclose(auto["peak_force_N"], peaks, rtol=0.01)
    # a scene's [region] rings = "auto", tol_mm = 0.1: the same sweep
    text = (SCENES / "paper_stomach.toml").read_text().replace('path = "stomach.obj"', f"path = {str(SCENES / 'stomach.obj')!r}")
    (tmp_path / "auto.toml").write_text(text.replace("\nrings = 4 ", '\nrings = "auto"\ntol_mm = 0.1\n# '))
    assert main(["sweep", str(tmp_path / "auto.toml"), *press, "--out", str(tmp_path / "scene.npz")]) == 0
    by_scene = SWEEP_TABLE.read(tmp_path / "scene.npz")
    for c in COLUMNS:
        np.testing.assert_array_equal(by_scene[c], auto[c])
    # each point's rings are a fresh adaptive palpation's there (sized from rest, whatever the order)
    for k in (1, 4):
        pal = AdaptivePalpation(stomach, TissueParams(), tol=1e-4, dt=1e-3, device="cpu", retire=False)
        pal.touch(int(auto["vertex"][k]))
        hold_press(pal, 0.01, 0.1, 0.2)
        assert pal.rings_chosen == auto["rings"][k]


def test_devices_started_ahead():
    # the contexts a --device names start on a thread; a name with no device behind it is left to the
    # command (no error here); afterwards every CUDA device named has its context
    import warp as wp

    from almsdm_warp.warp_init import devices_started, start_devices

    start_devices("cpu")
    devices_started()
    names = ",".join(["cpu", *(d.alias for d in wp.get_cuda_devices()), "cuda:99"])
    start_devices(names)
    devices_started()
    assert all(d.has_context for d in wp.get_cuda_devices())


def test_a_gpu_sweep_imports_what_it_needs_ahead(monkeypatch):
    # the modules a sweep names (preload) are imported on a thread of their own where its --device names
    # a GPU (the import overlaps Warp's start there); on the CPU nothing is started
    import importlib
    import threading

    from almsdm_warp.cli import main as cli

    assert cli.build_parser().parse_args(["sweep", "stomach", "--out", "s.npz"]).preload == ("scipy.spatial", "scipy.sparse.linalg")
    imported = []
    monkeypatch.setattr(importlib, "import_module", imported.append)
    for device in ("cpu", None, "cuda:1", "cpu,all"):
        before = set(threading.enumerate())
        cli._start_imports(("json", "math"), device)
        for thread in set(threading.enumerate()) - before:
            thread.join()
    assert imported == ["json", "math"] * 2


def test_profile_says_where_the_wall_time_went(tmp_path, capsys):
    # --profile: each phase, the press kernels, the presses' timeline and the way to the first press;
    # the timeline's three parts and the presses' union fit in the wall time
    import re

    out = tmp_path / "p.npz"
    args = ["sweep", "--points", "40", "--chunk", "16", "--rings", "1", "--ramp-s", "0.004", "--hold-s", "0",
            "--settle-s", "0.004", "--dt-ms", "1", "--no-progress", "--profile", "--out", str(out)]
    assert main(args) == 0
    text = capsys.readouterr().out
    seconds = {name: float(s) for name, s in re.findall(r"^(wall|press kernels \(device\)|before first press|idle between presses"
                                                       r"|after last press)\s+([0-9.]+) s", text, flags=re.M)}
    assert len(seconds) == 5
    parts = seconds["before first press"] + seconds["idle between presses"] + seconds["after last press"]
    assert parts + seconds["press kernels (device)"] == pytest.approx(seconds["wall"], abs=0.004)
    assert "on the way to the first press: plan" in text and "first press launched" in text
    assert sorted(SWEEP_TABLE.read(out)["vertex"]) == sorted(sample_points(load_cached(SCENES / "stomach.obj"), 40)[1])
