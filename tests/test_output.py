"""Writing outputs: the path is checked by trying it, before any work; a write that fails at the
end is one line with exit code 2; nothing half-written, no temporary file left behind."""

import os
from pathlib import Path

import numpy as np
import pytest
from fuzzing import check_outcome, run_main

FAST = ["--ramp-s", "0.01", "--hold-s", "0.005", "--settle-s", "0.01"]


@pytest.mark.skipif(not Path("/proc").is_dir() or os.geteuid() != 0, reason="needs /proc and root (os.access says yes)")
def test_json_where_os_access_lies(tmp_path):
    """os.access(/proc, W_OK) is True for root, but no file can be made there: the check now tries
    (a FileNotFoundError traceback came after the whole run before)."""
    for argv in (["touch"], ["palpate", *FAST]):
        code, stdout, err = run_main([*argv, "--json", "/proc/almsdm-out.json"])
        check_outcome(code, stdout, err)
        assert code == 2 and "cannot write in folder /proc" in err, err


def test_write_failure_after_the_run_is_one_line(tmp_path, monkeypatch):
    """The folder is writable when checked but the write fails at the end (disk full, say): one
    line and exit 2, and no temporary file left."""
    import almsdm_warp.export.output as output

    real = os.replace

    def full(src, dst):
        if str(dst).endswith("out.json"):
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(output.os, "replace", full)
    out = tmp_path / "out.json"
    code, stdout, err = run_main(["touch", "--rings", "1", "--json", out])
    check_outcome(code, stdout, err, out, tmp_path)
    assert code == 2 and "No space left on device" in err
    assert list(tmp_path.iterdir()) == []


def _new_file_mode():
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_gives_a_new_files_mode(tmp_path, umask):
    """mkstemp makes the temporary file owner-only; the published file has 0o666 less the umask."""
    from almsdm_warp.export.output import atomic_write

    old = os.umask(umask)
    try:
        out = atomic_write(tmp_path / "t.csv", lambda tmp: Path(tmp).write_text("a\n"))
        assert (out.stat().st_mode & 0o777) == _new_file_mode() == 0o666 & ~umask
    finally:
        os.umask(old)
    assert out.read_text() == "a\n" and sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


def test_atomic_write_that_fails_leaves_nothing(tmp_path):
    """An exception in the middle of the write: neither the target nor the temporary file remains."""
    from almsdm_warp.export.output import atomic_write

    def half(tmp):
        Path(tmp).write_text("half a ")
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError, match="interrupted"):
        atomic_write(tmp_path / "t.csv", half)
    assert list(tmp_path.iterdir()) == []


def test_sweep_table_goes_through_the_one_writer(tmp_path, monkeypatch):
    """The sweep's table is published by export.output.publish, with a new file's mode."""
    import almsdm_warp.export.output as output
    from almsdm_warp.batch.sweep_plan import COLUMNS, SWEEP_TABLE

    published = []
    real = output.publish
    monkeypatch.setattr(output, "publish", lambda tmp, path, sync=True: published.append((Path(path).name, sync)) or real(tmp, path, sync))
    columns = {c: [1.0, 2.0] for c in COLUMNS}
    out = SWEEP_TABLE.write(tmp_path / "s.csv", columns)
    assert published == [("s.csv", True)] and (out.stat().st_mode & 0o777) == _new_file_mode()  # synced
    assert SWEEP_TABLE.read(out)["peak_force_N"].tolist() == [1.0, 2.0]


def test_every_table_format_holds_every_table(tmp_path):
    """Each table format (export/tables.py) writes and reads back the sweep's, the dataset's and the
    trace's tables exactly, each through its layout; the command line takes exactly its suffixes."""
    from almsdm_warp.batch.dataset import DATASET_TABLE
    from almsdm_warp.batch.sweep_plan import SWEEP_TABLE
    from almsdm_warp.cli.trace import TRACE_TABLE
    from almsdm_warp.errors import InputError
    from almsdm_warp.export.tables import TABLE_FORMATS
    from almsdm_warp.export.writers import suffixes

    assert suffixes("table") == tuple(TABLE_FORMATS)
    rng = np.random.default_rng(0)
    for k, layout in enumerate((SWEEP_TABLE, DATASET_TABLE, TRACE_TABLE)):
        kinds = {"int64": lambda: rng.integers(-99, 1 << 40, 5), "float64": lambda: rng.normal(size=5) * 1e-7,
                 "str": lambda: np.array(["a", "bb", "", "d e", "f"])}
        columns = {c: kinds[d]() for c, d in layout.dtypes.items()}
        for suffix in TABLE_FORMATS:
            back = layout.read(layout.write(tmp_path / f"t{k}{suffix}", columns))
            assert list(back) == list(layout.dtypes)
            for c, values in columns.items():
                assert back[c].dtype.kind == values.dtype.kind
                np.testing.assert_array_equal(back[c], values)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(f"t{k}{s}" for k in range(3) for s in TABLE_FORMATS)
    with pytest.raises(InputError, match=r"t\.xlsx: unknown table suffix '\.xlsx' \(allowed: \.csv, \.npz, \.parquet\)"):
        SWEEP_TABLE.write(tmp_path / "t.xlsx", columns)
    with pytest.raises(InputError, match=r"t1\.csv: not a sweep table \(header \['scene'"):
        SWEEP_TABLE.read(tmp_path / "t1.csv")
    with pytest.raises(InputError, match=r"t0\.npz: not a dataset table \(no column 'scene'\)"):
        DATASET_TABLE.read(tmp_path / "t0.npz")


