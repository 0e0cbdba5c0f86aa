"""Load an organ mesh from a file: pick a reader by suffix, then validate and repair (validate.py).

Every failure is an :class:`InputError` with one line that starts with the path; third-party
reader exceptions are wrapped (`raise ... from exc`), never let through.
"""

from __future__ import annotations

import contextlib
import io as _stdio
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from .gmsh_v1 import is_gmsh_v1, read_gmsh_v1
from .tissue_mesh import TissueMesh
from .validate import check_scale
from .vtk_polydata import read_vtk_polydata, vtk_dataset

KNOWN_FORMATS = {
    ".obj": "Wavefront OBJ surface (trimesh); several objects are concatenated",
    ".stl": "STL surface, ASCII or binary (trimesh)",
    ".ply": "PLY surface, ASCII or binary (trimesh)",
    ".off": "OFF surface (trimesh)",
    ".vtu": "VTK XML unstructured grid: tetra and triangle cells (meshio)",
    ".vtk": "legacy VTK: UNSTRUCTURED_GRID (meshio), or an ASCII POLYDATA surface",
    ".msh": "Gmsh v2 / v4 (meshio), or Gmsh v1 $NOD/$ELM as SOFA ships it",
}
"""File suffixes that :func:`load_mesh` reads (any case), with what each holds."""

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
    if not p.exists():
        raise InputError(f"{where}: no such file")
    if p.is_dir():
        raise InputError(f"{where}: is a directory, not a mesh file")
    suffix = p.suffix.lower()
    if suffix not in KNOWN_FORMATS:
        known = ", ".join(KNOWN_FORMATS)
        raise InputError(f"{where}: unknown mesh format {suffix or '(no suffix)'!r}; known: {known}")
    try:
        with open(p, "rb") as f:
            head = f.read(4096)
    except PermissionError as exc:
        raise InputError(f"{where}: permission denied, cannot read the file") from exc
    except OSError as exc:
        raise InputError(f"{where}: cannot read: {exc.strerror or exc}") from exc
    if not head:
        raise InputError(f"{where}: empty file (0 bytes)")

    if suffix in _TRIMESH:
        fmt, read = _TRIMESH[suffix], _read_trimesh
    elif suffix == ".msh" and is_gmsh_v1(head):
        fmt, read = "Gmsh v1", read_gmsh_v1
    elif suffix == ".vtk" and vtk_dataset(head) == "POLYDATA":
        fmt, read = "VTK POLYDATA", _read_polydata
    else:
        fmt, read = {".vtu": "VTU", ".vtk": "VTK", ".msh": "Gmsh"}[suffix], _read_meshio
    try:
        vertices, triangles, tetrahedra, notes = read(p, where)
    except InputError:
        raise
    except Exception as exc:  # wrapped, never let through: the message says which file and format
        raise InputError(f"{where}: cannot read as {fmt}: {_explain_bare(exc, p) or _one_line(exc)}") from exc

    mesh = TissueMesh.from_arrays(vertices, triangles, tetrahedra, scale=scale, path=where)
    if notes:
        mesh.notes = tuple(notes) + mesh.notes
    return mesh


def _read_trimesh(p: Path, where: str):
    import trimesh

    if p.suffix.lower() == ".obj":
        _check_obj_face_indices(p, where)

    loaded = trimesh.load_mesh(p, file_type=p.suffix.lower()[1:], process=False)
    if isinstance(loaded, trimesh.Scene):  # several objects: concatenated, none dropped
        loaded = loaded.to_mesh()
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = getattr(loaded, "faces", None)
    faces = np.zeros((0, 3), dtype=np.int64) if faces is None else np.asarray(faces, dtype=np.int64)
    _check_announced_counts(p, where, len(vertices), len(faces))
    return vertices, faces, None, []


def _check_obj_face_indices(p: Path, where: str) -> None:
    """Every OBJ face index names a vertex: trimesh reads an index 0 as the last vertex (0 - 1 =
    -1: a wrong mesh, silently) and fails on one past the end with a bare IndexError. Positive
    indices count from the file's first vertex, negative ones back from the last vertex so far."""
    with open(p, "rb") as f:
        lines = f.read().split(b"\n")
    total = sum(1 for line in lines if line[:2] in (b"v ", b"v\t"))
    seen = 0
    for number, line in enumerate(lines, start=1):
        head = line[:2]
        if head in (b"v ", b"v\t"):
            seen += 1
        elif head in (b"f ", b"f\t"):
            for token in line.split()[1:]:
                try:
                    index = int(token.split(b"/")[0])
                except ValueError:
                    break  # not a number: the reader's own error says what it is
                if index == 0 or index > total or index < -seen:
                    what = "OBJ indices start at 1" if index == 0 else (
                        f"the file has {total} vertices" if index > 0 else f"only {seen} vertices precede it")
                    raise InputError(f"{where}: line {number}: face {line.decode(errors='replace').strip()[:60]!r} "
                                     f"references vertex {index}, but {what}")


def _announced_counts(p: Path):
    """(format, vertices, faces) that an OFF or PLY header or a binary STL's size announces, or
    None where the file announces nothing (OBJ, ASCII STL) or its header is not understood."""
    suffix = p.suffix.lower()
    if suffix == ".stl":
        size = p.stat().st_size
        with open(p, "rb") as f:
            head = f.read(84)
        if len(head) == 84:
            n = int(np.frombuffer(head[80:84], dtype="<u4")[0])
            if size == 84 + 50 * n or not head.lstrip().lower().startswith(b"solid"):
                return ("binary STL", None, n) if size == 84 + 50 * n else ("binary STL", -1, n)
        return None
    if suffix not in (".off", ".ply"):
        return None
    with open(p, "rb") as f:
        text = f.read(1 << 16).decode("latin-1")
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


def _check_announced_counts(p: Path, where: str, vertex_count: int, face_count: int) -> None:
    """trimesh stops quietly where a truncated OFF or ASCII PLY ends, and reads a truncated binary
    STL as empty: half a mesh, which would look like a physics bug later. Compare with what the
    file announces (polygons may become several triangles: at least that many faces)."""
    announced = _announced_counts(p)
    if announced is None:
        return
    fmt, vertices, faces = announced
    if fmt == "binary STL":
        if vertices == -1:
            size = p.stat().st_size
            raise InputError(f"{where}: truncated binary STL: its header announces {faces} triangles "
                             f"({84 + 50 * faces} bytes), but the file has {size} bytes")
        return
    if vertex_count != vertices or face_count < faces:
        raise InputError(f"{where}: the {fmt} header announces {vertices} vertices and {faces} faces, but the file "
                         f"holds {vertex_count} vertices and {face_count} faces (truncated, or lines missing?)")


def _read_polydata(p: Path, where: str):
    vertices, triangles, notes = read_vtk_polydata(p, where)
    return vertices, triangles, None, notes


def _read_meshio(p: Path, where: str):
    import meshio

    reader = {".vtu": meshio.vtu.read, ".vtk": meshio.vtk.read, ".msh": meshio.gmsh.read}[p.suffix.lower()]
    captured = _stdio.StringIO()
    with contextlib.redirect_stderr(captured):  # meshio prints its warnings to stderr: keep them as notes
        m = reader(os.fspath(p))
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
