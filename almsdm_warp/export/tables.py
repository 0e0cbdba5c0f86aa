"""Tables of columns by suffix: every table the package writes or reads (a sweep's, its parts', a
dataset's, a trace) goes through :data:`TABLE_FORMATS`.

What a table holds is data, a :class:`TableLayout` (its columns in order, each one's dtype, the
columns an older or a smaller table may lack, and entries a format may keep beside the columns,
such as a dataset's "schema"); how a file holds it is a :class:`TableFormat`. A new format is a
writer and a reader (and, where the format can take rows as they come, a row writer such as
export/npz_rows.py's NpzRows) and one line of TABLE_FORMATS; every table, and the suffixes the
command line takes for one (export/writers.py), follow. Writes are atomic (export/output.py).

A column's dtype is "int64", "float64", "str", or "float64[N]": N values a row (a force curve, a
tactile map), a 2-D array [rows, N] in memory, a fixed-size list in Parquet, an [rows, N] array in
an .npz, and N columns NAME[0] .. NAME[N-1] in a CSV. A writer may be given `info`, what made the
table (the scene, the mesh's hash, the material, ...): Parquet keeps it in its schema's metadata
(export/parquet.py); CSV and NPZ have no place for it and leave it out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import InputError
from .npz_rows import NpzRows
from .output import atomic_write
from .parquet import ParquetRows, read_parquet, require_pyarrow, split_dtype, write_parquet

CSV_BLOCK = 1 << 16
"""Rows formatted at once in a CSV (each column a block at a time)."""


@dataclass(frozen=True)
class TableLayout:
    """What a table holds, whatever the file's format."""

    name: str
    """The table in a few words, for messages ("sweep table": "PATH: not a sweep table ...")."""
    dtypes: dict
    """Column -> "int64", "float64", "str" or "float64[N]" (N values a row), in the table's order."""
    optional: tuple = ()
    """Columns a table may lack (written where the columns given hold them; a reader takes a table without them)."""
    meta: dict = field(default_factory=dict)
    """Entry -> text, kept beside the columns by a format that can (an .npz: a 0-d string array each, first)."""

    def columns(self, present) -> list[str]:
        """The columns of a table that holds `present`: every required one, the optional ones present, in order."""
        return [c for c in self.dtypes if c in present or c not in self.optional]

    def cast(self, columns: dict) -> dict:
        """`columns` as arrays of their dtypes, in order (a required one missing: KeyError)."""
        return {c: np.asarray(columns[c]).astype(_dtype(self.dtypes[c]), copy=False) for c in self.columns(columns)}

    def write(self, path, columns: dict, info: dict | None = None, sync: bool = True) -> Path:
        """Write `columns` to `path` in its suffix's format, atomically (fsynced unless `sync` is False: see
        export/output.py's publish); `info`: what made the table, kept where the format can (Parquet's schema metadata)."""
        fmt, columns = table_format(path), self.cast(columns)
        fmt.check(path)
        atomic_write(path, lambda tmp: fmt.write(tmp, columns, self, info), sync)
        return Path(path)

    def read(self, path) -> dict:
        """The columns of the table at `path` (by its suffix); InputError for a file that is not one."""
        return table_format(path).read(Path(path), self)

    def rows(self, path, n: int, info: dict | None = None):
        """A writer of `n` rows to `path` as they come (rows(begin, columns), finish(columns), discard()),
        or None where the format writes a table only whole (an .npz of a layout with entries beside the columns)."""
        fmt = table_format(path)
        fmt.check(path)
        return None if fmt.rows is None else fmt.rows(path, n, self, info)

    def widths(self) -> dict:
        """Column -> values a row (1 for a scalar column)."""
        return {c: split_dtype(d)[1] or 1 for c, d in self.dtypes.items()}


def _dtype(name: str):
    base = split_dtype(name)[0]
    return str if base == "str" else np.dtype(base)


def csv_names(name: str, width: int) -> list[str]:
    """The CSV columns of a column of `width` values a row: NAME, or NAME[0] .. NAME[width - 1]."""
    return [name] if width == 1 else [f"{name}[{k}]" for k in range(width)]


# -- CSV: a header line, then a row a line; floats as repr writes them (the shortest text that reads back the same)
def write_csv(tmp, columns: dict, layout: TableLayout, info: dict | None = None) -> None:
    flat = {}  # a column of N values a row: N columns
    for name, col in columns.items():
        parts = col.reshape(len(col), -1).T if col.ndim > 1 else [col]
        flat.update(zip(csv_names(name, len(parts)), parts))
    n = len(next(iter(flat.values()))) if flat else 0
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(",".join(flat) + "\n")
        for b in range(0, n, CSV_BLOCK):
            text = [map(repr if col.dtype.kind == "f" else str, col[b : b + CSV_BLOCK].tolist()) for col in flat.values()]
            f.write("".join(line + "\n" for line in map(",".join, zip(*text))))


