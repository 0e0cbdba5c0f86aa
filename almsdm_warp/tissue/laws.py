"""Tissue laws on the host: each law's entry names its kernel functions (kernels/laws), its critical
step and its stiffness bound. A new law is one file in kernels/laws, one line in each LAWS and its tests.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Callable

import numpy as np

from ..errors import InputError
from ..mesh.topology import csr_entries
from ..kernels.laws import LAWS as KERNEL_LAWS


def stable_step(mass, K, C, vertices=None, what: str = "") -> float:
    """Largest stable step [s] of semi-implicit Euler for stiffness K and damping C (3n x 3n, sparse)
    and lumped `mass` [n], over the free `vertices` (default: all; the others held fixed).

    The stiffest mode of M^-1/2 K M^-1/2 has eigenvalue w^2; with that mode's damping
    g = v^T M^-1/2 C M^-1/2 v, the scheme is stable while dt <= (-g + sqrt(g^2 + 4 w^2)) / w^2
    (for g = 0: 2 / w). Where the free vertices fall apart into pieces that share no entry of K or C
    (the regions of a batch), each piece's stiffest mode is found on its own (the modes of the whole
    are the pieces' modes: the same answer, without an eigensolver crawling through many equal
    eigenvalues). InputError where K or C over the mass is not finite (`what` says whose)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    n = len(mass)
    free = np.arange(n) if vertices is None else np.unique(np.asarray(vertices, dtype=np.int64))
    if len(free) == 0:
        return float("inf")
    w = 1.0 / np.sqrt(np.asarray(mass, dtype=np.float64)[free])
    with np.errstate(all="ignore"):  # an overflow is reported below, in words
        if vertices is not None:
            dof = (3 * free[:, None] + np.arange(3)).ravel()
            K, C = K.tocsr()[dof][:, dof], C.tocsr()[dof][:, dof]
        K, C = over_mass(K, w), over_mass(C, w)
    if not (np.all(np.isfinite(K.data)) and np.all(np.isfinite(C.data))):
        raise InputError(f"the model's stiffness or damping over mass is not finite ({what}): it has no stable step")
    pieces, label = (1, None) if K.shape[0] <= 60 else connected_components(pattern(K, C), directed=False)
    if pieces == 1:
        lam, g = stiffest_mode(K, C)
    else:
        if K.format == "bsr":
            K, C, label = K.tocsr(), C.tocsr(), np.repeat(label, 3)
        order = np.argsort(label, kind="stable")
        bounds = np.searchsorted(label[order], np.arange(pieces + 1))
        modes = [stiffest_mode(K[idx][:, idx], C[idx][:, idx])
                 for idx in (order[b:e] for b, e in zip(bounds[:-1], bounds[1:]))]
        lam, g = max(modes, key=lambda m: m[0])
    if lam <= 0:
        return float("inf")
    return float((-g + np.sqrt(g * g + 4.0 * lam)) / lam)


def over_mass(A, w: np.ndarray):
    """W A W for W = diag(w) repeated over each vertex's 3 rows (w [n]: M^-1/2 of each vertex); a 3x3 block
    matrix (BSR, a block a vertex pair) is scaled in place, block by block (no second copy of a large mesh's)."""
    import scipy.sparse as sp

    if A.format == "bsr" and A.blocksize == (3, 3):
        A.data *= (np.repeat(w, np.diff(A.indptr)) * w[A.indices])[:, None, None]
        return A
    W = sp.diags(np.repeat(w, 3))
    return (W @ A @ W).tocsr()


def pattern(K, C):
    """The graph of K's and C's nonzero couplings (of 3x3 blocks, a vertex each, for BSR; else of rows)."""
    import scipy.sparse as sp

    if K.format == "bsr":  # the springs' blocks: C's pattern is K's
        return sp.csr_matrix((np.ones(len(K.indices), dtype=np.int8), K.indices, K.indptr), shape=(len(K.indptr) - 1,) * 2)
    return abs(K) + abs(C)


