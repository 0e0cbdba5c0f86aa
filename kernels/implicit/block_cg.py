"""Block-Jacobi preconditioned conjugate gradients on a region's 3x3 blocks: the implicit steps' solve.

One function for the one-region step (kernels/implicit/step.py) and the batch
(kernels/implicit/batch.py, on each palpation's row views). It runs in the calling thread,
its sums in a fixed order, so a rerun gives the same bits on any device. Called once per step:
its array arguments are copied once, not per vertex.

The system is A dv = b over the `free_count` unknowns in local order, with A's row i the diagonal
block `block_diag[i]` and, for each CSR entry k of the row, -`csr_block[k]` at column
`csr_local[k]` (-1: a known, not an unknown: the fixed ring or the driven vertex). Row i's
entries are offsets[row]..offsets[row + 1] with row = rows[i] when `by_row`, else i. The driven
vertex (local index `driven`, -1 for none) has dv = 0. Where `constrained`, an unknown with a
nonzero unit `normal[i]` keeps the normal part of its warm start (the prescribed normal velocity
of a sphere's contact) and moves only in its tangent plane: residual and search directions are
filtered with S = I - n n^T (Baraff & Witkin 1998, modified PCG).

The solve stops where |r| <= tolerance x |b'|, b' the right-hand side of the system it solves. Without
constraints b' = b (its |b|^2 given as `b_norm2`). With them the unknowns are the tangential parts,
b' = S (b - A dv_c) with dv_c the prescribed normal parts, and r is kept in the tangent planes to
float32's precision. Where the probe stops or turns, A dv_c is far larger than the tangential
residual: filtered once, its rounding stays in r along n, which no search direction reduces, so
|r| stalls above the target; CG then iterates on rounding (r P^-1 r of either sign) and returns a
wrong dv (a vertex left deep inside the sphere, a force spike, another hold equilibrium).
"""

import warp as wp

from ..arrays import CG_FIELDS, BatchCGArrays, CGArrays, struct_from
from ..index import nonneg

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def filter_normal(x: wp.vec3, n: wp.vec3):
    # S x with S = I - n n^T: x without its part along the constrained normal (n = 0: unconstrained)
    return x - wp.dot(x, n) * n


@wp.func
def normal_part(x: wp.vec3, n: wp.vec3):
    # (n n^T) x: x's part along the constrained normal (n = 0: none)
    return wp.dot(x, n) * n


