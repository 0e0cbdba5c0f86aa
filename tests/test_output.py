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
