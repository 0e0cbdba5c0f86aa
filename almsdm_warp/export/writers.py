"""Output files by suffix: one table from a suffix to what the file holds and the function that writes it.

The command line checks every output path here before any work (``--json``, ``--out``, ``--usd``,
``--png``) and writes its records through :func:`write_output`. A new record format is one
function and one line of :data:`FORMATS`; the table formats are export/tables.py's TABLE_FORMATS
(each table written by its layout, TableLayout.write). A suffix a flag does not take is one
InputError that lists the ones it does.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..errors import InputError
from .output import check_writable, write_json
from .tables import TABLE_FORMATS, suffix_error

KINDS = {"record": "JSON", "table": "table", "stage": "USD", "image": "PNG"}
"""What an output holds -> the word its messages use: a JSON record (--json), a table of columns
(sweep --out), a USD stage (--usd), a picture (--png)."""


@dataclass(frozen=True)
class OutputFormat:
    """One file format an output may be written in."""

    suffix: str
    """The file name's suffix, lower case, with its dot."""
    kind: str
    """What it holds: a key of KINDS."""
    what: str
    """The format in a few words."""
    write: Callable[[object, object], Path] | None
    """write(path, data) -> path, atomic; None for a table, which its layout writes (export.tables.TableLayout.write),
    and for a stage or a picture, which its producer writes (export.usd.UsdRecorder frame by frame,
    export.preview.render_png, export.sweep_png.plot_sweep)."""


FORMATS: dict[str, OutputFormat] = {
    f.suffix: f
    for f in (
        OutputFormat(".json", "record", "JSON, indented", write_json),
        *(OutputFormat(t.suffix, "table", t.what, None) for t in TABLE_FORMATS.values()),
        OutputFormat(".usda", "stage", "a USD stage as text", None),
        OutputFormat(".usdc", "stage", "a USD stage as a binary crate", None),
        OutputFormat(".usd", "stage", "a USD stage (crate)", None),
        OutputFormat(".png", "image", "a PNG picture", None),
    )
}
"""Every output format, by suffix."""


def suffixes(kind: str) -> tuple[str, ...]:
    """The suffixes an output of `kind` may have, in FORMATS order."""
    if kind not in KINDS:
        raise ValueError(f"unknown output kind {kind!r} (allowed: {', '.join(KINDS)})")
    return tuple(s for s, f in FORMATS.items() if f.kind == kind)


def output_format(path, kind: str, flag: str | None = None) -> OutputFormat:
    """The format of an output of `kind` at `path`, from its suffix; InputError for a suffix that
    kind does not take (the message starts with `flag` where one is given)."""
    allowed = suffixes(kind)
    suffix = Path(path).suffix.lower()
    if suffix not in allowed:
        raise suffix_error(path, KINDS[kind], allowed, flag)
    return FORMATS[suffix]


def check_output(path, kind: str, flag: str | None = None) -> Path:
    """Fail before any work when `path` cannot take an output of `kind`: its suffix, the package its
    format needs (a table's TableFormat.check: .parquet without pyarrow), then its folder."""
    fmt = output_format(path, kind, flag)
    if fmt.kind == "table":
        TABLE_FORMATS[fmt.suffix].check(f"{flag} {path}" if flag else path)
    return check_writable(path)


def write_output(path, data, kind: str, flag: str | None = None) -> Path:
    """Write `data` (a record: a dict) to `path` in its suffix's format, atomically."""
    fmt = output_format(path, kind, flag)
    if fmt.write is None:
        raise TypeError(f"{fmt.suffix} ({fmt.what}) is written by its producer (a table: by its layout), not by write_output")
    return fmt.write(path, data)


def _same_file(a, b) -> bool:
    ra, rb = Path(os.path.realpath(a)), Path(os.path.realpath(b))
    if ra == rb:
        return True
    try:
        return os.path.samefile(a, b)  # hard links, bind mounts
    except OSError:  # one of them does not exist yet
        return False


def check_distinct(outputs: dict, inputs: dict | None = None) -> None:
    """InputError when two outputs name the same file (one would silently replace the other) or an
    output names an input (it would be replaced by the output). outputs, inputs: flag -> path,
    None for one not given; a path that names no existing file can match only an output."""
    outs = [(flag, p) for flag, p in outputs.items() if p is not None]
    for k, (flag, p) in enumerate(outs):
        for other, q in outs[:k]:
            if _same_file(p, q):
                raise InputError(f"{other} {q} and {flag} {p} are the same file: give each output its own path")
        for what, q in (inputs or {}).items():
            if q is not None and Path(q).exists() and _same_file(p, q):
                raise InputError(f"{flag} {p} is the input {what} {q}: the output would replace it; give another path")
