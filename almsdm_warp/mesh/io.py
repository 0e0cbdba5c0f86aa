"""Load an organ mesh from a file: pick a reader by suffix, then validate and repair (validate.py).

Every failure is an :class:`InputError` with one line that starts with the path; third-party
reader exceptions are wrapped (`raise ... from exc`), never let through.
"""

from __future__ import annotations

import contextlib
import io as _stdio
import os
import re
import stat
import tempfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .gmsh_refs import check_gmsh_node_references
from .gmsh_v1 import is_gmsh_v1, read_gmsh_v1
from .tissue_mesh import TissueMesh
from .validate import check_scale
from .stl import read_stl
from .vtk_legacy import read_legacy_vtk

KNOWN_FORMATS = {
    ".obj": "Wavefront OBJ surface (trimesh); several objects are concatenated",
    ".stl": "STL surface, ASCII or binary",
    ".ply": "PLY surface, ASCII or binary (trimesh)",
    ".off": "OFF surface (trimesh)",
    ".vtu": "VTK XML unstructured grid: tetra and triangle cells (meshio)",
    ".vtk": "legacy VTK, ASCII or binary: UNSTRUCTURED_GRID (tetra and triangle cells) or a POLYDATA surface",
    ".msh": "Gmsh v2 / v4 (meshio), or Gmsh v1 $NOD/$ELM as SOFA ships it",
}
"""File suffixes that :func:`load_mesh` reads (any case), with what each holds."""

MAX_FILE_BYTES = 2 * 1024**3
"""Mesh files larger than this (2 GiB; an ASCII OBJ of about 20 million triangles) are refused
before anything is read."""

_SPECIAL = ((stat.S_ISFIFO, "FIFO (named pipe)"), (stat.S_ISCHR, "character device"),
            (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket"))
_TRIMESH = {".obj": "OBJ", ".stl": "STL", ".ply": "PLY", ".off": "OFF"}
# meshio cell types that carry no surface or volume: ignored, and reported in the notes.
_IGNORED_CELLS = ("vertex", "line", "line3", "polyline")


def load_mesh(path, *, scale: float = 1.0) -> TissueMesh:
    """Read, validate and repair a tetrahedral or surface mesh.

    path: a file whose suffix is one of :data:`KNOWN_FORMATS`.
    scale: file units x scale = millimetres (1.0 for a file in mm, 10.0 for cm, 1000.0 for m).
    Returns a :class:`TissueMesh` in metres whose `notes` list every repair; raises InputError.
    """
    where = str(path)
    check_scale(scale, where)  # before reading, not after
    p = Path(path)
    suffix = p.suffix.lower()
    data = read_bounded(p, where, before_reading=lambda: _check_suffix(suffix, where))
    if suffix in _TRIMESH:
        fmt, read = _TRIMESH[suffix], _read_trimesh
    elif suffix == ".msh" and is_gmsh_v1(data[:4096].removeprefix(b"\xef\xbb\xbf")):
        fmt, read = "Gmsh v1", _read_gmsh_v1
    elif suffix == ".vtk":
        fmt, read = "legacy VTK", _read_legacy_vtk
    else:
        fmt, read = {".vtu": "VTU", ".msh": "Gmsh"}[suffix], _read_meshio
    try:
        vertices, triangles, tetrahedra, notes = read(p, where, data)
    except InputError:
        raise
    except Exception as exc:  # wrapped, never let through: the message says which file and format
        raise InputError(f"{where}: cannot read as {fmt}: {_explain_bare(exc, p) or _one_line(exc)}") from exc

    mesh = TissueMesh.from_arrays(vertices, triangles, tetrahedra, scale=scale, path=where)
    if notes:
        mesh.notes = tuple(notes) + mesh.notes
    return mesh


def _check_suffix(suffix: str, where: str) -> None:
    if suffix not in KNOWN_FORMATS:
        known = ", ".join(KNOWN_FORMATS)
        raise InputError(f"{where}: unknown mesh format {suffix or '(no suffix)'!r}; known: {known}")


def read_bounded(path, where: str, before_reading=None, what: str = "mesh file", limit: int | None = None) -> bytes:
    """The bytes of a regular file (a `what`) of at most `limit` bytes (default MAX_FILE_BYTES), else InputError before reading.

    The file is opened without blocking and checked on the open descriptor (fstat), so a path that
    names a FIFO, a device (/dev/zero, /dev/urandom) or a socket is refused instead of read without
    end; `before_reading` runs once the path is known to be a regular file (a check of its name).
    """
    limit = MAX_FILE_BYTES if limit is None else limit
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0))
    except FileNotFoundError as exc:
        raise InputError(f"{where}: no such file") from exc
    except IsADirectoryError as exc:
        raise InputError(f"{where}: is a directory, not a {what}") from exc
    except PermissionError as exc:
        raise InputError(f"{where}: permission denied, cannot read the file") from exc
    except OSError as exc:
        raise InputError(f"{where}: cannot read: {exc.strerror or exc}") from exc
    mode = os.fstat(fd)
    if stat.S_ISDIR(mode.st_mode):
        os.close(fd)
        raise InputError(f"{where}: is a directory, not a {what}")
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(mode.st_mode):
            kind = next((name for test, name in _SPECIAL if test(mode.st_mode)), "special file")
            raise InputError(f"{where}: is a {kind}, not a regular file; a {what} is read only from a regular file "
                             f"(a device or a pipe may never end)")
        if mode.st_size > limit:
            raise InputError(f"{where}: the file has {mode.st_size} bytes, more than the {limit} bytes a {what} may have")
        if before_reading is not None:
            before_reading()
        try:
            data = f.read(limit + 1)
        except OSError as exc:
            raise InputError(f"{where}: cannot read: {exc.strerror or exc}") from exc
    if len(data) > limit:
        raise InputError(f"{where}: the file grew past the {limit} bytes a {what} may have while it was read")
    if not data:
        raise InputError(f"{where}: empty file (0 bytes)")
    return data