def stiffest_mode(K, C) -> tuple[float, float]:
    """(w^2, g): the largest eigenvalue of the symmetric K and its mode's damping v^T C v (stable_step);
    where the eigensolver does not converge, Gershgorin's bounds of both (they under-estimate the step).
    ARPACK starts from a seeded random vector: the same estimate on every call and run (from its own random
    start, the paper preset's whole-mesh step moved by 1e-7 between three calls of one process)."""
    from scipy.sparse.linalg import ArpackError, eigsh

    if K.shape[0] <= 60:
        vals, vecs = np.linalg.eigh(K.toarray())
        lam, v = vals[-1], vecs[:, -1]
    else:
        try:
            start = np.random.default_rng(0).standard_normal(K.shape[0])
            vals, vecs = eigsh(K, k=1, which="LA", tol=1e-6, v0=start)
            lam, v = vals[0], vecs[:, 0]
        except ArpackError:
            return float(abs(K).sum(axis=1).max()), float(abs(C).sum(axis=1).max())
    return float(lam), float(v @ (C @ v))


def block_matrix(n: int, rows, cols, blocks, diagonal=None):
    """The 3n x 3n sparse matrix of 3x3 `blocks` [m, k, 3, 3] at block rows `rows` and columns `cols`
    (vertex ids, [m, k]; repeated entries add up), plus `diagonal` [n] on the diagonal."""
    import scipy.sparse as sp

    r = (3 * np.asarray(rows, dtype=np.int64))[..., None, None] + np.arange(3)[:, None]
    c = (3 * np.asarray(cols, dtype=np.int64))[..., None, None] + np.arange(3)[None, :]
    r, c = np.broadcast_to(r, blocks.shape).ravel(), np.broadcast_to(c, blocks.shape).ravel()
    values = blocks.ravel()
    if diagonal is not None:
        r, c = np.concatenate([r, np.arange(3 * n)]), np.concatenate([c, np.arange(3 * n)])
        values = np.concatenate([values, np.repeat(diagonal, 3)])
    return sp.csr_matrix((values, (r, c)), shape=(3 * n, 3 * n))


def springs_matrices(model, anchors: bool = True, vertices=None):
    """(K, C): the springs law's stiffness and damping at rest (springs along their edges, anchors),
    3n x 3n as 3x3 blocks (BSR: a block a vertex pair, from the mesh's CSR adjacency, so no more memory
    than the blocks); with `vertices` (sorted, unique), only their rows and columns, 3m x 3m in their
    order (the springs that touch them: work that grows with them, not with the mesh)."""
    import scipy.sparse as sp

    offsets, neighbour, edge_id = model.mesh.adjacency
    n = model.particle_count
    v = np.arange(n, dtype=np.int64) if vertices is None else np.asarray(vertices, dtype=np.int64)
    at = np.arange(len(neighbour)) if vertices is None else csr_entries(offsets, v)
    row = np.repeat(np.arange(len(v)), offsets[v + 1] - offsets[v])
    col = neighbour[at].astype(np.int64)
    if vertices is not None:  # local ids; -1 outside
        slot = np.minimum(np.searchsorted(v, col), len(v) - 1)
        col = np.where(v[slot] == col, slot, -1)
    e = edge_id[at]
    p, ends = model.mesh.vertices, model.mesh.edges
    d = p[ends[e, 1]] - p[ends[e, 0]]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    inside = col >= 0
    # each row's blocks in column order, its diagonal block slotted in among the neighbours inside
    count = np.bincount(row[inside], minlength=len(v))
    indptr = np.concatenate([[0], np.cumsum(count + 1)])
    rank = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)  # place among its row's inside
    slot = indptr[row[inside]] + rank + (col[inside] > row[inside])
    diagonal = indptr[:-1] + np.bincount(row[inside & (col < row)], minlength=len(v))
    indices = np.empty(indptr[-1], dtype=np.int32)
    indices[slot], indices[diagonal] = col[inside], np.arange(len(v))
    scale = 1.0 if anchors else 0.0
    out = []
    for edge, vertex in ((model.spring_ke_host, model.anchor_ke_host), (model.spring_kd_host, model.anchor_kd_host)):
        k_e, data = edge[e], np.empty((indptr[-1], 3, 3))
        with np.errstate(all="ignore"):
            for i, j in np.ndindex(3, 3):  # a component of every block at a time: k d_i d_j [entries]
                part = k_e * (d[:, i] * d[:, j])
                data[slot, i, j] = -part[inside]
                data[diagonal, i, j] = np.bincount(row, weights=part, minlength=len(v)) + (vertex[v] * scale if i == j else 0.0)
        out.append(sp.bsr_matrix((data, indices, indptr), shape=(3 * len(v), 3 * len(v))))
    return tuple(out)