# -- outputs only to regular files, each its own, never an input -----------------------------
ROOT = Path(__file__).resolve().parents[1]


def _special(tmp_path, case):
    """(argv, message, check that the special file is intact) for one kind of bad output."""
    if case == "device":
        link = tmp_path / "null.json"
        link.symlink_to("/dev/null")
        return ["touch", "--rings", "1", "--json", link], "is a device", lambda: Path("/dev/null").is_char_device()
    if case == "folder":
        (tmp_path / "d.json").mkdir()
        return ["touch", "--rings", "1", "--json", tmp_path / "d.json"], "is a folder", lambda: (tmp_path / "d.json").is_dir()
    if case == "fifo":
        os.mkfifo(tmp_path / "f.json")
        return ["touch", "--rings", "1", "--json", tmp_path / "f.json"], "is a FIFO", lambda: (tmp_path / "f.json").is_fifo()
    if case == "twice":
        x = tmp_path / "x.json"
        return ["palpate", *FAST, "--json", x, "--usd", x], "are the same file", lambda: not x.exists()
    if case == "twice-by-link":
        (tmp_path / "x.png").symlink_to(tmp_path / "x.usdc")
        return ["palpate", *FAST, "--usd", tmp_path / "x.usdc", "--png", tmp_path / "x.png"], "are the same file", \
            lambda: not (tmp_path / "x.usdc").exists()
    if case == "input-mesh":
        mesh = tmp_path / "m.obj"
        mesh.write_bytes((ROOT / "scenes" / "stomach.obj").read_bytes())
        (tmp_path / "out.json").symlink_to(mesh)
        return ["touch", mesh, "--rings", "1", "--json", tmp_path / "out.json"], "is the input", \
            lambda: mesh.read_bytes() == (ROOT / "scenes" / "stomach.obj").read_bytes()
    raise ValueError(case)


@pytest.mark.parametrize("case", ["device", "folder", "fifo", "twice", "twice-by-link", "input-mesh"])
def test_outputs_only_to_regular_files_of_their_own(tmp_path, case):
    """An output onto a device, a folder, a FIFO, another output or an input: one line, exit 2,
    before any work, and nothing written (a rename would have replaced the special file)."""
    argv, message, intact = _special(tmp_path, case)
    before = sorted(p.name for p in tmp_path.iterdir())
    code, stdout, err = run_main(argv)
    check_outcome(code, stdout, err, folder=tmp_path)
    assert code == 2 and message in err, err
    assert intact() and sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_special_file_made_after_the_check_is_not_replaced(tmp_path):
    """publish checks the target again: a FIFO put there during the run stays a FIFO."""
    from almsdm_warp.errors import InputError
    from almsdm_warp.export.output import atomic_write

    target = tmp_path / "t.csv"

    def write(tmp):
        Path(tmp).write_text("a\n")
        os.mkfifo(target)

    with pytest.raises(InputError, match="is a FIFO"):
        atomic_write(target, write)
    assert target.is_fifo() and [p.name for p in tmp_path.iterdir()] == ["t.csv"]


# -- a full disk -------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".usdc", ".usda"])
def test_usd_on_a_full_disk_is_one_line(full_disk, suffix):
    """USD's error stack (hundreds of lines and a traceback before) is one line naming the cause."""
    code, stdout, err = run_main(["palpate", *FAST, "--usd", full_disk / f"p{suffix}", "--usd-every", "1"])
    check_outcome(code, stdout, err, folder=full_disk)
    assert code == 2 and "No space left on device" in err, err
    assert list(full_disk.iterdir()) == []


# -- signals, in a real process ----------------------------------------------------------------
READY = "ready: main() is about to run"
"""Written to stderr by the process _start(..., ready=True) runs, just before main(): a signal sent
after it reaches the command line's own handling, not the interpreter's start (which a loaded
machine can stretch past any fixed delay, and which no code of ours can handle)."""