def _read_trimesh(p: Path, where: str, data: bytes):
    suffix = p.suffix.lower()
    if suffix == ".stl":
        vertices, faces = read_stl(data, where)
        return vertices, faces, None, []
    data = strip_bom(data, where, text=suffix != ".ply")
    if suffix == ".obj":
        plain = read_plain_obj(data)
        if plain is not None:
            return (*plain, None, [])
        check_obj_face_indices(data, where)
    trimesh = import_trimesh()
    # OBJ and OFF are text: decoded here (UTF-8, else Latin-1 for stray bytes in comments), so that
    # trimesh never needs an encoding guesser; PLY's header is ASCII and its body may be binary.
    source = _stdio.BytesIO(data) if suffix == ".ply" else _stdio.StringIO(_decode_text(data))
    resolver = trimesh.resolvers.FilePathResolver(os.fspath(p.resolve()))
    loaded = trimesh.load_mesh(source, file_type=suffix[1:], process=False, resolver=resolver)
    if isinstance(loaded, trimesh.Scene):  # several objects: concatenated, none dropped
        loaded = loaded.to_mesh()
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = getattr(loaded, "faces", None)
    faces = np.zeros((0, 3), dtype=np.int64) if faces is None else np.asarray(faces, dtype=np.int64)
    _check_announced_counts(suffix, data, where, len(vertices), len(faces))
    return vertices, faces, None, []


def import_trimesh():
    """The trimesh module with its graph engine and repair, imported on a thread of its own (once): trimesh
    imports scipy inside `except BaseException`, so a Ctrl-C that reached that import would be swallowed
    and leave trimesh without its graph engine (a traceback later, in a mesh's repair); signals reach
    only the main thread, whose wait here takes the interrupt while the import completes."""
    import importlib
    import sys
    import threading

    names = ("trimesh", "trimesh.graph", "trimesh.repair")
    if not all(n in sys.modules for n in names):
        done = threading.Thread(target=lambda: [importlib.import_module(n) for n in names], name="import-trimesh", daemon=True)
        done.start()
        done.join()
    return importlib.import_module("trimesh")


_NUMBER = rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PLAIN_V = re.compile(rb"^v[ \t]+(" + _NUMBER + rb"[ \t]+" + _NUMBER + rb"[ \t]+" + _NUMBER + rb")[ \t]*\r?$", re.MULTILINE)
_PLAIN_F = re.compile(rb"^f[ \t]+([0-9]+[ \t]+[0-9]+[ \t]+[0-9]+)[ \t]*\r?$", re.MULTILINE)
_NOT_PLAIN = re.compile(rb"^(?![vf][ \t]|#|[ \t]*\r?$)", re.MULTILINE)


