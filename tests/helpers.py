"""What several test files share: independent float64 answers (NumPy and SciPy, no Warp), the
project's scripts loaded as modules, and the fuzz tests' check of a loader's error."""

import importlib.util
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from fuzzing import hang_guard, record

from almsdm_warp.errors import InputError

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str):
    """scripts/<name>.py imported as a module (the scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def load_or_record_error(load, path, test, case):
    """`load(path)` (under the hang guard), or None when it raises an InputError: then the message
    must be one line that names the file and says more, and it is recorded as the case's outcome."""
    try:
        with hang_guard(60):
            return load(path)
    except InputError as exc:
        message = str(exc)
        assert "\n" not in message and message.startswith(str(path)), message
        assert len(message) > len(str(path)) + 5
        record(test, case, "error", message[len(str(path)):])
        return None


def spring_stiffness_matrix(x, edges, ke, rest_length, anchor_ke):
    """The tangent stiffness K = -df/dx [N/m] of springs and anchors at positions `x` [n, 3]:
    each spring's exact block ke (d d^T + (1 - L0/l)(I - d d^T)), each anchor ka I; sparse, [3n, 3n].
    `ke`, `rest_length` per edge and `anchor_ke` per vertex: arrays or scalars."""
    n = len(x)
    r = x[edges[:, 1]] - x[edges[:, 0]]
    length = np.linalg.norm(r, axis=1)
    d = r / length[:, None]
    ddt = d[:, :, None] * d[:, None, :]
    eye = np.eye(3)
    blocks = np.asarray(ke)[..., None, None] * (ddt + (1.0 - rest_length / length)[:, None, None] * (eye - ddt))
    rows, cols, vals = [np.arange(3 * n)], [np.arange(3 * n)], [np.repeat(np.broadcast_to(anchor_ke, n), 3)]
    for a, b, sign in ((0, 0, 1.0), (1, 1, 1.0), (0, 1, -1.0), (1, 0, -1.0)):
        for i in range(3):
            for j in range(3):
                rows.append(3 * edges[:, a] + i)
                cols.append(3 * edges[:, b] + j)
                vals.append(sign * blocks[:, i, j])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))


def write_tet_ball(path, radius_mm: float, edge_mm: float):
    """A tet ball (mesh.primitives.tet_ball_arrays) written to `path` (.vtu) in millimetres; returns the path."""
    import meshio

    from almsdm_warp.mesh.primitives import tet_ball_arrays

    vertices, tets = tet_ball_arrays(radius_mm, edge_mm)
    meshio.write(path, meshio.Mesh(vertices * 1e3, [("tetra", tets)]))
    return path


def stop_after_writes(monkeypatch, count: int = 2):
    """A sweep killed mid-run: Parts.write writes `count` chunks, then raises KeyboardInterrupt.
    Returns the real Parts.write (to put back with monkeypatch.setattr before a resume)."""
    from almsdm_warp.batch.sweep_store import Parts

    real, calls = Parts.write, []

    def write_then_stop(self, i, columns):
        if len(calls) == count:
            raise KeyboardInterrupt
        calls.append(i)
        real(self, i, columns)

    monkeypatch.setattr(Parts, "write", write_then_stop)
    return real
