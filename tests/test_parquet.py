"""Parquet tables (export/parquet.py): read by pandas and polars as written, what made them in the
schema's metadata, rows streamed in any order, nothing half-written, and a clear line without pyarrow."""

import json
import subprocess
import sys

import numpy as np
import pytest
from fuzzing import check_outcome, run_main
from helpers import stop_after_writes

from almsdm_warp.batch.dataset import DATASET_TABLE
from almsdm_warp.batch.sweep_plan import SWEEP_TABLE, mesh_sha256
from almsdm_warp.errors import InputError
from almsdm_warp.export.tables import TableLayout
from conftest import ROOT, SCENES, load_cached

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

FAST = ["--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05", "--dt-ms", "0.5"]
CURVES = TableLayout("curve table", {"point": "int64", "scene": "str", "force_curve_N": "float64[4]", "peak_force_N": "float64"})


def random_columns(layout, n, seed=0):
    rng = np.random.default_rng(seed)
    make = {"int64": lambda: rng.integers(-99, 1 << 40, n), "float64": lambda: rng.normal(size=n) * 1e-7,
            "str": lambda: np.array([f"s{k % 7}" for k in range(n)]), "float64[4]": lambda: rng.normal(size=(n, 4))}
    return {c: make[d]() for c, d in layout.dtypes.items()}


def test_pandas_and_polars_read_what_was_written(tmp_path):
    pd = pytest.importorskip("pandas")
    pl = pytest.importorskip("polars")
    info = {"scene": "stomach", "mesh": {"sha256": "ab" * 32}, "version": "0.1.0"}
    for layout in (DATASET_TABLE, CURVES):
        columns = random_columns(layout, 11)
        path = layout.write(tmp_path / f"{layout.name.replace(' ', '_')}.parquet", columns, info)
        frames = {"pandas": pd.read_parquet(path), "polars": pl.read_parquet(path)}
        for reader, frame in frames.items():
            assert list(frame.columns) == list(layout.dtypes), reader
            for c, values in columns.items():
                got = frame[c].to_list()
                if values.ndim == 2:  # a fixed-size list column: a list of N values a row
                    got = [list(row) for row in got]
                assert got == values.tolist(), (reader, c)
        if layout is CURVES:
            assert frames["polars"]["force_curve_N"].dtype == pl.Array(pl.Float64, 4)
        meta = pq.read_schema(path).metadata
        assert json.loads(meta[b"almsdm"]) == {"table": layout.name, **info}
        for key, text in layout.meta.items():  # the dataset's "schema" entry: each column's unit and meaning
            assert meta[key.encode()].decode() == text
        back = layout.read(path)  # and the package's own reader
        for c, values in columns.items():
            np.testing.assert_array_equal(back[c], values)


@pytest.mark.parametrize("order", ["shuffled", "in order"])
def test_rows_streamed_in_any_order_read_back_whole(tmp_path, monkeypatch, order):
    # blocks in any order, some left to finish(): the same table as one write, in several row groups
    import almsdm_warp.export.parquet as parquet

    monkeypatch.setattr(parquet, "ROW_GROUP", 2000)
    n = 10007
    columns = random_columns(CURVES, n, 1)
    table = CURVES.rows(tmp_path / "t.parquet", n, {"scene": "x"})
    rng = np.random.default_rng(2)
    blocks = list(range(0, n, 1000))
    for b in (rng.permutation(blocks) if order == "shuffled" else blocks)[:-3]:
        table.rows(int(b), {c: v[b : b + 1000] for c, v in columns.items()})
    assert not (tmp_path / "t.parquet").exists()  # nothing at the target before finish()
    table.finish(columns)
    table.discard()  # after finish(): nothing to remove, the table stays
    assert pq.ParquetFile(tmp_path / "t.parquet").metadata.num_row_groups > 1
    back = CURVES.read(tmp_path / "t.parquet")
    for c, values in columns.items():
        np.testing.assert_array_equal(back[c], values)
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_a_full_disk_leaves_nothing(full_disk):
    # a table larger than the 64 KiB disk, written whole and by rows: one InputError, no file left
    columns = random_columns(CURVES, 20000, 3)
    with pytest.raises(InputError, match="No space left on device"):
        CURVES.write(full_disk / "t.parquet", columns)
    table = CURVES.rows(full_disk / "r.parquet", 20000)
    with pytest.raises(InputError, match="No space left on device"):
        for b in range(0, 20000, 5000):
            table.rows(b, {c: v[b : b + 5000] for c, v in columns.items()})
        table.finish(columns)
    table.discard()
    assert list(full_disk.iterdir()) == []


