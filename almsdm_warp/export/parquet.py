"""Parquet tables (Apache Arrow's pyarrow, the ``parquet`` extra): one row a press, a column a quantity.

Each column's Arrow type follows its layout's dtype (int64, float64, string; a fixed-size column
"float64[N]", N values a row: a fixed-size list); the schema's metadata holds the layout's entries
(a dataset's "schema": each column's unit and meaning) and, under ``almsdm``, what made the table
(the package and its version, the scene, the mesh's hash, the material, the law, the lesion: the
`info` a writer is given), so that a file read on its own says where its numbers come from
(:func:`read_info`). pandas and polars read it as it is (tests/test_parquet.py).

:class:`ParquetRows` takes a sweep's rows as its chunks come, through Arrow's ParquetWriter (row
groups written in order, the file's footer at the end): rows that come ahead of a gap wait for it.
Writes are atomic (export/output.py). pyarrow is imported only here, when a .parquet is asked for;
without it, one InputError says how to install it.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np

from ..errors import InputError
from .output import discard, publish, temp_path

INFO_KEY = "almsdm"
"""The schema metadata's key whose value is the JSON of what made the table (the writer's `info`)."""
ROW_GROUP = 1 << 16
"""Rows a row group holds at least while rows stream in (the last may hold fewer)."""


def require_pyarrow(path=None):
    """pyarrow.parquet, or InputError saying how to install it (the command line checks it before any work)."""
    try:
        import pyarrow.parquet as pq
    except ImportError as exc:
        where = f"{path}: " if path is not None else ""
        raise InputError(f"{where}a .parquet table needs pyarrow: pip install 'almsdm_warp[parquet]' (or write .npz or .csv)") from exc
    return pq


def arrow_schema(layout, names, info: dict | None):
    """The Arrow schema of `layout`'s columns `names`, its metadata the layout's entries and `info`."""
    import pyarrow as pa

    scalar = {"int64": pa.int64(), "float64": pa.float64(), "str": pa.string()}
    fields = []
    for name in names:
        base, width = split_dtype(layout.dtypes[name])
        fields.append(pa.field(name, scalar[base] if width is None else pa.list_(scalar[base], width), nullable=False))
    meta = {str(k): str(v) for k, v in layout.meta.items()}
    meta[INFO_KEY] = json.dumps({"table": layout.name, **(info or {})}, default=str)
    return pa.schema(fields, metadata=meta)


def split_dtype(dtype: str):
    """("float64", 16) for "float64[16]" (N values a row), (dtype, None) for a scalar column."""
    if dtype.endswith("]"):
        base, width = dtype[:-1].split("[")
        return base, int(width)
    return dtype, None


def arrow_table(columns: dict, schema):
    """`columns` (numpy, cast to their layout's dtypes) as an Arrow table of `schema`."""
    import pyarrow as pa

    arrays = []
    for f in schema:
        values = columns[f.name]
        if pa.types.is_fixed_size_list(f.type):
            flat = pa.array(np.ascontiguousarray(values, dtype=np.float64).reshape(-1), type=f.type.value_type)
            arrays.append(pa.FixedSizeListArray.from_arrays(flat, f.type.list_size))
        else:
            arrays.append(pa.array(values.tolist() if f.type == pa.string() else values, type=f.type))
    return pa.Table.from_arrays(arrays, schema=schema)


def write_parquet(tmp, columns: dict, layout, info: dict | None = None) -> None:
    """Write `columns` as one Parquet file at `tmp` (TableFormat.write)."""
    pq = require_pyarrow(tmp)
    pq.write_table(arrow_table(columns, arrow_schema(layout, list(columns), info)), tmp)


def read_parquet(path: Path, layout) -> dict:
    """The layout's columns of the Parquet table at `path` (TableFormat.read); InputError for a file that is not one."""
    pq = require_pyarrow(path)
    import pyarrow as pa

    try:
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as exc:
        raise InputError(f"{path}: not a {layout.name} (not a Parquet file: {exc})") from exc
    names = layout.columns(table.column_names)
    missing = [c for c in names if c not in table.column_names]
    if missing:
        raise InputError(f"{path}: not a {layout.name} (no column {missing[0]!r})")
    out = {}
    for c in names:
        base, width = split_dtype(layout.dtypes[c])
        col = table.column(c).combine_chunks()
        if width is not None:
            out[c] = col.flatten().to_numpy(zero_copy_only=False).astype(np.float64).reshape(-1, width)
        elif base == "str":
            out[c] = np.array(col.to_pylist(), dtype=str)
        else:
            out[c] = col.to_numpy(zero_copy_only=False).astype(base)
    return out


def read_info(path) -> dict:
    """What made the Parquet table at `path` (its schema metadata's INFO_KEY entry), as a dict."""
    pq = require_pyarrow(path)
    meta = pq.read_schema(path).metadata or {}
    return json.loads(meta.get(INFO_KEY.encode(), b"{}"))


class ParquetRows:
    """`path` (.parquet) with `n` rows of `layout`'s columns, written by rows(begin, columns) as they come
    (any order: rows after a gap wait for it) in row groups of ROW_GROUP rows or more, and published by
    finish(columns), which takes every column whole (the rows not written yet); discard() removes the
    temporary file. NpzRows's interface (export/npz_rows.py)."""

    def __init__(self, path, n: int, layout, info: dict | None = None):
        pq = require_pyarrow(path)
        self.path, self.n, self.layout = Path(path), int(n), layout
        self.schema = arrow_schema(layout, layout.columns(layout.dtypes), info)
        self.tmp, self.writer = temp_path(self.path), None
        self.done, self.waiting, self.held = 0, {}, []  # rows written; blocks ahead of a gap; rows not yet a row group
        self._lock = threading.Lock()  # rows() from several writing threads
        try:
            self.writer = pq.ParquetWriter(self.tmp, self.schema)
        except OSError as exc:
            self.discard()
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def rows(self, begin: int, columns: dict) -> None:
        """Rows begin.. of every column (columns: name -> array, a row each); from any thread."""
        block = self.layout.cast({c: columns[c] for c in self.schema.names})
        with self._lock:
            self.waiting[int(begin)] = block
            while self.done in self.waiting:
                block = self.waiting.pop(self.done)
                self.held.append(block)
                self.done += len(block[self.schema.names[0]])
            if sum(len(b[self.schema.names[0]]) for b in self.held) >= ROW_GROUP:
                self._flush()

    def _flush(self) -> None:
        if not self.held:
            return
        block = {c: np.concatenate([b[c] for b in self.held]) for c in self.schema.names}
        self.held = []
        try:
            self.writer.write_table(arrow_table(block, self.schema))
        except OSError as exc:  # a full disk: one line, as atomic_path says it
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def finish(self, columns: dict) -> Path:
        """Write the rows not written yet (from `columns`, every row), close the file and publish it."""
        whole = self.layout.cast({c: columns[c] for c in self.schema.names})
        while self.done < self.n:
            ahead = [b for b in self.waiting if b > self.done]
            end = min(ahead, default=self.n)
            self.rows(self.done, {c: v[self.done : end] for c, v in whole.items()})
        self._flush()
        try:
            self.writer.close()
            self.writer = None
            return publish(self.tmp, self.path)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot write: {exc.strerror or exc}") from exc

    def discard(self) -> None:
        """Remove the unfinished file."""
        if self.writer is not None:
            try:
                self.writer.close()
            except OSError:
                pass
            self.writer = None
        discard(self.tmp)