def read_plain_obj(data: bytes):
    """(vertices [n, 3], faces [m, 3] from 0) of an OBJ that holds only `v x y z` and `f i j k` lines
    (plain 1-based vertex indices, each naming a vertex, every vertex named), comments and blank lines,
    as trimesh reads it (the vertices in file order); None for any other OBJ (trimesh reads it, and
    says what is wrong). No import of trimesh and its dependencies for the common case."""
    if _NOT_PLAIN.search(data):
        return None
    vertex_lines = len(_OBJ_VERTEX.findall(data))
    face_lines = len(_OBJ_FACE.findall(data))
    v, f = _PLAIN_V.findall(data), _PLAIN_F.findall(data)
    if len(v) != vertex_lines or len(f) != face_lines:
        return None
    if not v or not f:
        return None
    vertices = np.array(b" ".join(v).split(), dtype=np.float64).reshape(-1, 3)
    faces = np.array(b" ".join(f).split(), dtype=np.int64).reshape(-1, 3) - 1
    if faces.min() < 0 or faces.max() >= len(vertices) or np.bincount(faces.ravel(), minlength=len(vertices)).min() == 0:
        return None  # an index out of range, or a vertex no face uses (trimesh drops it)
    return vertices, faces


_BOMS = ((b"\xef\xbb\xbf", "utf-8"), (b"\xff\xfe", "utf-16-le"), (b"\xfe\xff", "utf-16-be"))


def strip_bom(data: bytes, where: str, text: bool = True) -> bytes:
    """The file's bytes without a leading byte-order mark; a UTF-16 text file re-encoded as UTF-8
    (where `text`; a UTF-16 file with a binary body cannot be read and is an error)."""
    for bom, codec in _BOMS:
        if data.startswith(bom):
            if codec == "utf-8":
                return data[len(bom):]
            if not text:
                raise InputError(f"{where}: the file starts with a {codec.upper()} byte-order mark; "
                                 f"save it as ASCII or UTF-8")
            try:
                return data[len(bom):].decode(codec).encode("utf-8")
            except UnicodeDecodeError as exc:
                raise InputError(f"{where}: starts with a {codec.upper()} byte-order mark but is not "
                                 f"{codec.upper()} text at byte {exc.start + len(bom)}") from exc
    return data


def _decode_text(data: bytes) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


_OBJ_VERTEX = re.compile(rb"^v[ \t]", re.MULTILINE)
_OBJ_FACE = re.compile(rb"^f[ \t]+([^\n]*)", re.MULTILINE)
_OBJ_AFTER_SLASH = re.compile(rb"/[^ \t\r]*")


def check_obj_face_indices(data: bytes, where: str) -> None:
    """Every OBJ face index names a vertex: trimesh reads an index 0 as the last vertex (0 - 1 =
    -1: a wrong mesh, silently) and fails on one past the end with a bare IndexError. Positive
    indices count from the file's first vertex, negative ones back from the last vertex so far.
    Checked at once with regular expressions and NumPy; the offending line is looked for only when
    there is one (or when negative indices need the count of the vertices before each face)."""
    total = len(_OBJ_VERTEX.findall(data))
    faces = _OBJ_FACE.findall(data)
    try:
        index = np.array(_OBJ_AFTER_SLASH.sub(b"", b" ".join(faces)).split(), dtype=np.int64)
    except (ValueError, OverflowError):
        return  # not a number: the reader's own error says what it is
    if len(index) and ((index == 0) | (index > total)).any() | (index < 0).any():
        _find_bad_obj_face(data, where, total)


def _find_bad_obj_face(data: bytes, where: str, total: int) -> None:
    seen = 0
    for number, line in enumerate(data.split(b"\n"), start=1):
        head = line[:2]
        if head in (b"v ", b"v\t"):
            seen += 1
        elif head in (b"f ", b"f\t"):
            for token in line.split()[1:]:
                index = int(token.split(b"/")[0])
                if index == 0 or index > total or index < -seen:
                    what = "OBJ indices start at 1" if index == 0 else (
                        f"the file has {total} vertices" if index > 0 else f"only {seen} vertices precede it")
                    raise InputError(f"{where}: line {number}: face {line.decode(errors='replace').strip()[:60]!r} "
                                     f"references vertex {index}, but {what}")


