"""Reader for legacy Gmsh v1 `.msh` files (as SOFA ships them), which meshio does not read.

    $NOD
    n
    id x y z              (n lines; ids are arbitrary labels)
    $ENDNOD
    $ELM
    m
    id type reg_phys reg_elem nnodes n1 .. nk    (m lines; nodes given by label)
    $ENDELM

Triangles (type 2) and tetrahedra (type 4) are kept; points and lines are ignored and reported;
any other 2-D or 3-D element type is an error (a mesh that loads half looks like a physics bug later).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

# Gmsh element type -> (name, nodes per element).
ELEMENT_TYPES = {
    1: ("line", 2), 2: ("triangle", 3), 3: ("quadrangle", 4), 4: ("tetrahedron", 4),
    5: ("hexahedron", 8), 6: ("prism", 6), 7: ("pyramid", 5), 8: ("second-order line", 3),
    9: ("second-order triangle", 6), 10: ("second-order quadrangle", 9),
    11: ("second-order tetrahedron", 10), 12: ("second-order hexahedron", 27),
    13: ("second-order prism", 18), 14: ("second-order pyramid", 14), 15: ("point", 1),
}
_NODES_PER_TYPE = np.array([0] + [ELEMENT_TYPES[t][1] for t in range(1, 16)], dtype=np.int64)
KEPT = {2: 3, 4: 4}
IGNORED = {1, 8, 15}


def is_gmsh_v1(head: bytes) -> bool:
    """True when the first non-blank line of a file is `$NOD` (Gmsh v1)."""
    for line in head.splitlines():
        if line.strip():
            return line.strip() == b"$NOD"
    return False


def read_gmsh_v1(data: bytes, where: str):
    """(vertices [n, 3] float64, triangles [m, 3], tetrahedra [t, 4] int64, notes) from the bytes
    of a v1 file (ASCII)."""
    lines = _ascii_lines(data, where)
    cur = _Cursor(lines, where)

    cur.expect("$NOD")
    n = cur.count("$NOD", "node")
    first = cur.i
    rows = cur.block(n, "$NOD", "node", "id x y z")
    bad = np.flatnonzero([len(r) != 4 for r in rows])
    if len(bad):
        cur.fail(first + bad[0], f"expected a node 'id x y z', got {lines[first + bad[0]].strip()!r}")
    labels = _numbers(rows, slice(0, 1), np.int64, cur, first, "a node id").reshape(-1)
    xyz = _numbers(rows, slice(1, 4), np.float64, cur, first, "node coordinates")
    cur.expect("$ENDNOD", f"after the {n} nodes that $NOD announced")

    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    dup = np.flatnonzero(sorted_labels[1:] == sorted_labels[:-1])
    if len(dup):
        j = order[dup[0] + 1]
        cur.fail(first + j, f"node id {labels[j]} is defined twice")

    cur.expect("$ELM")
    m = cur.count("$ELM", "element")
    first = cur.i
    rows = cur.block(m, "$ELM", "element", "id type reg_phys reg_elem nnodes n1 .. nk")
    short = np.flatnonzero([len(r) < 5 for r in rows])
    if len(short):
        cur.fail(first + short[0], f"expected 'id type reg_phys reg_elem nnodes n1 .. nk', "
                                   f"got {lines[first + short[0]].strip()!r}")
    head = _numbers([r[:5] for r in rows], slice(0, 5), np.int64, cur, first, "an element header")
    ids, types, nnodes = head[:, 0], head[:, 1], head[:, 4]
    lengths = np.array([len(r) for r in rows], dtype=np.int64)
    wrong = np.flatnonzero(lengths != 5 + nnodes)
    if len(wrong):
        j = wrong[0]
        cur.fail(first + j, f"element {ids[j]} says {nnodes[j]} nodes but lists {lengths[j] - 5}")
    known = np.isin(types, list(ELEMENT_TYPES))
    expected = _NODES_PER_TYPE[np.where(known, types, 0)]
    wrong = np.flatnonzero(known & (expected != nnodes))
    if len(wrong):
        j = wrong[0]
        name, k = ELEMENT_TYPES[int(types[j])]
        cur.fail(first + j, f"element {ids[j]} is a {name} (type {types[j]}) with {nnodes[j]} nodes, expected {k}")
    cur.expect("$ENDELM", f"after the {m} elements that $ELM announced")

    notes = []
    unsupported = np.flatnonzero(~np.isin(types, list(KEPT) + list(IGNORED)))
    if len(unsupported):
        j = unsupported[0]
        t = int(types[j])
        name = ELEMENT_TYPES.get(t, ("unknown",))[0]
        count = int((types == t).sum())
        cur.fail(first + j, f"element {ids[j]} has type {t} ({name}; {count} such elements), which is not "
                            f"supported: only triangles (type 2) and tetrahedra (type 4) are read")
    for t in sorted(set(types[np.isin(types, list(IGNORED))].tolist())):
        notes.append(f"ignored {int((types == t).sum())} {ELEMENT_TYPES[t][0]} elements (Gmsh type {t})")

    out = []
    for t, k in KEPT.items():
        sel = np.flatnonzero(types == t)
        nodes = _numbers([rows[j][5:] for j in sel], slice(0, k), np.int64, cur, first, "node ids",
                         line_of=sel).reshape(-1, k)
        pos = np.searchsorted(sorted_labels, nodes).clip(0, max(n - 1, 0))
        missing = (sorted_labels[pos] != nodes) if n else np.ones_like(nodes, dtype=bool)
        if missing.any():
            r = np.flatnonzero(missing.any(axis=1))[0]
            label = nodes[r][missing[r]][0]
            cur.fail(first + sel[r], f"element {ids[sel[r]]} references node {label}, which $NOD does not define")
        out.append(order[pos] if n else nodes)
    trailing = [ln for ln in lines[cur.i:] if ln.strip()]
    if trailing:
        notes.append(f"ignored {len(trailing)} lines after $ENDELM (first: {trailing[0].strip()[:40]!r})")
    return xyz, out[0], out[1], notes


def _ascii_lines(data: bytes, where: str) -> list[str]:
    try:
        return data.decode("ascii").splitlines()
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(f"{where}: line {line}: byte {data[exc.start]:#04x} is not ASCII text "
                         f"(a Gmsh v1 file is ASCII)") from exc


class _Cursor:
    """Walks the lines of the file and reports errors with 1-based line numbers."""

    def __init__(self, lines, where):
        self.lines, self.where, self.i = lines, where, 0

    def fail(self, index: int, message: str):
        raise InputError(f"{self.where}: line {index + 1}: {message}")

    def _next_nonblank(self, wanted: str) -> str:
        while self.i < len(self.lines) and not self.lines[self.i].strip():
            self.i += 1
        if self.i >= len(self.lines):
            raise InputError(f"{self.where}: truncated Gmsh v1 file: ended at line {len(self.lines)}, "
                             f"expected {wanted}")
        self.i += 1
        return self.lines[self.i - 1].strip()

    def expect(self, keyword: str, context: str = "") -> None:
        got = self._next_nonblank(keyword)
        if got != keyword:
            self.fail(self.i - 1, f"expected {keyword}{' ' + context if context else ''}, got {got[:60]!r}")

    def count(self, section: str, what: str) -> int:
        got = self._next_nonblank(f"the {what} count after {section}")
        try:
            value = int(got)
        except ValueError:
            value = -1
        if value < 0:
            self.fail(self.i - 1, f"expected the {what} count after {section}, got {got[:60]!r}")
        return value

    def block(self, count: int, section: str, what: str, form: str) -> list[list[str]]:
        rows = [ln.split() for ln in self.lines[self.i:self.i + count]]
        early = np.flatnonzero([bool(r) and r[0].startswith("$") for r in rows])
        if len(early):
            self.fail(self.i + early[0], f"{section} announced {count} {what}s, but only {early[0]} precede "
                                         f"{rows[early[0]][0]}")
        if len(rows) < count:
            raise InputError(f"{self.where}: truncated Gmsh v1 file: {section} announced {count} {what}s, "
                             f"but the file ends at line {len(self.lines)}")
        self.i += count
        return rows


def _numbers(rows, columns, dtype, cur, first, what, line_of=None):
    """Rows of tokens -> array; on a bad token, name its line."""
    if not rows:
        return np.zeros((0, columns.stop - columns.start), dtype=dtype)
    try:
        return np.array([r[columns] for r in rows], dtype=dtype).reshape(len(rows), -1)
    except (ValueError, OverflowError):
        for j, r in enumerate(rows):
            try:
                np.array(r[columns], dtype=dtype)
            except (ValueError, OverflowError):
                line = first + (line_of[j] if line_of is not None else j)
                cur.fail(line, f"expected {what} ({np.dtype(dtype).name}), got {' '.join(r[columns])!r}")
        raise
