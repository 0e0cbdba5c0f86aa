"""Reader for legacy VTK files (`.vtk`), ASCII and BINARY: DATASET POLYDATA and UNSTRUCTURED_GRID.

POLYDATA: POINTS, POLYGONS (fan-triangulated) and TRIANGLE_STRIPS (alternating winding);
VERTICES and LINES are ignored and reported. UNSTRUCTURED_GRID: POINTS, CELLS and CELL_TYPES;
tetrahedra (VTK type 10) and triangles (5) are kept, vertices, poly-vertices, lines and polylines
(1-4) ignored and reported, any other cell type is an error. Both cell layouts are read: the
classic list (`n i j k ...`) and VTK 5.1's OFFSETS / CONNECTIVITY. FIELD arrays and METADATA
blocks are skipped; reading stops at POINT_DATA / CELL_DATA.

Keyword lines are text; the numbers after them are ASCII, or big-endian binary of the type the
keyword line names (as VTK writes them, e.g. 3D Slicer's binary POLYDATA). Every announced count
is checked: a file that ends early, a cell that runs past its section, an index that is negative
or past the last point are errors naming the file, the line or section, the cell and the value.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError

CELL_SECTIONS = ("VERTICES", "LINES", "POLYGONS", "TRIANGLE_STRIPS")
# VTK cell type -> name, for UNSTRUCTURED_GRID; kept and ignored ones below.
CELL_TYPES = {1: "vertex", 2: "poly_vertex", 3: "line", 4: "polyline", 5: "triangle", 6: "triangle_strip",
              7: "polygon", 8: "pixel", 9: "quad", 10: "tetra", 11: "voxel", 12: "hexahedron", 13: "wedge",
              14: "pyramid", 21: "quadratic_edge", 22: "quadratic_triangle", 23: "quadratic_quad",
              24: "quadratic_tetra", 25: "quadratic_hexahedron"}
IGNORED_CELL_TYPES = {1, 2, 3, 4}
# Binary data types as the keyword lines name them, read big-endian.
_TYPES = {"bit": "u1", "unsigned_char": "u1", "char": "i1", "unsigned_short": "u2", "short": "i2",
          "unsigned_int": "u4", "int": "i4", "unsigned_long": "u8", "long": "i8", "float": "f4", "double": "f8",
          "vtktypeint8": "i1", "vtktypeuint8": "u1", "vtktypeint16": "i2", "vtktypeuint16": "u2",
          "vtktypeint32": "i4", "vtktypeuint32": "u4", "vtktypeint64": "i8", "vtktypeuint64": "u8",
          "vtkidtype": "i8"}
# A keyword line starts with a letter; ASCII numbers do not (nan and inf aside).
_KEYWORD_LINE = re.compile(rb"^[ \t]*(?![-+]?(?:nan|inf)\b)[A-Za-z]", re.MULTILINE | re.IGNORECASE)


def vtk_dataset(head: bytes) -> str | None:
    """The DATASET type named in a legacy VTK header (e.g. 'POLYDATA'), or None."""
    for line in head.splitlines()[:8]:
        words = line.split()
        if len(words) >= 2 and words[0].upper() == b"DATASET":
            return words[1].decode("ascii", "replace").upper()
    return None


def read_legacy_vtk(data: bytes, where: str):
    """(vertices [n, 3] float64, triangles [m, 3] int64 or None, tetrahedra [t, 4] int64 or None,
    notes) from the bytes of a legacy VTK file."""
    lines = data.split(b"\n", 3)
    if len(lines) < 4 or not lines[0].lstrip().lower().startswith(b"# vtk datafile"):
        raise InputError(f"{where}: line 1: not a legacy VTK file (expected '# vtk DataFile Version ...')")
    mode = lines[2].strip().upper()
    if mode not in (b"ASCII", b"BINARY"):
        raise InputError(f"{where}: line 3: expected ASCII or BINARY, got {mode[:40].decode('latin-1')!r}")
    stream = _Stream(data, where, binary=mode == b"BINARY", start=len(data) - len(lines[3]))
    words = stream.keyword_line("DATASET")
    if words is None or words[0] != "DATASET" or len(words) < 2:
        stream.fail("expected 'DATASET POLYDATA' or 'DATASET UNSTRUCTURED_GRID'")
    kind = words[1]
    if kind not in ("POLYDATA", "UNSTRUCTURED_GRID"):
        stream.fail(f"DATASET {kind[:40]} is not supported, only POLYDATA and UNSTRUCTURED_GRID")
    sections = _read_sections(stream, kind)
    points = sections.pop("POINTS", None)
    if points is None:
        raise InputError(f"{where}: the {kind} file has no POINTS section")
    if kind == "POLYDATA":
        return (points, *_polydata_triangles(sections, len(points), where))
    return (points, *_grid_cells(sections, len(points), where))


def _read_sections(stream, kind):
    """{keyword: array or (offsets, connectivity, line)} up to POINT_DATA / CELL_DATA or the end."""
    cell_keys = CELL_SECTIONS if kind == "POLYDATA" else ("CELLS",)
    sections = {}
    while (words := stream.keyword_line()) is not None:
        key, line = words[0], stream.line
        if key in ("POINT_DATA", "CELL_DATA"):
            break
        if key == "POINTS":
            n = stream.count(words, 1, "the POINTS count")
            sections["POINTS"] = stream.array(3 * n, _word(words, 2, "float"), "POINTS", float).reshape(n, 3)
        elif key in cell_keys:
            sections[key] = (*_read_cells(stream, words, key), line)
        elif key == "CELL_TYPES" and kind == "UNSTRUCTURED_GRID":
            n = stream.count(words, 1, "the CELL_TYPES count")
            sections[key] = (stream.array(n, "int", "CELL_TYPES", int), line)
        elif key == "FIELD":
            for _ in range(stream.count(words, 2, "the FIELD array count")):
                array = stream.keyword_line("a FIELD array") or []
                comps, tuples = stream.count(array, 1, "components"), stream.count(array, 2, "tuples")
                stream.array(comps * tuples, _word(array, 3, "float"), f"FIELD array {array[0][:40]}", float)
        elif key == "METADATA":
            stream.skip_block()
        else:
            stream.fail(f"unexpected {key[:40]!r} in a {kind} dataset")
    return sections


def _read_cells(stream, words, key):
    """(offsets [cells + 1], connectivity) of one cell section, classic or OFFSETS / CONNECTIVITY."""
    n = stream.count(words, 1, f"the {key} cell count")
    size = stream.count(words, 2, f"the {key} size")
    if stream.peek_keyword() == "OFFSETS":
        offsets = stream.array(n, _word(stream.keyword_line(), 1, "vtktypeint64"), f"{key} OFFSETS", int)
        nxt = stream.keyword_line(f"CONNECTIVITY after the {key} OFFSETS")
        if nxt is None or nxt[0] != "CONNECTIVITY":
            stream.fail(f"expected CONNECTIVITY after the {n} {key} OFFSETS")
        conn = stream.array(size, _word(nxt, 1, "vtktypeint64"), f"{key} CONNECTIVITY", int)
        if n == 0 or offsets[0] != 0 or offsets[-1] != size or (np.diff(offsets) < 0).any():
            stream.fail(f"{key} OFFSETS must rise from 0 to the connectivity size {size}")
        return offsets, conn
    flat = stream.array(size, "int", key, int)
    k = size // n if n and size % n == 0 else 0
    if k > 1 and (flat[::k] == k - 1).all():  # every cell of the same length: no walk needed
        starts = np.arange(0, size + 1, k, dtype=np.int64)
    else:
        starts = _walk_cells(stream, flat, n, size, key)
    keep = np.ones(size, dtype=bool)
    keep[starts[:-1]] = False
    return starts - np.arange(n + 1), flat[keep]


def _walk_cells(stream, values, n, size, key):
    """Where each cell of a classic list starts: each cell's length says where the next one does."""
    starts = np.zeros(n + 1, dtype=np.int64)
    pos = 0
    for c in range(n):
        if pos >= size or values[pos] < 0 or pos + 1 + values[pos] > size:
            stream.fail(f"{key} cell {c} runs past the section's size {size}")
        starts[c + 1] = pos = pos + 1 + int(values[pos])
    if pos != size:
        stream.fail(f"{key} says size {size}, but its {n} cells use {pos} numbers")
    return starts