def _announced_counts(suffix: str, data: bytes):
    """(format, vertices, faces) that an OFF or PLY header announces, or None where the file
    announces nothing (OBJ) or its header is not understood."""
    if suffix not in (".off", ".ply"):
        return None
    text = data[: 1 << 16].decode("latin-1")
    if suffix == ".off":
        tokens = " ".join(line.split("#", 1)[0] for line in text.splitlines()[:50]).split()
        if len(tokens) >= 3 and tokens[0].upper().endswith("OFF") and tokens[1].isdigit() and tokens[2].isdigit():
            return "OFF", int(tokens[1]), int(tokens[2])
        return None
    counts = {}
    for line in text.splitlines():
        words = line.split()
        if words[:1] == ["end_header"]:
            break
        if len(words) == 3 and words[0] == "element" and words[2].isdigit():
            counts[words[1]] = int(words[2])
    if "vertex" in counts:
        return "PLY", counts["vertex"], counts.get("face", 0)
    return None


def _check_announced_counts(suffix: str, data: bytes, where: str, vertex_count: int, face_count: int) -> None:
    """trimesh stops quietly where a truncated OFF or ASCII PLY ends: half a mesh, which would look
    like a physics bug later. Compare with what the file announces (polygons may become several
    triangles: at least that many faces)."""
    announced = _announced_counts(suffix, data)
    if announced is None:
        return
    fmt, vertices, faces = announced
    if vertex_count != vertices or face_count < faces:
        raise InputError(f"{where}: the {fmt} header announces {vertices} vertices and {faces} faces, but the file "
                         f"holds {vertex_count} vertices and {face_count} faces (truncated, or lines missing?)")


def _read_gmsh_v1(p: Path, where: str, data: bytes):
    return read_gmsh_v1(strip_bom(data, where), where)


def _read_legacy_vtk(p: Path, where: str, data: bytes):
    return read_legacy_vtk(strip_bom(data, where, text=False), where)


def _read_meshio(p: Path, where: str, data: bytes):
    import meshio

    stripped = strip_bom(data, where)
    if p.suffix.lower() == ".msh":
        check_gmsh_node_references(stripped, where)
    reader = {".vtu": meshio.vtu.read, ".msh": meshio.gmsh.read}[p.suffix.lower()]
    captured = _stdio.StringIO()
    with contextlib.ExitStack() as stack:
        stack.enter_context(contextlib.redirect_stderr(captured))  # meshio's warnings: kept as notes
        source = os.fspath(p)
        if stripped is not data:  # meshio reads a path: give it the bytes without the byte-order mark
            tmp = stack.enter_context(tempfile.TemporaryDirectory())
            source = os.path.join(tmp, "mesh" + p.suffix.lower())
            with open(source, "wb") as f:
                f.write(stripped)
        m = reader(source)
    notes = [f"meshio: {' '.join(line.split())}" for line in captured.getvalue().splitlines() if line.strip()]

    blocks = {"triangle": [], "tetra": []}
    ignored: dict[str, int] = {}
    for block in m.cells:
        if block.type in blocks:
            blocks[block.type].append(np.asarray(block.data, dtype=np.int64))
        elif block.type in _IGNORED_CELLS:
            ignored[block.type] = ignored.get(block.type, 0) + len(block.data)
        else:
            raise InputError(
                f"{where}: unsupported cell type {block.type!r} ({len(block.data)} cells); only 'tetra' and "
                f"'triangle' cells are read ({', '.join(_IGNORED_CELLS)} cells are ignored)"
            )
    notes += [f"ignored {count} {kind} cells" for kind, count in ignored.items()]
    tri = np.concatenate(blocks["triangle"]) if blocks["triangle"] else None
    tet = np.concatenate(blocks["tetra"]) if blocks["tetra"] else None
    return np.asarray(m.points, dtype=np.float64), tri, tet, notes


def _explain_bare(exc: BaseException, p: Path) -> str | None:
    """What went wrong when a reader says nothing (meshio's VTU reader raises a bare ReadError for
    any XML it cannot parse): the XML parser's own message, with line and column."""
    if str(exc).strip() or p.suffix.lower() != ".vtu":
        return None
    import xml.etree.ElementTree as ET

    try:
        ET.parse(p)
    except ET.ParseError as xml_error:
        return f"broken XML: {_one_line(xml_error).split(': ', 1)[-1]}"
    except Exception:  # noqa: BLE001 - only an explanation: the caller reports the original error
        return None
    return "well-formed XML, but not a VTK UnstructuredGrid that meshio reads (a missing or inconsistent element)"


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
