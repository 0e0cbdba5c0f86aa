"""A sweep's chunks on disk beside its output (OUT.parts/): each chunk's table written as it is done,
atomically, with its checksum in plan.json, so that an interrupted sweep resumes from what it wrote."""

from __future__ import annotations

import hashlib
import json
import shutil
import threading
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..export.output import atomic_write
from .sweep_plan import SweepPlan


def file_sha256(path) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class Parts:
    """The chunks a sweep has written so far, beside its output: OUT.parts/{plan.json, sums.txt, chunk_*.npz}.

    plan.json holds the plan's key (written atomically with the first chunk); sums.txt the SHA-256 of
    every chunk written, a line a chunk ("index hex") appended after the chunk (a folder of an older
    version has them in plan.json's "chunks", still read). Rewriting every checksum after each chunk
    cost a CPU sweep of 30,000 points 1.5 s and grew with the square of its chunks; an appended line
    is the same few bytes for the millionth. A chunk counts as done only when its bytes match its
    checksum: a chunk truncated or changed on disk, or one written but not yet in sums.txt (an
    interrupt between the two; a torn last line is not a checksum), is removed and pressed again on
    resume (:attr:`damaged` lists them). Nothing here is fsynced (a rename, not a sync: fewer syncs a
    chunk on the writer's thread): what a power cut loses fails its checksum, or leaves no readable
    plan.json, and is pressed again. The output is synced.
    """

    def __init__(self, out: Path, plan: SweepPlan):
        self.dir = Path(str(out) + ".parts")
        self.plan = plan
        self._key = None
        self._base_key = None
        self.created = False
        """Whether open() made the folder (a run refused before its first chunk then removes it)."""
        self.dropped: str | None = None
        """Why open() removed every chunk it found (None: it kept those that matched)."""
        self._manifest_due = False  # a new folder's plan.json: written with its first chunk
        self.sums: dict[int, str] = {}
        """Chunk index -> SHA-256 of its file, as written."""
        self.damaged: list[int] = []
        """Chunks found on disk by open() that did not match their checksum (removed, to be pressed again)."""
        self.written: dict[int, dict] = {}
        """Chunk index -> the columns this process wrote to its file (gather() takes them as they are)."""
        self.table: dict | None = None
        """The output's columns, every point, filled in as write() writes each chunk (on the writer's
        thread, while the next chunks press): gather() returns it when this process wrote every chunk."""
        self.rows_file = None
        """An NpzRows of the output (export/npz_rows.py) that write() also writes each chunk's rows to,
        or None."""
        self._lock = threading.Lock()  # chunks finish on several threads (several GPUs)

    @property
    def key(self) -> str:
        """The plan's key (SweepPlan.key: it hashes every point, so it waits for their sampling)."""
        if self._key is None:
            self._key = self.plan.key()
        return self._key

    @property
    def manifest(self) -> Path:
        return self.dir / "plan.json"

    @property
    def sums_log(self) -> Path:
        return self.dir / "sums.txt"

    def chunk_path(self, i: int) -> Path:
        return self.dir / f"chunk_{i:06d}.npz"

    @property
    def base_key(self) -> str:
        """The plan's key but its chunking (which cuts the work, not a number): a folder of the same plan cut
        into other chunks is started again, not refused."""
        if self._base_key is None:
            self._base_key = replace(self.plan, chunk=0, tail=0).key()
        return self._base_key

    def open(self) -> list[int]:
        """Create or reuse the parts folder; returns the chunk indices already done (checksums verified).

        A new folder's plan.json is written with its first chunk (on the writer's thread: the key waits
        for the points), so a folder with neither plan.json nor a chunk is one a run left before its
        first chunk: taken as new. Chunks that cannot be verified (plan.json missing or unreadable: a run
        killed while the folder was removed, a truncated file) or that were cut for other chunks are
        removed and pressed again (:attr:`dropped` says why); a readable plan.json of another plan is refused."""
        self.dropped = None
        if self.dir.exists() and (self.manifest.exists() or any(self.dir.glob("chunk_*.npz"))):
            try:
                data = json.loads(self.manifest.read_text())
                found, base = data["key"], data.get("base")
                self.sums = {int(i): str(h) for i, h in data.get("chunks", {}).items()}
                self.sums.update(self._logged_sums())
            except (OSError, ValueError, KeyError, TypeError, AttributeError):
                found = base = None
                self.dropped = "had no readable plan.json to check them against"
            if found is not None and found != self.key:
                if base != self.base_key:
                    raise InputError(
                        f"{self.dir} holds parts of a different sweep (other mesh, points or parameters): "
                        f"delete it, or give another --out"
                    )
                self.dropped = "were cut into other chunks"
            if self.dropped is not None:
                self._clear()
                return []
        else:
            self.created = not self.dir.exists()
            self.dir.mkdir(exist_ok=True)
            self._manifest_due = True
            return []
        done, self.damaged = [], []
        present = {p.name for p in self.dir.iterdir()}  # one listing, not a look-up a chunk
        for i in range(len(self.plan.chunks)):
            path = self.chunk_path(i)
            if path.name not in present:
                continue
            if self.sums.get(i) == file_sha256(path):
                done.append(i)
            else:
                self.damaged.append(i)
                path.unlink()
                self.sums.pop(i, None)
        return done

    def _logged_sums(self) -> dict[int, str]:
        # sums.txt's checksums ({} without one); a line that is not "index hex" (a torn last line) is skipped
        try:
            text = self.sums_log.read_text()
        except FileNotFoundError:
            return {}
        sums = {}
        for line in text.splitlines():
            fields = line.split()
            if len(fields) == 2 and fields[0].isdigit() and len(fields[1]) == 64:
                sums[int(fields[0])] = fields[1]
        return sums

    def _clear(self) -> None:
        """Remove every chunk, the checksums and plan.json (the folder stays): the parts start again."""
        for path in self.dir.glob("chunk_*.npz"):
            path.unlink(missing_ok=True)
        self.sums_log.unlink(missing_ok=True)
        self.manifest.unlink(missing_ok=True)
        self.sums = {}
        self._manifest_due = True

    def _write_manifest(self) -> None:
        # a new folder's (or one cleared): no checksum yet, and none of another run's left in sums.txt
        data = {"key": self.key, "base": self.base_key, "points": len(self.plan.vertices)}
        self.sums_log.unlink(missing_ok=True)
        atomic_write(self.manifest, lambda tmp: Path(tmp).write_text(json.dumps(data)), sync=False)

    def write(self, i: int, columns: dict) -> None:
        """Write chunk `i` atomically, then its checksum into plan.json."""
        with self._lock:
            if self._manifest_due:  # before any chunk: a folder with a chunk always has its plan.json
                self._write_manifest()
                self._manifest_due = False
        digest = file_sha256(self.plan.table.write(self.chunk_path(i), columns, sync=False))
        with self._lock:
            self.sums[i] = digest
            with open(self.sums_log, "a") as log:
                log.write(f"{i} {digest}\n")
            self.written[i] = columns
            if self.table is None:
                n = len(self.plan.vertices)
                self.table = {c: np.empty((n, *np.shape(columns[c])[1:]), dtype=np.asarray(columns[c]).dtype) for c in self.plan.table.dtypes}
            begin, end = self.plan.chunks[i]
            for c in self.plan.table.dtypes:
                self.table[c][begin:end] = columns[c]
        if self.rows_file is not None:  # the output's rows too, in place (its own lock where it needs one)
            self.rows_file.rows(begin, columns)

    def gather(self) -> dict:
        """Every chunk's columns, in point order: those this process wrote from memory, the others read
        back; InputError for a chunk found damaged."""
        if len(self.written) == len(self.plan.chunks):
            return self.table
        parts = []
        for i in range(len(self.plan.chunks)):
            if i in self.written:
                parts.append(self.written[i])
                continue
            path = self.chunk_path(i)
            try:
                if self.sums.get(i) != file_sha256(path):
                    raise ValueError("its checksum does not match plan.json")
                parts.append(self.plan.table.read(path))
            except (OSError, ValueError, KeyError, zipfile.BadZipFile, InputError) as exc:
                raise InputError(f"{path}: damaged ({exc}); run the same command again to press that chunk again") from exc
        return {c: np.concatenate([p[c] for p in parts]) for c in self.plan.table.dtypes}

    def discard_if_new(self) -> None:
        """Remove the folder where open() made it and no chunk is done (a run refused before any result)."""
        if self.created and not self.sums:
            self.remove()

    def remove(self) -> None:
        """Remove the folder: the chunks first, then the checksums, plan.json last, so that a run killed on
        the way leaves a plan.json beside the chunks still there (resumed), never chunks without one."""
        if self.dir.is_dir():
            for path in self.dir.iterdir():
                if path not in (self.manifest, self.sums_log):
                    path.unlink(missing_ok=True) if not path.is_dir() else shutil.rmtree(path, ignore_errors=True)
            self.sums_log.unlink(missing_ok=True)
        shutil.rmtree(self.dir, ignore_errors=True)