def _check_indices(conn, offsets, n_points, what, line, where):
    bad = (conn < 0) | (conn >= n_points)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        cell = int(np.searchsorted(offsets, k, side="right")) - 1
        raise InputError(f"{where}: line {line}: {what} cell {cell} references point {conn[k]}, but POINTS has "
                         f"{n_points} points (0..{n_points - 1})")


def _polydata_triangles(sections, n_points, where):
    triangles, notes = [], []
    for key in CELL_SECTIONS:
        if key not in sections:
            continue
        offsets, conn, line = sections[key]
        _check_indices(conn, offsets, n_points, key, line, where)
        counts = np.diff(offsets)
        if key in ("VERTICES", "LINES"):
            notes.append(f"ignored {len(counts)} {key} cells")
            continue
        small = counts < 3
        if small.any():
            notes.append(f"dropped {int(small.sum())} {key} cells with fewer than 3 points "
                         f"(first: cell {np.flatnonzero(small)[0]})")
        triangles.append(_triangulate(conn, offsets[:-1][~small], counts[~small], strip=key == "TRIANGLE_STRIPS"))
    tri = np.concatenate(triangles) if triangles else np.zeros((0, 3), dtype=np.int64)
    return tri, None, notes


def _grid_cells(sections, n_points, where):
    if "CELLS" not in sections:
        raise InputError(f"{where}: the UNSTRUCTURED_GRID file has no CELLS section")
    offsets, conn, line = sections["CELLS"]
    n = len(offsets) - 1
    types, types_line = sections.get("CELL_TYPES", (None, line))
    if types is None or len(types) != n:
        got = "no CELL_TYPES section" if types is None else f"CELL_TYPES (line {types_line}) lists {len(types)}"
        raise InputError(f"{where}: CELLS (line {line}) announces {n} cells, but {got}")
    _check_indices(conn, offsets, n_points, "CELLS", line, where)
    counts = np.diff(offsets)
    out, notes = {}, []
    for t in np.unique(types).tolist():
        sel = np.flatnonzero(types == t)
        name = CELL_TYPES.get(t, "unknown")
        if t in IGNORED_CELL_TYPES:
            notes.append(f"ignored {len(sel)} {name} cells")
            continue
        k = {5: 3, 10: 4}.get(t)
        if k is None:
            raise InputError(f"{where}: unsupported cell type {name!r} (VTK type {t}, {len(sel)} cells; first: cell "
                             f"{sel[0]}); only tetra (10) and triangle (5) cells are read (types 1-4 are ignored)")
        wrong = sel[counts[sel] != k]
        if len(wrong):
            raise InputError(f"{where}: CELLS (line {line}): cell {wrong[0]} is a {name} with {counts[wrong[0]]} "
                             f"points, expected {k}")
        out[k] = conn[offsets[sel][:, None] + np.arange(k)]
    return out.get(3), out.get(4), notes


