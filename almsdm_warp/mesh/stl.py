"""STL reader, binary and ASCII, with NumPy only (no text-encoding guesser needed).

Binary: an 80-byte header, a little-endian uint32 triangle count, then 50 bytes per triangle
(normal, three corners as float32, a uint16 attribute); the file size must be exactly
84 + 50 x count. ASCII: `solid ... facet normal ... outer loop vertex x y z (x3) endloop endfacet
... endsolid`, one or several solids, read in order. Every corner is its own vertex (vertex i of
triangle t is 3t + i), as trimesh reads STL without processing; validation merges them.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import InputError

_BINARY = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_VERTEX_LINE = re.compile(rb"^[ \t]*vertex[ \t]+(.*)$", re.IGNORECASE | re.MULTILINE)
_FACET = re.compile(rb"^[ \t]*facet\b", re.IGNORECASE | re.MULTILINE)


def binary_stl_count(data: bytes) -> int | None:
    """The triangle count of a binary STL whose size matches its header, else None."""
    if len(data) < 84:
        return None
    n = int(np.frombuffer(data[80:84], dtype="<u4")[0])
    return n if len(data) == 84 + _BINARY.itemsize * n else None


def read_stl(data: bytes, where: str):
    """(vertices [3m, 3] float64, triangles [m, 3] int64) from the bytes of an STL file."""
    n = binary_stl_count(data)
    if n is None:  # not binary: text, where a UTF-8 byte-order mark may come first
        data = data.removeprefix(b"\xef\xbb\xbf")
    if n is not None:
        corners = np.frombuffer(data, dtype=_BINARY, count=n, offset=84)["corners"]
        vertices = corners.reshape(-1, 3).astype(np.float64)
    elif data.lstrip()[:5].lower() == b"solid" and b"\0" not in data[:4096]:
        vertices = _read_ascii(data, where)
    else:
        if len(data) < 84:
            raise InputError(f"{where}: truncated binary STL: {len(data)} bytes, shorter than its 84-byte header")
        n = int(np.frombuffer(data[80:84], dtype="<u4")[0])
        raise InputError(f"{where}: truncated binary STL: its header announces {n} triangles "
                         f"({84 + 50 * n} bytes), but the file has {len(data)} bytes")
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)


def _read_ascii(data: bytes, where: str) -> np.ndarray:
    body = data.rstrip()
    last = body.rsplit(b"\n", 1)[-1].strip().lower()
    if not last.startswith(b"endsolid"):
        raise InputError(f"{where}: truncated ASCII STL: it does not end with 'endsolid' "
                         f"(last line {last[:40].decode('latin-1')!r})")
    rows = _VERTEX_LINE.findall(body)
    facets = len(_FACET.findall(body))
    if len(rows) != 3 * facets:
        raise InputError(f"{where}: ASCII STL has {facets} facets but {len(rows)} vertex lines (3 per facet expected)")
    words = b" ".join(rows).split()
    if len(words) != 3 * len(rows):
        bad = next(i for i, r in enumerate(rows) if len(r.split()) != 3)
        raise InputError(f"{where}: ASCII STL vertex line {bad + 1} holds {len(rows[bad].split())} numbers, "
                         f"expected 3: {rows[bad][:60].decode('latin-1')!r}")
    try:
        return np.array(words, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        bad = next(i for i, w in enumerate(words) if not _is_float(w))
        raise InputError(f"{where}: ASCII STL vertex line {bad // 3 + 1}: {words[bad][:40].decode('latin-1')!r} "
                         f"is not a number") from None


def _is_float(word: bytes) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True
