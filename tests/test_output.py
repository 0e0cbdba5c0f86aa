"""Writing outputs: the path is checked by trying it, before any work; a write that fails at the
end is one line with exit code 2; nothing half-written, no temporary file left behind."""

import os
from pathlib import Path

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
    from almsdm_warp.batch.sweep import COLUMNS, read_table, write_table

    published = []
    real = output.publish
    monkeypatch.setattr(output, "publish", lambda tmp, path: published.append(Path(path).name) or real(tmp, path))
    columns = {c: [1.0, 2.0] for c in COLUMNS}
    out = write_table(tmp_path / "s.csv", columns)
    assert published == ["s.csv"] and (out.stat().st_mode & 0o777) == _new_file_mode()
    assert read_table(out)["peak_force_N"].tolist() == [1.0, 2.0]