def _triangulate(conn, starts, counts, strip: bool):
    """Fan triangles (c0, c_j+1, c_j+2) of polygons, or strip triangles with alternating winding."""
    per = counts - 2
    cell = np.repeat(np.arange(len(per)), per)
    j = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    s = starts[cell]
    if strip:
        tri = np.stack([conn[s + j], conn[s + j + 1], conn[s + j + 2]], axis=1)
        odd = j % 2 == 1
        tri[odd] = tri[odd][:, [1, 0, 2]]
        return tri
    return np.stack([conn[s], conn[s + j + 1], conn[s + j + 2]], axis=1)


def _word(words, i, default):
    return words[i].lower() if words is not None and len(words) > i else default


class _Stream:
    """Walks the file: keyword lines as text, data blocks as ASCII numbers or big-endian binary."""

    def __init__(self, data: bytes, where: str, binary: bool, start: int):
        self.data, self.where, self.binary, self.pos, self.line = data, where, binary, start, 4

    def line_at(self, pos: int) -> int:
        return self.data.count(b"\n", 0, min(pos, len(self.data))) + 1

    def fail(self, message: str):
        raise InputError(f"{self.where}: line {self.line}: {message}")

    def _skip_blank(self) -> int:
        pos = self.pos
        while pos < len(self.data) and self.data[pos] in b" \t\r\n":
            pos += 1
        return pos

    def peek_keyword(self) -> str | None:
        pos = self._skip_blank()
        end = self.data.find(b"\n", pos)
        words = self.data[pos:len(self.data) if end < 0 else end].split()
        return words[0].decode("latin-1").upper() if words else None

    def keyword_line(self, wanted: str | None = None) -> list[str] | None:
        """The next non-blank line as words (the first upper-cased), or None at the end of the file."""
        pos = self._skip_blank()
        if pos >= len(self.data):
            if wanted:
                raise InputError(f"{self.where}: truncated VTK file: it ends at line {self.line_at(pos)}, "
                                 f"expected {wanted}")
            return None
        end = self.data.find(b"\n", pos)
        end = len(self.data) if end < 0 else end
        words = self.data[pos:end].decode("latin-1").split()
        self.line, self.pos = self.line_at(pos), end + 1
        return [words[0].upper(), *words[1:]]

    def skip_block(self) -> None:
        """A METADATA block: text lines up to the first blank one."""
        while self.pos < len(self.data):
            end = self.data.find(b"\n", self.pos)
            end = len(self.data) if end < 0 else end
            text, self.pos = self.data[self.pos:end], end + 1
            if not text.strip():
                return

    def count(self, words, i: int, what: str) -> int:
        try:
            value = int(words[i])
        except (IndexError, ValueError):
            value = -1
        if value < 0:
            got = repr(words[i][:40]) if i < len(words) else "nothing"
            self.fail(f"expected {what}, got {got}")
        return value

    def array(self, count: int, vtk_type: str, section: str, kind) -> np.ndarray:
        """`count` numbers after the current keyword line, as float64 or int64 (`kind`)."""
        dtype = np.float64 if kind is float else np.int64
        if self.binary:
            code = _TYPES.get(vtk_type)
            if code is None:
                self.fail(f"unknown data type {vtk_type[:40]!r} for {section}; known: {', '.join(_TYPES)}")
            nbytes = count * int(code[1])
            if self.pos + nbytes > len(self.data):
                raise InputError(f"{self.where}: truncated VTK file: {section} (line {self.line}) announces {count} "
                                 f"values ({nbytes} bytes), but the file ends {len(self.data) - self.pos} bytes later")
            values = np.frombuffer(self.data, dtype=">" + code, count=count, offset=self.pos)
            self.pos += nbytes
            return values.astype(dtype)
        start = self._skip_blank()
        match = _KEYWORD_LINE.search(self.data, start)
        end = len(self.data) if match is None else match.start()
        words = self.data[start:end].split()
        if len(words) < count and match is None:
            raise InputError(f"{self.where}: truncated VTK file: {section} (line {self.line}) announces {count} "
                             f"numbers, but the file ends at line {self.line_at(len(self.data.rstrip()))}")
        if len(words) != count:
            self.fail(f"{section} announces {count} numbers, but {len(words)} come before line {self.line_at(end)}")
        self.pos = end
        try:
            return np.array(words, dtype=dtype)
        except (ValueError, OverflowError):
            k = next(i for i, w in enumerate(words) if not _parses(w, dtype))
            raise InputError(f"{self.where}: line {self._line_of_word(start, k)}: expected a number in {section}, "
                             f"got {words[k][:40].decode('latin-1')!r}") from None

    def _line_of_word(self, start: int, k: int) -> int:
        first = self.line_at(start)
        for number, text in enumerate(self.data[start:].split(b"\n")):
            k -= len(text.split())
            if k < 0:
                return first + number
        return first


def _parses(word: bytes, dtype) -> bool:
    try:
        np.array([word], dtype=dtype)
    except (ValueError, OverflowError):
        return False
    return True