def springs_critical_dt(model, vertices=None, anchors: bool = True) -> float:
    """Largest stable step [s] of semi-implicit Euler for the springs law, linearized at rest (stable_step).
    An estimate: a deep press adds geometric stiffness to the stretched springs."""
    what = (f"largest spring {model.spring_ke_host.max():.3g} N/m, anchor {model.anchor_ke_host.max():.3g} N/m; "
            f"a lesion's stiffness_factor too large?")
    if vertices is None:
        return stable_step(model.particle_mass_host, *springs_matrices(model, anchors), None, what)
    free = np.unique(np.asarray(vertices, dtype=np.int64))
    return stable_step(model.particle_mass_host[free], *springs_matrices(model, anchors, free), None, what)


def springs_entries(model):
    """The springs law's entries: each vertex's CSR adjacency (its springs) and their constants."""
    dm = model.dmesh
    return dm.adj_offsets, dm.adj_vertex, model.adj_spring


def springs_stiffness_bound(model) -> float:
    """The stiffest vertex's springs and anchor together [N/m] (float32 constants as the device holds them,
    rounded from the host's: no read from the device, which would wait for each of its streams)."""
    e = model.mesh.edges
    k = np.zeros(model.particle_count)
    ke = model.spring_ke_host.astype(np.float32).astype(np.float64)
    np.add.at(k, e[:, 0], ke)
    np.add.at(k, e[:, 1], ke)
    k += model.anchor_ke_host.astype(np.float32)
    return float(k.max(initial=0.0))


def lame(young: float, poisson: float) -> tuple[float, float]:
    """(mu_0, lambda_0) [Pa] of Young's modulus [Pa] and Poisson's ratio."""
    return young / (2.0 * (1.0 + poisson)), young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))


def check_volumetric(law: str, mesh, tissue) -> None:
    """ValueError unless `mesh` has tets and `tissue` is a Material of Poisson's ratio in [0, 0.5)."""
    from .material import Material

    if not mesh.tet_count:
        raise ValueError(f"the {law} law is a volumetric law: it needs a tet mesh, and {mesh.name} has no tetrahedra")
    if not isinstance(tissue, Material):
        raise ValueError(f"the {law} law needs a material (Young's modulus and Poisson's ratio), not the paper's per-spring constants")
    if not 0.0 <= tissue.poisson_ratio < 0.5:
        raise ValueError(f"the {law} law needs a Poisson's ratio in [0, 0.5), got {tissue.poisson_ratio}")


def _tet_material(model):
    # the tets (each oriented to a positive rest volume), their rest data, and (mu_0, lambda_0)
    mesh, tissue = model.mesh, model.tissue
    check_volumetric(model.law, mesh, tissue)
    tets = mesh.tetrahedra.astype(np.int64).copy()
    x = mesh.vertices
    dm = np.stack([x[tets[:, c]] - x[tets[:, 0]] for c in (1, 2, 3)], axis=2)  # columns: edges from corner 0
    det = np.linalg.det(dm)
    flip = det < 0
    tets[flip, 1], tets[flip, 2] = tets[flip, 2].copy(), tets[flip, 1].copy()
    dm[flip, :, 0], dm[flip, :, 1] = dm[flip, :, 1].copy(), dm[flip, :, 0].copy()
    det = np.abs(det)
    if np.any(det <= 0):
        bad = int(np.flatnonzero(det <= 0)[0])
        raise ValueError(f"tet {bad} of {mesh.name} has no volume: the {model.law} law cannot hold it")
    mu, lam = lame(tissue.youngs_modulus, tissue.poisson_ratio)
    scale = np.ones(len(tets)) if getattr(model, "element_scale", None) is None else model.element_scale
    return tets, dm, det / 6.0, (mu * scale, lam * scale)  # per tet (a lesion scales both)


CORNER_ORDER = np.array([[1, 0, 3, 2], [0, 1, 2, 3], [0, 2, 3, 1], [0, 3, 1, 2]])
"""A vertex at corner c of an oriented tet sees it as (i, a, j, k) = the tet's corners in row c's order:
itself second and the same orientation (each row an even permutation), so that its entry's volume is
(x_a - x_i) . ((x_j - x_i) x (x_k - x_i)) / 6 and that volume's gradient at x_a is the cross product."""