@wp.func
def solve_block_cg(
    free_count: int,
    driven: int,
    offsets: wp.array(dtype=wp.int32),
    rows: wp.array(dtype=wp.int32),
    by_row: int,
    csr_local: wp.array(dtype=wp.int32),
    csr_block: wp.array(dtype=wp.mat33),
    block_diag: wp.array(dtype=wp.mat33),
    block_diag_inv: wp.array(dtype=wp.mat33),
    constrained: int,
    normal: wp.array(dtype=wp.vec3),
    b_norm2: float,
    max_iterations: int,
    tolerance: float,
    dv: wp.array(dtype=wp.vec3),
    cg_r: wp.array(dtype=wp.vec3),
    cg_p: wp.array(dtype=wp.vec3),
    cg_Ap: wp.array(dtype=wp.vec3),
):
    # cg_r holds b on entry and the residual on return; dv the warm start, then the solution.
    # Returns (iterations, |r|^2, |b'|^2), b' the solved system's right-hand side (see above).
    # r = b - A dv (warm start), z = P^-1 r, p = z; with constraints, b' = S (b - A dv_c) on the way
    rz = float(0.0)
    rhs_norm2 = b_norm2
    if constrained != 0:
        rhs_norm2 = float(0.0)
    for i in range(free_count):
        row = i
        if by_row != 0:
            row = rows[i]
        if i == driven:
            dv[i] = wp.vec3(0.0)
        Ax = block_diag[i] * dv[i]
        for k in range(offsets[row], offsets[row + 1]):
            lj = csr_local[k]
            if lj >= 0:
                Ax -= csr_block[k] * dv[lj]
        r = cg_r[i] - Ax
        if i == driven:
            r = wp.vec3(0.0)
        if constrained != 0:
            # filtered twice: once leaves the rounding of the prescribed normal part (float32 eps x
            # |A dv_c|, far above the tangential residual) along n, where no search direction reaches
            # it and |r| stalls above the target; the second filter removes that
            r = filter_normal(filter_normal(r, normal[i]), normal[i])
            if i != driven:
                # row i of S (b - A dv_c): the prescribed normal velocity changes moved to the right-hand side
                Ac = block_diag[i] * normal_part(dv[i], normal[i])
                for k in range(offsets[row], offsets[row + 1]):
                    lj = csr_local[k]
                    if lj >= 0:
                        Ac -= csr_block[k] * normal_part(dv[lj], normal[lj])
                bc = filter_normal(filter_normal(cg_r[i] - Ac, normal[i]), normal[i])
                rhs_norm2 += wp.dot(bc, bc)
        z = block_diag_inv[i] * r
        if constrained != 0:
            z = filter_normal(z, normal[i])
        cg_r[i] = r
        cg_p[i] = z
        rz += wp.dot(r, z)

    iterations = int(0)
    r_norm2 = float(0.0)
    for i in range(free_count):
        r_norm2 += wp.dot(cg_r[i], cg_r[i])
    threshold = tolerance * tolerance * rhs_norm2
    while iterations < max_iterations and r_norm2 > threshold:
        pAp = float(0.0)
        for i in range(free_count):
            Ap = wp.vec3(0.0)
            if i != driven:
                row = i
                if by_row != 0:
                    row = rows[i]
                Ap = block_diag[i] * cg_p[i]
                for k in range(offsets[row], offsets[row + 1]):
                    lj = csr_local[nonneg(k)]
                    if lj >= 0:
                        Ap -= csr_block[nonneg(k)] * cg_p[lj]
                if constrained != 0:
                    Ap = filter_normal(Ap, normal[i])
            cg_Ap[i] = Ap
            pAp += wp.dot(cg_p[i], Ap)
        if not (pAp > 0.0):
            break  # p A p not positive (or not finite): the search direction is spent
        alpha = rz / pAp
        r_norm2 = float(0.0)
        rz_new = float(0.0)
        for i in range(free_count):
            dv[i] = dv[i] + alpha * cg_p[i]
            r = cg_r[i] - alpha * cg_Ap[i]
            cg_r[i] = r
            z = block_diag_inv[i] * r
            if constrained != 0:
                z = filter_normal(z, normal[i])
            cg_Ap[i] = z  # A p is spent: keep the preconditioned residual there
            r_norm2 += wp.dot(r, r)
            rz_new += wp.dot(r, z)
        if not (rz_new > 0.0):
            break  # r P^-1 r not positive: r is zero, or rounding only
        beta = rz_new / rz
        rz = rz_new
        for i in range(free_count):
            cg_p[i] = cg_Ap[i] + beta * cg_p[i]
        iterations += 1
    return iterations, r_norm2, rhs_norm2


class CGScratch:
    """The solve's arrays (CG_FIELDS), zeroed: `rows` None for one palpation's, else a row per palpation."""

    def __init__(self, vertex_capacity: int, entry_capacity: int, device, rows: int | None = None):
        sizes = {"vertex": vertex_capacity, "entry": max(entry_capacity, 1), "stats": 2}
        for name, dtype, size in CG_FIELDS:
            shape = sizes[size] if rows is None else (rows, sizes[size])
            setattr(self, name, wp.zeros(shape, dtype=dtype, device=device))
        self.arrays = struct_from(CGArrays if rows is None else BatchCGArrays, self)
        """The arrays above as one kernel argument (kernels/arrays.py)."""