def test_a_sweep_to_parquet_holds_the_npz_numbers_and_what_made_them(tmp_path):
    from almsdm_warp import __version__
    from almsdm_warp.export.parquet import read_info

    args = ["sweep", "stomach_lesion", "--points", "12", "--chunk", "5", *FAST]
    assert run_main([*args, "--out", tmp_path / "s.npz"])[0] == 0
    code, _, err = run_main([*args, "--out", tmp_path / "s.parquet"])
    assert code == 0, err
    a, b = SWEEP_TABLE.read(tmp_path / "s.npz"), SWEEP_TABLE.read(tmp_path / "s.parquet")
    assert list(a) == list(b)
    for c in a:
        np.testing.assert_array_equal(a[c], b[c])
    info = read_info(tmp_path / "s.parquet")
    assert info["scene"] == "stomach_lesion" and info["version"] == __version__ and info["table"] == "sweep table"
    assert info["mesh"]["sha256"] == mesh_sha256(load_cached(SCENES / "stomach.obj"))
    assert info["lesion"]["radius_mm"] > 0 and info["material"]["type"] and info["press"]["dt_ms"] == 0.5
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz", "s.parquet"]


def test_without_pyarrow_one_line_before_any_work(tmp_path, monkeypatch):
    # pyarrow missing (as a None in sys.modules makes it): .parquet is refused before the sweep, .npz runs
    for name in ("pyarrow", "pyarrow.parquet"):
        monkeypatch.setitem(sys.modules, name, None)
    out = tmp_path / "s.parquet"
    code, stdout, err = run_main(["sweep", "--points", "4", *FAST, "--out", out])
    check_outcome(code, stdout, err, folder=tmp_path)
    assert code == 2 and "--out" in err and "needs pyarrow: pip install 'almsdm_warp[parquet]'" in err, err
    assert "sweep:" not in stdout and list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="needs pyarrow"):
        SWEEP_TABLE.read(out)
    assert run_main(["sweep", "--points", "4", *FAST, "--out", tmp_path / "s.npz"])[0] == 0


def test_the_package_imports_without_pyarrow():
    # the table formats, the command line and the sweep import no pyarrow until a .parquet is asked for
    code = ("import sys; sys.modules['pyarrow'] = None; "
            "import almsdm_warp.export.writers, almsdm_warp.cli.main, almsdm_warp.batch.dataset; print('ok')")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_an_interrupted_sweep_resumes_to_the_same_parquet(tmp_path, monkeypatch):
    # the resumed run streams only the chunks it presses (after a gap: they wait), finish() adds the ones
    # read back from the parts: the same table as one run's
    from almsdm_warp.batch.sweep_store import Parts

    args = ["sweep", "--points", "20", "--chunk", "6", *FAST]
    assert run_main([*args, "--out", tmp_path / "whole.parquet"])[0] == 0
    real = stop_after_writes(monkeypatch, 2)
    out = tmp_path / "resumed.parquet"
    assert run_main([*args, "--out", out])[0] == 130 and not out.exists()
    monkeypatch.setattr(Parts, "write", real)
    code, stdout, _ = run_main([*args, "--out", out])
    assert code == 0 and "resuming: 2 of 4 chunks" in stdout
    a, b = SWEEP_TABLE.read(tmp_path / "whole.parquet"), SWEEP_TABLE.read(out)
    for c in a:
        np.testing.assert_array_equal(a[c], b[c])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["resumed.parquet", "whole.parquet"]