def tet_entries(model):
    """A tet law's entries (kernels/laws/tets.py): each vertex's incident tets (vertex-to-tet CSR), each
    with the tet's four vertex ids in the vertex's order (CORNER_ORDER: the vertex is corner 1) and its
    rest data in that order (D_m^-1, V_0, mu_0, lambda_0, the shear weights, the vertex's nodal weights)."""
    import warp as wp

    from ..kernels.laws.tets import TetEntry

    tets, _, volume, (mu, lam0) = _tet_material(model)
    n = model.particle_count
    corner_vertex = tets.ravel()
    order = np.argsort(corner_vertex, kind="stable")  # by vertex, then tet, then corner
    tet_of, corner = order // 4, order % 4
    offsets = np.concatenate([[0], np.cumsum(np.bincount(corner_vertex, minlength=n))]).astype(np.int32)
    topology = tets[tet_of[:, None], CORNER_ORDER[corner]]  # [entries, 4]: (i, a, j, k)
    x = model.mesh.vertices
    dm = np.stack([x[topology[:, c]] - x[topology[:, 0]] for c in (1, 2, 3)], axis=2)
    dm_inv = np.linalg.inv(dm)
    grads = np.concatenate([-dm_inv.sum(axis=1, keepdims=True), dm_inv], axis=1)  # [entries, 4, 3]: b_i, b_a, b_j, b_k
    v0, m0 = volume[tet_of], mu[tet_of]
    shear = (m0 * v0)[:, None] * np.einsum("ecx,ex->ec", grads[:, 1:], grads[:, 1])  # mu V_0 (b_a.b_a, b_j.b_a, b_k.b_a)
    rest = np.bincount(corner_vertex, weights=np.tile(volume[:, None], (1, 4)).ravel(), minlength=n)  # S_a = sum V_t
    kappa = np.bincount(corner_vertex, weights=np.tile((volume * lam0)[:, None], (1, 4)).ravel(), minlength=n) / np.maximum(rest, 1e-300)
    params = np.zeros(len(order), dtype=TetEntry.numpy_dtype())
    params["dm_inv"] = dm_inv
    params["volume"] = v0
    params["mu"] = m0
    params["bulk"] = lam0[tet_of]
    params["corner"] = 1
    params["gradient"] = grads[:, 1]
    params["shear"] = shear
    params["mu_v6"] = m0 / (6.0 * v0)
    owner = corner_vertex[order]
    params["nodal"] = np.stack([1.0 / (6.0 * rest[owner]), kappa[owner]], axis=1)
    params["slots"] = _row_slots(model.mesh.adjacency, owner, topology)
    d = model.device
    return (wp.array(offsets, dtype=wp.int32, device=d), wp.array(topology.astype(np.int32), dtype=wp.vec4i, device=d),
            wp.array(params, dtype=TetEntry, device=d))