MM_DECIMALS = 9
"""Decimals a length in millimetres is written to (a picometre): below any mesh's float32 resolution, and
above the noise of a unit's conversion (0.0232598 m x 1000 is -23.259800000000002 in binary)."""


def millimetres(metres):
    """`metres` [m] as millimetres for a table, rounded to MM_DECIMALS: the file's -23.2598, not the
    -23.259800000000002 a conversion leaves (what a CSV writes is the shortest text of the value)."""
    return np.round(np.asarray(metres, dtype=np.float64) * 1e3, MM_DECIMALS)


def read_csv(path: Path, layout: TableLayout) -> dict:
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip().split(",")
    widths = layout.widths()
    present = {c for c in layout.dtypes if csv_names(c, widths[c])[0] in header}
    names = layout.columns(present)
    if header != [h for c in names for h in csv_names(c, widths[c])]:
        raise InputError(f"{path}: not a {layout.name} (header {header})")
    parsed = {"str": object, "int64": np.int64, "float64": np.float64}  # str: read as Python strings, then sized
    dtype = np.dtype([(h, parsed[split_dtype(layout.dtypes[c])[0]]) for c in names for h in csv_names(c, widths[c])])
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "loadtxt: input contained no data")  # a header alone: no rows
        data = np.loadtxt(path, delimiter=",", skiprows=1, dtype=dtype, comments=None, ndmin=1, encoding="utf-8")
    out = {}
    for c in names:
        if layout.dtypes[c] == "str":
            out[c] = np.array(data[c].tolist(), dtype=str)
        elif widths[c] > 1 or split_dtype(layout.dtypes[c])[1] is not None:
            out[c] = np.stack([np.array(data[h]) for h in csv_names(c, widths[c])], axis=1).reshape(len(data), widths[c])
        else:
            out[c] = np.array(data[c])
    return out


# -- NPZ: a NumPy archive, one array a column (np.load reads it without pickle)
def write_npz(tmp, columns: dict, layout: TableLayout, info: dict | None = None) -> None:
    with open(tmp, "wb") as f:
        np.savez(f, **{k: np.array(text) for k, text in layout.meta.items()}, **columns)


def read_npz(path: Path, layout: TableLayout) -> dict:
    with np.load(path, allow_pickle=False) as z:
        missing = [c for c in layout.columns(z.files) if c not in z.files]
        if missing:
            raise InputError(f"{path}: not a {layout.name} (no column {missing[0]!r})")
        return {c: z[c] for c in layout.columns(z.files)}


def npz_rows(path, n: int, layout: TableLayout, info: dict | None = None):
    """NpzRows of `layout`'s columns, or None for a layout with entries beside the columns (written whole)."""
    if layout.meta:
        return None
    return NpzRows(path, n, {c: _dtype(d) for c, d in layout.dtypes.items()}, layout.widths())


def no_check(path) -> None:
    """A format that every installation can write."""


@dataclass(frozen=True)
class TableFormat:
    """One file format a table may be written in."""

    suffix: str
    """The file name's suffix, lower case, with its dot."""
    what: str
    """The format in a few words."""
    write: Callable[[object, dict, TableLayout, dict | None], None]
    """write(temporary path, columns cast to the layout's dtypes, layout, info): the whole file there."""
    read: Callable[[Path, TableLayout], dict]
    """read(path, layout) -> columns; InputError for a file that does not hold the layout's table."""
    rows: Callable | None = None
    """rows(path, n, layout, info) -> a writer of rows as they come (export/npz_rows.py's NpzRows), or None."""
    check: Callable = no_check
    """check(path): InputError where this installation cannot write the format (a package missing),
    called before any work (export/writers.py's check_output) and by every write."""


TABLE_FORMATS: dict[str, TableFormat] = {
    f.suffix: f
    for f in (
        TableFormat(".csv", "comma-separated columns, a header line first", write_csv, read_csv),
        TableFormat(".npz", "a NumPy archive, one array a column", write_npz, read_npz, npz_rows),
        TableFormat(".parquet", "Apache Parquet (the parquet extra: pyarrow)", write_parquet, read_parquet, ParquetRows,
                    require_pyarrow),
    )
}
"""Every table format, by suffix."""


def suffix_error(path, what: str, allowed, flag: str | None = None) -> InputError:
    """The InputError for `path` whose suffix is not one of `allowed` for a `what` output."""
    p = Path(path)
    where = f"{flag} {p}" if flag else str(p)
    got = repr(p.suffix) if p.suffix else "(none)"
    return InputError(f"{where}: unknown {what} suffix {got} (allowed: {', '.join(allowed)})")


def table_format(path) -> TableFormat:
    """The table format of `path`, from its suffix; InputError for one no format has."""
    fmt = TABLE_FORMATS.get(Path(path).suffix.lower())
    if fmt is None:
        raise suffix_error(path, "table", TABLE_FORMATS)
    return fmt
