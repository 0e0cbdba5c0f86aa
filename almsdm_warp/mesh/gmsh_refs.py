"""Node references of ASCII Gmsh v2.2 and v4.1 files, checked before meshio reads them.

meshio maps an element's node tags to point indices with `remap[tag - 1]`: a tag of 0 or below
becomes a negative index, which NumPy wraps to another point (a wrong mesh, no error), and a tag
past the largest one fails with a bare IndexError. Here every node tag an element lists must be
one that $Nodes defines; the first that is not is an error naming the line, the element and the tag.
Binary Gmsh files are left to meshio and to validation (their indices are range-checked there).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError


def check_gmsh_node_references(data: bytes, where: str) -> None:
    lines = data.split(b"\n")
    if not lines or lines[0].strip() != b"$MeshFormat" or len(lines) < 2:
        return
    fmt = lines[1].split()
    if len(fmt) < 2 or fmt[1] != b"0":  # binary: not read here
        return
    version = fmt[0][:1]
    nodes = _section(lines, b"$Nodes")
    elements = _section(lines, b"$Elements")
    if nodes is None or elements is None:
        return
    try:
        if version == b"2":
            defined, (refs, owners, line_of) = _tags_v2(lines, nodes), _refs_v2(lines, elements)
        elif version == b"4":
            defined, (refs, owners, line_of) = _tags_v4(lines, nodes), _refs_v4(lines, elements)
        else:
            return
    except (ValueError, IndexError):
        return  # malformed: meshio's own error says where
    defined = np.sort(defined)
    pos = np.searchsorted(defined, refs).clip(0, max(len(defined) - 1, 0))
    missing = defined[pos] != refs if len(defined) else np.ones(len(refs), dtype=bool)
    if missing.any():
        k = int(np.argmax(missing))
        raise InputError(f"{where}: line {line_of[k] + 1}: element {owners[k]} references node {refs[k]}, "
                         f"which $Nodes does not define")


def _section(lines, name):
    for i, line in enumerate(lines):
        if line.strip() == name:
            return i + 1
    return None


def _tags_v2(lines, at):
    n = int(lines[at])
    return np.array([line.split(None, 1)[0] for line in lines[at + 1:at + 1 + n]], dtype=np.int64)


def _refs_v2(lines, at):
    """(node tags, element id per tag, line index per tag) of a v2.2 $Elements section."""
    m = int(lines[at])
    rows = [np.array(line.split(), dtype=np.int64) for line in lines[at + 1:at + 1 + m]]
    refs = [r[3 + r[2]:] for r in rows]
    counts = np.array([len(x) for x in refs], dtype=np.int64)
    ids = np.array([r[0] for r in rows], dtype=np.int64)
    flat = np.concatenate(refs) if refs else np.zeros(0, dtype=np.int64)
    return flat, np.repeat(ids, counts), np.repeat(np.arange(at + 1, at + 1 + m), counts)


def _tags_v4(lines, at):
    blocks = int(lines[at].split()[0])
    i, tags = at + 1, []
    for _ in range(blocks):
        k = int(lines[i].split()[3])
        tags.append(np.array(lines[i + 1:i + 1 + k], dtype=np.int64))
        i += 1 + 2 * k
    return np.concatenate(tags) if tags else np.zeros(0, dtype=np.int64)


def _refs_v4(lines, at):
    blocks = int(lines[at].split()[0])
    i, refs, ids, where = at + 1, [], [], []
    for _ in range(blocks):
        k = int(lines[i].split()[3])
        rows = np.array([line.split() for line in lines[i + 1:i + 1 + k]], dtype=np.int64).reshape(k, -1)
        refs.append(rows[:, 1:].reshape(-1))
        ids.append(np.repeat(rows[:, 0], rows.shape[1] - 1))
        where.append(np.repeat(np.arange(i + 1, i + 1 + k), rows.shape[1] - 1))
        i += 1 + k
    cat = (lambda x: np.concatenate(x) if x else np.zeros(0, dtype=np.int64))
    return cat(refs), cat(ids), cat(where)
