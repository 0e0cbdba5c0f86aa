"""An .npz table written row block by row block while it is computed, published when complete.

A sweep's table is its chunks' rows; written as a whole at the end it costs a write and an fsync
of every byte after the last press (about 0.1 s for 1e6 rows on an H200's host). Here the file's
layout is fixed first (one stored, uncompressed ZIP entry per column, each a 1-D .npy array of
known length and dtype: what ``np.savez`` writes, readable by ``np.load``), each block of rows
goes to its place in every column as it comes, flushed to disk on the caller's thread, and
finish() adds what only the whole holds (each entry's CRC-32, the central directory) and renames
the temporary file to the target (export/output.py's publish): nothing is half-written.
"""

from __future__ import annotations

import io
import os
import struct
import threading
import zlib
from pathlib import Path

import numpy as np

from ..errors import InputError
from .output import discard, publish, temp_path

_LOCAL = struct.Struct("<IHHHHHIIIHH")  # local file header (30 bytes), then name and extra
_CENTRAL = struct.Struct("<IHHHHHHIIIHHHHHII")  # central directory entry (46 bytes)
_ZIP64_EOCD = struct.Struct("<IQHHIIQQQQ")
_ZIP64_LOCATOR = struct.Struct("<IIQI")
_EOCD = struct.Struct("<IHHHHIIH")
_VERSION = 45  # ZIP64
_FULL32 = 0xFFFFFFFF
_DOS_DATE = (1980 - 1980) << 9 | 1 << 5 | 1  # 1980-01-01, as np.savez's entries carry a fixed date too
_DOS_TIME = 0


def npy_header(dtype, n: int, width: int | None = None) -> bytes:
    """The .npy header np.save writes before n values of `dtype` (1-D; [n, width] where a width is given; C order)."""
    buf = io.BytesIO()
    shape = (int(n),) if width is None else (int(n), int(width))
    np.lib.format.write_array_header_1_0(buf, {"descr": np.lib.format.dtype_to_descr(np.dtype(dtype)), "fortran_order": False,
                                               "shape": shape})
    return buf.getvalue()


