"""Reader for legacy ASCII VTK `DATASET POLYDATA` surfaces, which meshio does not read.

Reads POINTS and POLYGONS (fan-triangulated) and TRIANGLE_STRIPS, in both the classic cell list
(`n i j k ...`) and the VTK 5.1 OFFSETS / CONNECTIVITY layout. VERTICES and LINES are ignored
and reported; FIELD and METADATA blocks are skipped; reading stops at POINT_DATA / CELL_DATA.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

CELL_SECTIONS = ("VERTICES", "LINES", "POLYGONS", "TRIANGLE_STRIPS")
_KEYWORDS = {"POINTS", *CELL_SECTIONS, "POINT_DATA", "CELL_DATA", "FIELD", "METADATA"}


def vtk_dataset(head: bytes) -> str | None:
    """The DATASET type named in a legacy VTK header (e.g. 'POLYDATA'), or None."""
    for line in head.splitlines()[:8]:
        words = line.split()
        if len(words) >= 2 and words[0].upper() == b"DATASET":
            return words[1].decode("ascii", "replace").upper()
    return None


def read_vtk_polydata(path, where: str):
    """(vertices [n, 3] float64, triangles [m, 3] int64, notes) from an ASCII POLYDATA file."""
    with open(path, encoding="ascii") as f:
        lines = f.read().splitlines()
    if len(lines) < 4 or not lines[0].lstrip().lower().startswith("# vtk datafile"):
        raise InputError(f"{where}: line 1: not a legacy VTK file (expected '# vtk DataFile Version ...')")
    mode = lines[2].strip().upper()
    if mode != "ASCII":
        raise InputError(f"{where}: line 3: {mode or 'an empty line'} VTK POLYDATA is not supported, only ASCII "
                         f"(save it as ASCII, or as .obj / .ply / .stl)")
    words = [ln.split() for ln in lines[4:]]
    toks = [t for w in words for t in w]
    line_of = np.repeat(np.arange(5, len(lines) + 1), [len(w) for w in words])
    reader = _Tokens(toks, line_of, where, len(lines))

    points, triangles, notes = None, [], []
    while reader.i < len(toks):
        at = reader.i
        kw = toks[at].upper()
        if kw == "POINTS":
            n = reader.int_at(at + 1, "the POINTS count")
            points = reader.take(at + 3, 3 * n, np.float64, "POINTS", at).reshape(n, 3)
            reader.i = at + 3 + 3 * n
        elif kw in CELL_SECTIONS:
            starts, counts, conn = _read_cells(reader, kw, at)
            n_points = -1 if points is None else len(points)
            bad = (conn < 0) | (conn >= n_points)
            if bad.any():
                cell = int(np.searchsorted(starts + counts, np.flatnonzero(bad)[0], side="right"))
                if points is None:
                    reader.fail(at, f"{kw} come before POINTS")
                reader.fail(at, f"{kw} cell {cell} references point {conn[bad][0]}, but POINTS has "
                                f"{n_points} points (0..{n_points - 1})")
            if kw in ("VERTICES", "LINES"):
                notes.append(f"ignored {len(counts)} {kw} cells")
                continue
            small = counts < 3
            if small.any():
                notes.append(f"dropped {int(small.sum())} {kw} cells with fewer than 3 points "
                             f"(first: cell {np.flatnonzero(small)[0]})")
            triangles.append(_triangulate(conn, starts[~small], counts[~small], strip=kw == "TRIANGLE_STRIPS"))
        elif kw in ("POINT_DATA", "CELL_DATA"):
            break
        elif kw == "FIELD":
            reader.i = at + 3
            for _ in range(reader.int_at(at + 2, "the FIELD array count")):
                comps = reader.int_at(reader.i + 1, "the FIELD array's components")
                tuples = reader.int_at(reader.i + 2, "the FIELD array's tuples")
                reader.i += 4 + comps * tuples
        elif kw == "METADATA":
            reader.i += 1
            while reader.i < len(toks) and toks[reader.i].upper() not in _KEYWORDS - {"FIELD", "METADATA"}:
                reader.i += 1
        else:
            reader.fail(at, f"unexpected {toks[at][:40]!r} in a POLYDATA dataset")
    if points is None:
        raise InputError(f"{where}: the POLYDATA file has no POINTS section")
    tri = np.concatenate(triangles) if triangles else np.zeros((0, 3), dtype=np.int64)
    return points, tri, notes


def _read_cells(reader, kw, at):
    """(start, count per cell, connectivity) of one cell section, classic or OFFSETS/CONNECTIVITY."""
    toks = reader.toks
    n = reader.int_at(at + 1, f"the {kw} cell count")
    size = reader.int_at(at + 2, f"the {kw} size")
    if at + 3 < len(toks) and toks[at + 3].upper() == "OFFSETS":
        offsets = reader.take(at + 5, n, np.int64, kw + " OFFSETS", at)
        j = at + 5 + n
        if j >= len(toks) or toks[j].upper() != "CONNECTIVITY":
            reader.fail(min(j, len(toks) - 1), f"expected CONNECTIVITY after the {n} {kw} OFFSETS")
        conn = reader.take(j + 2, size, np.int64, kw + " CONNECTIVITY", j)
        reader.i = j + 2 + size
        if n == 0 or offsets[0] != 0 or offsets[-1] != size or (np.diff(offsets) < 0).any():
            reader.fail(at, f"{kw} OFFSETS must rise from 0 to the connectivity size {size}")
        return offsets[:-1], np.diff(offsets), conn
    flat = reader.take(at + 3, size, np.int64, kw, at)
    reader.i = at + 3 + size
    starts, counts = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    pos, values = 0, flat.tolist()
    for c in range(n):  # each cell's length says where the next one starts
        if pos >= size or pos + 1 + values[pos] > size or values[pos] < 0:
            reader.fail(at, f"{kw} cell {c} runs past the section's size {size}")
        starts[c], counts[c] = pos + 1, values[pos]
        pos += 1 + values[pos]
    if pos != size:
        reader.fail(at, f"{kw} says size {size}, but its {n} cells use {pos} numbers")
    conn = flat.copy()
    conn[starts - 1] = 0  # the counts are not vertex references
    keep = np.ones(size, dtype=bool)
    keep[starts - 1] = False
    new_start = starts - np.arange(1, n + 1)
    return new_start, counts, conn[keep]


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


class _Tokens:
    def __init__(self, toks, line_of, where, n_lines):
        self.toks, self.line_of, self.where, self.n_lines, self.i = toks, line_of, where, n_lines, 0

    def fail(self, index: int, message: str):
        line = self.line_of[index] if 0 <= index < len(self.line_of) else self.n_lines
        raise InputError(f"{self.where}: line {line}: {message}")

    def int_at(self, index: int, what: str) -> int:
        if index >= len(self.toks):
            raise InputError(f"{self.where}: truncated VTK file: it ends at line {self.n_lines}, expected {what}")
        try:
            value = int(self.toks[index])
        except ValueError:
            value = -1
        if value < 0:
            self.fail(index, f"expected {what}, got {self.toks[index][:40]!r}")
        return value

    def take(self, start: int, count: int, dtype, section: str, at: int) -> np.ndarray:
        if start + count > len(self.toks):
            raise InputError(f"{self.where}: truncated VTK file: {section} (line {self.line_of[at]}) announces "
                             f"{count} numbers, but the file ends at line {self.n_lines}")
        chunk = self.toks[start:start + count]
        try:
            return np.array(chunk, dtype=dtype)
        except ValueError:
            for k, t in enumerate(chunk):
                try:
                    np.array(t, dtype=dtype)
                except ValueError:
                    self.fail(start + k, f"expected a number in {section}, got {t[:40]!r}")
            raise