def tet_entry_tets(model):
    """(entry_tet, tet_corners, tet_rest): each of a tet law's entries' tet (the order of tet_entries),
    int32 [entries]; each tet's corners as oriented there, int32 [tets, 4]; and its rest data in that
    order (kernels/laws/tets.py TetRest: D_m^-1, V_0, mu_0, the shear weights), for a pass over each tet once
    (kernels/region/volumes.py)."""
    from ..kernels.laws.tets import TetRest

    tets, dm, volume, (mu, _) = _tet_material(model)
    order = np.argsort(tets.ravel(), kind="stable")  # tet_entries' order: by vertex, then tet, then corner
    rest = np.zeros(len(tets), dtype=TetRest.numpy_dtype())
    dm_inv = np.linalg.inv(dm)
    rest["dm_inv"], rest["volume"], rest["mu"] = dm_inv, volume, mu
    rest["shear"] = (mu * volume)[:, None, None] * np.einsum("tck,tdk->tcd", dm_inv, dm_inv)  # mu V_0 (b_c . b_d), rows of D_m^-1
    rest["mu_v6"] = mu / (6.0 * volume)
    return (order // 4).astype(np.int32), tets.astype(np.int32), rest


def _row_slots(adjacency, owner: np.ndarray, topology: np.ndarray) -> np.ndarray:
    """[entries, 4] int32: each entry's corners' places in its vertex's adjacency row (TetEntry.slots),
    -1 at the vertex's own corner (1); every other corner shares an edge of the tet with it."""
    offsets, neighbour = (np.asarray(a, dtype=np.int64) for a in adjacency[:2])
    n = len(offsets) - 1
    row = np.repeat(np.arange(n, dtype=np.int64), np.diff(offsets))
    keys = row * n + neighbour  # sorted: rows in order, each row's neighbours sorted by id
    owner = np.asarray(owner, dtype=np.int64)
    others = [0, 2, 3]  # corner 1 is the vertex itself
    wanted = owner[:, None] * n + topology[:, others].astype(np.int64)
    at = np.minimum(np.searchsorted(keys, wanted), len(keys) - 1)
    if not np.array_equal(keys[at], wanted):
        raise ValueError("a tet's corners do not all share an edge of the mesh: its edges must include the tets'")
    slots = np.full((len(owner), 4), -1, dtype=np.int32)
    slots[:, others] = at - offsets[owner][:, None]
    return slots


def _tet_gradients(model, vertices=None):
    # the tets (those with a corner among `vertices`, default all), their corners' barycentric
    # gradients at rest [m, 4, 3], volumes and (mu_0, lambda_0) each, and each vertex's nodal
    # volume sum_t V_t and bulk modulus kappa_a over all its tets (kernels/laws/neo_hookean.py)
    tets, dm, volume, (mu, lam) = _tet_material(model)
    n = model.particle_count
    nodal_volume = np.bincount(tets.ravel(), weights=np.repeat(volume, 4), minlength=n)
    kappa = np.bincount(tets.ravel(), weights=np.repeat(volume * lam, 4), minlength=n) / np.maximum(nodal_volume, 1e-300)
    if vertices is not None:
        keep = np.isin(tets, np.asarray(vertices, dtype=np.int64)).any(axis=1)
        tets, dm, volume, mu, lam = tets[keep], dm[keep], volume[keep], mu[keep], lam[keep]
    grads = np.linalg.inv(dm)  # rows: gradients of the barycentric coordinates of corners 1..3
    return tets, np.concatenate([-grads.sum(axis=1, keepdims=True), grads], axis=1), volume, mu, (nodal_volume, kappa)


def tet_stiffness(model, vertices=None):
    """A tet law (neo-Hookean or corotational) linearized at rest [N/m], 3n x 3n: its tets' linear elasticity of Lame
    parameters (mu_0, 0) plus the nodal volumetric term, B^T diag(S_a kappa_a / 4) B with B the nodal
    volume change per displacement, B[a, c] = sum over a's tets t holding c of V_t b_c / S_a (S_a =
    sum of a's tets' V_t): together linear elasticity of (mu_0, lambda_0) with the volume change
    averaged over each vertex's tets (average nodal pressure). With `vertices`, of the tets touching
    them only (every block between two of them exact, the rest left out)."""
    import scipy.sparse as sp

    tets, g, volume, mu, (nodal_volume, kappa) = _tet_gradients(model, vertices)
    n = model.particle_count
    # the tets' part: K_ab = V mu ((g_a . g_b) I + g_b g_a^T)
    dots = np.einsum("mai,mbi->mab", g, g)
    mu = mu[:, None, None, None, None]
    blocks = volume[:, None, None, None, None] * mu * (dots[..., None, None] * np.eye(3) + np.einsum("mbi,maj->mabij", g, g))
    rows, cols = np.broadcast_to(tets[:, :, None], (len(tets), 4, 4)), np.broadcast_to(tets[:, None, :], (len(tets), 4, 4))
    K = block_matrix(n, rows, cols, blocks)
    # the nodal part: row a of B gets V_t b_c / S_a at corner c's columns, for each corner a of each tet t
    a = np.broadcast_to(tets[:, :, None, None], (len(tets), 4, 4, 3))
    col = 3 * np.broadcast_to(tets[:, None, :, None], (len(tets), 4, 4, 3)) + np.arange(3)
    val = (volume[:, None, None, None] * np.broadcast_to(g[:, None, :, :], (len(tets), 4, 4, 3))) / nodal_volume[a]
    B = sp.csr_matrix((val.ravel(), (a.ravel(), col.ravel())), shape=(n, 3 * n))
    return (K + B.T @ sp.diags(nodal_volume * kappa / 4.0) @ B).tocsr()


def tet_critical_dt(model, vertices=None, anchors: bool = True) -> float:
    """Largest stable step [s] of semi-implicit Euler for a tet law linearized at rest (its
    tets' linear elasticity, the anchors and the vertex dampers; stable_step). A deep press stiffens
    a compressed tet: Palpation takes its substeps under 0.9 of this."""
    import scipy.sparse as sp

    scale = 1.0 if anchors else 0.0
    K = tet_stiffness(model, vertices) + sp.diags(np.repeat(model.anchor_ke_host * scale, 3))
    C = sp.diags(np.repeat(model.anchor_kd_host * scale, 3)).tocsr()
    return stable_step(model.particle_mass_host, K, C, vertices, f"E {model.tissue.youngs_modulus:.3g} Pa")


def tet_stiffness_bound(model) -> float:
    """An upper bound of the largest row sum of |K| of the tets at rest, plus the stiffest anchor [N/m]:
    each block |K_ab| <= V (2 mu + lambda) |b_a| |b_b| (at most 3x that a row), summed over a vertex's
    tets, without assembling K (O(tets) memory: a mesh of 1e5 tets costs no start-up)."""
    tets, g, volume, mu, (_, kappa) = _tet_gradients(model)
    norm = np.linalg.norm(g, axis=2)  # [m, 4]
    lam = kappa[tets].max(axis=1)  # the nodal term at most as stiff as the tet's own volume change with its stiffest corner's
    per = 3.0 * (volume * (2.0 * mu + lam))[:, None] * norm * norm.sum(axis=1, keepdims=True)
    k = np.bincount(tets.ravel(), weights=per.ravel(), minlength=model.particle_count)
    return float(k.max(initial=0.0)) + float(model.anchor_ke_host.max(initial=0.0))


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
    entries: Callable
    """entries(model): (offsets, topology, params), the device arrays of each vertex's entries that the
    law's vertex_force gathers (Model.entry_offsets, entry_topology, entry_params)."""
    integrators: tuple | None = None
    """The integrators with kernels for this law; None: every one of solvers.INTEGRATORS."""
    paths: tuple | None = None
    """The protocols with kernels for this law ("palpation", "batch", "stroke", "multi", "adaptive");
    None: every one."""
    check: Callable | None = None
    """check(law, mesh, tissue): ValueError where the law cannot model this mesh or tissue (before any work)."""

    def require(self, integrator: str | None = None, path: str | None = None) -> None:
        """ValueError where this law has no kernels for `integrator` or the protocol `path`."""
        if integrator is not None and not self.has(integrator=integrator):
            raise ValueError(f"the {self.name} law has no {integrator} step (it has: {', '.join(self.integrators)})")
        if path is not None and not self.has(path=path):
            raise ValueError(f"the {self.name} law has no kernels for a {path} (only: {', '.join(self.paths)})")

    @property
    def volumetric(self) -> bool:
        """Its entries are a vertex's incident tets (its kernels' VOLUMETRIC: a batch builds them as local tets)."""
        return bool(self.kernels.VOLUMETRIC)

    def has(self, integrator: str | None = None, path: str | None = None) -> bool:
        """Whether this law has kernels for `integrator` and the protocol `path` (None: not asked)."""
        return ((integrator is None or self.integrators is None or integrator in self.integrators)
                and (path is None or self.paths is None or path in self.paths))


LAWS = {
    "springs": Law("springs", KERNEL_LAWS["springs"], springs_critical_dt, springs_stiffness_bound, springs_entries),
    "neo-hookean": Law("neo-hookean", KERNEL_LAWS["neo-hookean"], tet_critical_dt, tet_stiffness_bound,
                       tet_entries, check=check_volumetric),
    "corotational": Law("corotational", KERNEL_LAWS["corotational"], tet_critical_dt, tet_stiffness_bound,
                        tet_entries, check=check_volumetric),
}
"""Law name -> its entry."""


def default_law(volume: bool, tissue) -> str:
    """The tissue law of a model that names none: stable neo-Hookean tets for a material on a volume
    (a tet mesh), the springs elsewhere (a surface, or the paper's per-spring constants)."""
    from .material import Material

    return "neo-hookean" if volume and isinstance(tissue, Material) else "springs"


def resolve_law(law: str | None, mesh, tissue) -> str:
    """`law`, or for None the default of `mesh` (a TissueMesh or DeviceMesh) and `tissue` (default_law)."""
    if law is not None:
        return law
    tets = getattr(mesh, "tetrahedra", None)
    return default_law(tets is not None and len(tets) > 0, tissue)


def law_entry(name: str) -> Law:
    """The entry of law `name`; ValueError naming the known ones for any other."""
    try:
        return LAWS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown tissue law {name!r} (known: {', '.join(LAWS)})") from None