def _start(tmp_path, *argv, ready=False):
    import signal
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    if ready:
        code = (f"import sys; from almsdm_warp.cli.main import main; print({READY!r}, file=sys.stderr, flush=True); "
                "sys.exit(main(sys.argv[1:]))")
        command = [sys.executable, "-c", code]
    else:
        command = [sys.executable, "-m", "almsdm_warp.cli.main"]
    # SIGINT at its default, as a terminal's foreground process has it: a suite started as a
    # background job of a non-interactive shell ignores SIGINT, and its children would inherit that
    # (the command line rightly keeps an ignored SIGINT ignored, as under nohup)
    return subprocess.Popen([*command, *map(str, argv)], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _signalled(tmp_path, argv, signum, wait, ready=False):
    """Start the command, call wait(proc), send `signum`: (exit code, stderr). ready: wait for the
    READY line first (and leave it out of the stderr returned)."""
    proc = _start(tmp_path, *argv, ready=ready)
    try:
        if ready:
            line = proc.stderr.readline()
            assert line.strip() == READY, line
        wait(proc)
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    return proc.returncode, err


def _attempts(check, tries=3):
    """Run `check` up to `tries` times, passing on the first success: a real process on a shared
    2-core machine can stall past a test's timing once (docs/reliability.md); broken behaviour
    fails every try."""
    for k in range(tries):
        try:
            return check(k)
        except AssertionError:
            if k == tries - 1:
                raise


def test_sigterm_during_a_usd_recording(tmp_path):
    """SIGTERM while frames are written: one line, exit 143 (128 + 15), no temporary file left."""
    import signal
    import time

    def recording(proc, folder):
        deadline = time.monotonic() + 120
        while not list(folder.glob(".p.usdc.*")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        if not list(folder.glob(".p.usdc.*")):
            _, err = proc.communicate(timeout=60)
            raise AssertionError(f"the recording never started: exit {proc.returncode}, stderr {err!r}")
        time.sleep(0.3)

    argv = ["palpate", "--presses", "1000", "--usd", "p.usdc", "--usd-every", "1", "--no-progress"]

    def check(k):
        folder = tmp_path / str(k)
        folder.mkdir()
        code, err = _signalled(folder, argv, signal.SIGTERM, lambda proc: recording(proc, folder))
        assert code == 143, err
        assert err.strip().splitlines() == ["almsdm: terminated"], err
        assert list(folder.iterdir()) == []

    _attempts(check)


@pytest.mark.parametrize("after_s", [0.2, 0.8])
def test_ctrl_c_in_the_first_second(tmp_path, after_s):
    """SIGINT while the program starts (imports, Warp's start; trimesh's imports swallowed it and
    failed later), timed from the moment main() runs: one line, exit 130, no traceback, nothing written."""
    import signal
    import time

    def check(k):
        folder = tmp_path / str(k)
        folder.mkdir()
        # 300 presses: still running at 0.8 s on any machine (one press is a few ms once Warp's
        # kernels are cached: a single press can end before the signal, or while Python exits)
        argv = ["palpate", "--presses", "300", "--no-progress", "--json", "out.json"]
        code, err = _signalled(folder, argv, signal.SIGINT, lambda proc: time.sleep(after_s), ready=True)
        assert code == 130, err
        assert err.strip().splitlines() == ["almsdm: interrupted"], err
        assert list(folder.iterdir()) == []

    _attempts(check)

@pytest.mark.parametrize("order", ["shuffled", "in order", "shuffled, every block"])
def test_npz_written_by_rows_reads_back_as_savez(tmp_path, order):
    # rows in any order (the CRCs taken as the rows before them have come), some left to finish() (not
    # in the last case, whose CRCs are then complete before it): np.load and zipfile's CRC check read
    # what np.savez writes
    import zipfile

    from almsdm_warp.export.npz_rows import NpzRows

    rng = np.random.default_rng(1)
    n = 10007
    columns = {"x_mm": rng.random(n), "vertex": rng.integers(0, 1 << 40, n), "f": rng.random(n).astype(np.float32)}
    path = tmp_path / "t.npz"
    table = NpzRows(path, n, {c: v.dtype for c, v in columns.items()})
    blocks = list(range(0, n, 1000))
    for b in rng.permutation(blocks) if order == "shuffled, every block" else (rng.permutation(blocks) if order == "shuffled" else blocks)[:-3]:
        table.rows(int(b), {c: v[b : b + 1000] for c, v in columns.items()})
    assert (table.crc_rows == n) == (order == "shuffled, every block")
    assert not path.exists()  # nothing at the target before finish()
    table.finish(columns)
    table.discard()  # after finish(): nothing to remove, the table stays
    with zipfile.ZipFile(path) as z:
        assert z.testzip() is None
    np.savez(tmp_path / "s.npz", **columns)
    with np.load(path) as got, np.load(tmp_path / "s.npz") as expected:
        assert got.files == expected.files
        for c in columns:
            assert got[c].dtype == expected[c].dtype
            np.testing.assert_array_equal(got[c], expected[c])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz", "t.npz"]


def test_npz_rows_discarded_leaves_nothing(tmp_path):
    from almsdm_warp.export.npz_rows import NpzRows

    table = NpzRows(tmp_path / "t.npz", 10, {"a": np.float64})
    table.rows(0, {"a": np.arange(5.0)})
    table.discard()
    assert list(tmp_path.iterdir()) == []
