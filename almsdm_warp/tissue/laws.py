"""Tissue laws on the host: each law's entry names its kernel functions (kernels/laws), its critical
step and its stiffness bound. A new law is one file in kernels/laws, one line in each LAWS and its tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Callable

import numpy as np

from ..errors import InputError
from ..kernels.laws import LAWS as KERNEL_LAWS


def springs_critical_dt(model, vertices=None, anchors: bool = True) -> float:
    """Largest stable step [s] of semi-implicit Euler for the springs law, linearized at rest.

    The stiffest mode of M^-1/2 K M^-1/2 over the free `vertices` (default: all; the others
    held fixed) has eigenvalue w^2; with that mode's damping g = v^T M^-1/2 C M^-1/2 v, the
    scheme is stable while dt <= (-g + sqrt(g^2 + 4 w^2)) / w^2 (for g = 0: 2 / w). An estimate:
    a deep press adds geometric stiffness to the stretched springs.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import ArpackError, eigsh

    n = model.particle_count
    free = np.arange(n) if vertices is None else np.unique(np.asarray(vertices, dtype=np.int64))
    if len(free) == 0:
        return float("inf")
    e = model.mesh.edges.astype(np.int64)
    d = model.mesh.vertices[e[:, 1]] - model.mesh.vertices[e[:, 0]]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    ddt = d[:, :, None] * d[:, None, :]  # [e, 3, 3]
    scale = 1.0 if anchors else 0.0

    def assemble(edge_coef, vertex_coef):
        blocks = edge_coef[:, None, None] * ddt
        rows, cols, vals = [], [], []
        for a, b, sign in ((0, 0, 1.0), (1, 1, 1.0), (0, 1, -1.0), (1, 0, -1.0)):
            for r in range(3):
                for c in range(3):
                    rows.append(3 * e[:, a] + r)
                    cols.append(3 * e[:, b] + c)
                    vals.append(sign * blocks[:, r, c])
        diag = np.repeat(vertex_coef * scale, 3)
        rows.append(np.arange(3 * n))
        cols.append(np.arange(3 * n))
        vals.append(diag)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))

    dof = (3 * free[:, None] + np.arange(3)).ravel()
    w = np.repeat(1.0 / np.sqrt(model.particle_mass_host), 3)[dof]
    Winv = sp.diags(w)
    with np.errstate(all="ignore"):  # an overflow is reported below, in words
        K = Winv @ assemble(model.spring_ke_host, model.anchor_ke_host)[dof][:, dof] @ Winv
        C = Winv @ assemble(model.spring_kd_host, model.anchor_kd_host)[dof][:, dof] @ Winv
    if not (np.all(np.isfinite(K.data)) and np.all(np.isfinite(C.data))):
        raise InputError(
            f"the model's stiffness or damping over mass is not finite (largest spring {model.spring_ke_host.max():.3g} N/m, "
            f"anchor {model.anchor_ke_host.max():.3g} N/m; a lesion's stiffness_factor too large?): it has no stable step"
        )
    if K.shape[0] <= 60:
        vals, vecs = np.linalg.eigh(K.toarray())
        lam, v = vals[-1], vecs[:, -1]
    else:
        try:
            vals, vecs = eigsh(K, k=1, which="LA", tol=1e-6)
            lam, v = vals[0], vecs[:, 0]
        except ArpackError:  # no convergence: Gershgorin's bounds, which under-estimate the step
            lam, v = float(abs(K).sum(axis=1).max()), None
    if lam <= 0:
        return float("inf")
    g = float(v @ (C @ v)) if v is not None else float(abs(C).sum(axis=1).max())
    return float((-g + np.sqrt(g * g + 4.0 * lam)) / lam)


def springs_stiffness_bound(model) -> float:
    """The stiffest vertex's springs and anchor together [N/m] (float32 constants as the device holds them)."""
    e = model.mesh.edges
    k = np.zeros(model.particle_count)
    ke = model.spring_ke.numpy().astype(np.float64)
    np.add.at(k, e[:, 0], ke)
    np.add.at(k, e[:, 1], ke)
    k += model.anchor_ke.numpy()
    return float(k.max(initial=0.0))


@dataclass(frozen=True)
class Law:
    """A tissue law: its name, its kernel functions, its critical step and its stiffness bound."""

    name: str
    kernels: ModuleType
    """Its module in kernels/laws: vertex_force, implicit_row, static_row (wp.funcs the step kernels compose)."""
    critical_dt: Callable[..., float]
    """critical_dt(model, vertices=None, anchors=True): the explicit step's stable limit [s] over the free vertices."""
    stiffness_bound: Callable[..., float]
    """stiffness_bound(model): the stiffest vertex's stiffness [N/m]: a force past many times that
    stiffness times the mesh's size has diverged (almsdm_warp.solvers.stepper)."""


LAWS = {
    "springs": Law("springs", KERNEL_LAWS["springs"], springs_critical_dt, springs_stiffness_bound),
}
"""Law name -> its entry."""


def law_entry(name: str) -> Law:
    """The entry of law `name`; ValueError naming the known ones for any other."""
    try:
        return LAWS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown tissue law {name!r} (known: {', '.join(LAWS)})") from None
