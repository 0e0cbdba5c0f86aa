"""A sweep's resume heals: a chunk damaged on disk is found by its checksum (sums.txt, or an older
folder's plan.json) and pressed again; the table equals an uninterrupted run's, byte for byte."""

import json
from pathlib import Path

from almsdm_warp.batch.sweep_plan import COLUMNS, SWEEP_TABLE
from almsdm_warp.batch.sweep_store import Parts
from almsdm_warp.cli.main import main

FAST = ["--ramp-s", "0.05", "--hold-s", "0.05", "--settle-s", "0.05", "--dt-ms", "0.5"]
ARGS = ["sweep", "--points", "20", "--chunk", "6", *FAST]


def whole_and_interrupted(tmp_path, name: str, chunks: int):
    """An uninterrupted sweep of ARGS (whole.SUFFIX) and one into `name` stopped after `chunks` chunks:
    (whole, out, out's parts folder)."""
    whole = tmp_path / f"whole{Path(name).suffix}"
    assert main([*ARGS, "--out", str(whole)]) == 0
    out = tmp_path / name
    interrupt_after(chunks, out)
    return whole, out, tmp_path / f"{name}.parts"


def test_damaged_chunks_are_pressed_again(tmp_path, capsys):
    whole, out, parts = whole_and_interrupted(tmp_path, "resumed.csv", 3)
    chunks = sorted(parts.glob("chunk_*.npz"))
    assert len(chunks) == 3
    sums = dict(line.split() for line in (parts / "sums.txt").read_text().splitlines())
    assert sorted(sums) == ["0", "1", "2"] and "chunks" not in json.loads((parts / "plan.json").read_text())
    # a chunk cut short (a full disk, a copy interrupted) and one with a byte changed
    data = chunks[0].read_bytes()
    chunks[0].write_bytes(data[: len(data) // 2])
    data = bytearray(chunks[2].read_bytes())
    data[len(data) // 3] ^= 0x01
    chunks[2].write_bytes(bytes(data))
    capsys.readouterr()
    assert main([*ARGS, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "resuming: 1 of 4 chunks" in cap.out
    assert "note: 2 chunk(s)" in cap.err and "Traceback" not in cap.err
    assert out.read_text() == whole.read_text()
    assert not parts.exists()


def test_a_chunk_without_its_checksum_is_pressed_again(tmp_path, capsys):
    """A chunk on disk whose checksum never reached plan.json (an interrupt between the two writes)
    is not trusted."""
    whole = tmp_path / "whole.csv"
    assert main([*ARGS, "--out", str(whole)]) == 0
    out = tmp_path / "r.csv"
    parts = tmp_path / "r.csv.parts"
    parts.mkdir()
    # a stray file under a chunk's name, and a plan.json with the right key but no checksums
    (parts / "chunk_000001.npz").write_bytes(b"PK\x03\x04 not a chunk")
    key = _key_of_the_sweep(tmp_path)
    (parts / "plan.json").write_text(json.dumps({"key": key, "points": 20}))
    capsys.readouterr()
    assert main([*ARGS, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "note: 1 chunk(s)" in cap.err
    assert out.read_text() == whole.read_text()


def test_a_torn_checksum_line_and_an_older_folders_checksums(tmp_path, capsys):
    """sums.txt's last line cut short (a kill mid-append) is no checksum: its chunk is pressed again; a
    folder of an older version, every checksum in plan.json's "chunks", resumes its chunks as they are."""
    whole, out, parts = whole_and_interrupted(tmp_path, "torn.csv", 3)
    log = (parts / "sums.txt").read_text()
    (parts / "sums.txt").write_text(log[: log.rindex("\n", 0, len(log) - 1) + 2])  # the last line: its index's first digit
    capsys.readouterr()
    assert main([*ARGS, "--out", str(out)]) == 0
    cap = capsys.readouterr()
    assert "resuming: 2 of 4 chunks" in cap.out and "note: 1 chunk(s)" in cap.err
    assert out.read_text() == whole.read_text()
    _, old, parts = whole_and_interrupted(tmp_path, "old.csv", 3)
    manifest = json.loads((parts / "plan.json").read_text())
    manifest["chunks"] = dict(line.split() for line in (parts / "sums.txt").read_text().splitlines())
    (parts / "plan.json").write_text(json.dumps(manifest))
    (parts / "sums.txt").unlink()
    capsys.readouterr()
    assert main([*ARGS, "--out", str(old)]) == 0
    cap = capsys.readouterr()
    assert "resuming: 3 of 4 chunks" in cap.out and "note:" not in cap.err
    assert old.read_text() == whole.read_text()


def test_a_run_stopped_before_its_first_chunk_leaves_a_folder_taken_as_new(tmp_path, capsys):
    whole, out, parts = whole_and_interrupted(tmp_path, "s.csv", 0)
    assert parts.is_dir() and not any(parts.iterdir())  # no plan.json yet: nothing was written
    capsys.readouterr()
    assert main([*ARGS, "--out", str(out)]) == 0
    assert "resuming" not in capsys.readouterr().out
    assert out.read_text() == whole.read_text()


def interrupt_after(chunks: int, out) -> None:
    """Run the sweep of ARGS into `out`, interrupted (Ctrl-C) when `chunks` chunks are written."""
    from unittest import mock

    real = Parts.write

    def write(self, i, columns):
        if len(self.sums) >= chunks:
            raise KeyboardInterrupt
        real(self, i, columns)

    with mock.patch.object(Parts, "write", write):
        assert main([*ARGS, "--out", str(out)]) == 130


def _key_of_the_sweep(tmp_path):
    """The plan key of ARGS, from the plan.json of a run stopped after its first chunk (a new folder's
    plan.json is written with its first chunk)."""
    interrupt_after(1, tmp_path / "k.csv")
    return json.loads((tmp_path / "k.csv.parts" / "plan.json").read_text())["key"]


def test_a_resumed_npz_table_equals_an_uninterrupted_one(tmp_path):
    # the .npz is written as chunks come (export/npz_rows.py): the chunks of the first run, read back
    # from their parts, are written into the resumed run's table at the end
    import numpy as np

    whole, out, _ = whole_and_interrupted(tmp_path, "r.npz", 2)
    assert not out.exists() and [p.name for p in tmp_path.iterdir() if p.name.startswith(".r.npz")] == []
    assert main([*ARGS, "--out", str(out)]) == 0
    a, b = SWEEP_TABLE.read(whole), SWEEP_TABLE.read(out)
    for c in COLUMNS:
        np.testing.assert_array_equal(a[c], b[c])