class NpzRows:
    """`path` (.npz) with `n` rows of the columns `dtypes` (name -> dtype), written by rows(begin,
    columns) in any order and published by finish(columns), which takes every column whole (for
    the CRCs, and the rows not yet written); discard() removes the temporary file. widths: name ->
    values a row of a column stored [n, width] (export/tables.py's "float64[N]"), 1 or absent: 1-D."""

    def __init__(self, path, n: int, dtypes: dict, widths: dict | None = None):
        self.path, self.n = Path(path), int(n)
        self.dtypes = {name: np.dtype(d) for name, d in dtypes.items()}
        self.widths = {name: w for name, w in (widths or {}).items() if w != 1}
        self.tmp, self.fd = temp_path(self.path), None
        self._crc_lock = threading.Lock()  # rows() from several writing threads: their CRC-32s in order
        try:
            self.fd = os.open(self.tmp, os.O_RDWR)
            self._lay_out()
        except OSError as exc:
            self.discard()
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def _lay_out(self) -> None:
        # each column's entry: (name, local header's offset, .npy header, its values' offset, entry size)
        self.entries = []
        offset = 0
        for name, dtype in self.dtypes.items():
            fname, head = f"{name}.npy".encode(), npy_header(dtype, self.n, self.widths.get(name))
            row = dtype.itemsize * self.widths.get(name, 1)
            data = offset + _LOCAL.size + len(fname) + 20 + len(head)
            self.entries.append((fname, offset, head, data, len(head) + self.n * row))
            offset = data + self.n * row
        self.central = offset
        os.ftruncate(self.fd, offset)
        self.written = np.zeros(self.n, dtype=bool)
        # each entry's CRC-32 over its bytes so far: rows are added in order, those that come early held
        # (their values, by first row) until the rows before them have come
        self.crc = [zlib.crc32(head) for _, _, head, _, _ in self.entries]
        self.crc_rows = 0
        self.early: dict[int, tuple[int, list]] = {}

    def rows(self, begin: int, columns: dict) -> None:
        """Rows begin.. of every column (columns: name -> 1-D array), written in place and flushed to disk
        (from several threads at once, each its own rows)."""
        try:
            self._rows(begin, columns)
        except OSError as exc:  # a full disk: one line, as atomic_path says it
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def _rows(self, begin: int, columns: dict) -> None:
        blocks = []
        for (fname, _, _, data, _), (name, dtype) in zip(self.entries, self.dtypes.items()):
            row = dtype.itemsize * self.widths.get(name, 1)
            values = memoryview(np.ascontiguousarray(columns[name], dtype=dtype)).cast("B")
            os.pwrite(self.fd, values, data + begin * row)
            blocks.append(values)
        end = begin + len(values) // row
        self.written[begin:end] = True
        with self._crc_lock:
            self.early[begin] = (end, blocks)  # views of the caller's columns, which it keeps (Parts.written)
            while self.crc_rows in self.early:  # the rows that now follow in order, into each entry's CRC-32
                end, blocks = self.early.pop(self.crc_rows)
                self.crc = [zlib.crc32(values, crc) for values, crc in zip(blocks, self.crc)]
                self.crc_rows = end
        os.fdatasync(self.fd)

    def finish(self, columns: dict) -> Path:
        """Write the rows not written yet, each entry's header and the central directory; publish."""
        try:
            return self._finish(columns)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def _finish(self, columns: dict) -> Path:
        missing = np.flatnonzero(~self.written)
        if len(missing):
            cuts = np.flatnonzero(np.diff(missing) != 1) + 1
            for run in np.split(missing, cuts):
                self._rows(int(run[0]), {name: np.asarray(columns[name])[run[0] : run[-1] + 1] for name in self.dtypes})
        central = []
        for (fname, at, head, data, size), crc in zip(self.entries, self._crcs(columns)):
            extra = struct.pack("<HHQQ", 1, 16, size, size)
            local = _LOCAL.pack(0x04034B50, _VERSION, 0, 0, _DOS_TIME, _DOS_DATE, crc, _FULL32, _FULL32, len(fname), len(extra))
            os.pwrite(self.fd, local + fname + extra + head, at)
            extra = struct.pack("<HHQQQ", 1, 24, size, size, at)
            central.append(_CENTRAL.pack(0x02014B50, _VERSION, _VERSION, 0, 0, _DOS_TIME, _DOS_DATE, crc, _FULL32, _FULL32,
                                         len(fname), len(extra), 0, 0, 0, 0o600 << 16, _FULL32) + fname + extra)
        directory = b"".join(central)
        end64 = self.central + len(directory)
        tail = _ZIP64_EOCD.pack(0x06064B50, _ZIP64_EOCD.size - 12, _VERSION, _VERSION, 0, 0, len(central), len(central),
                                len(directory), self.central)
        tail += _ZIP64_LOCATOR.pack(0x07064B50, 0, end64, 1)
        tail += _EOCD.pack(0x06054B50, 0, 0, 0xFFFF, 0xFFFF, _FULL32, _FULL32, 0)
        os.pwrite(self.fd, directory + tail, self.central)
        os.close(self.fd)
        self.fd = None
        return publish(self.tmp, self.path)

    def _crcs(self, columns: dict) -> list[int]:
        # each entry's CRC-32: the rows added in order so far, then the rest from `columns` (the values the
        # file holds), a thread a column (zlib leaves the GIL for large buffers)
        from concurrent.futures import ThreadPoolExecutor

        def rest(k: int, name: str, dtype) -> int:
            values = np.ascontiguousarray(np.asarray(columns[name])[self.crc_rows :], dtype=dtype)
            return zlib.crc32(memoryview(values).cast("B"), self.crc[k])

        if self.crc_rows >= self.n:
            return list(self.crc)
        with ThreadPoolExecutor(len(self.dtypes)) as pool:
            return list(pool.map(rest, range(len(self.dtypes)), self.dtypes, self.dtypes.values()))

    def discard(self) -> None:
        """Remove the unfinished file."""
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        discard(self.tmp)
