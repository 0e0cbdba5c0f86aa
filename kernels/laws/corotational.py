"""Corotational linear elasticity on tets with average nodal pressure: the option beside stable
neo-Hookean for a material on a volume (kernels/laws/neo_hookean.py says how the two share a nodal
volumetric term and why it keeps linear tets from locking).

The energy is a sum over tets and a sum over vertices:

    E = sum_t V_t mu |F_t - R_t|^2 + sum_a V_a lambda_0 / 2 (J_a - 1)^2

R the rotation of F's polar decomposition (from F's singular value decomposition, a reflection
turned back into a rotation where F is inverted: Irving, Teran & Fedkiw 2004), J_a the nodal volume
change (kernels/laws/tets.py). At rest it is linear elasticity of Lame parameters (mu_0, lambda_0),
as the neo-Hookean law is; under a rotation the element term is unchanged (no ghost forces of a
rotated linear tet), and it grows quadratically in the stretch however large: no stiffening under
compression as neo-Hookean's, the classic choice of interactive surgical simulators (Mueller & Gross
2004). The force on corner c is -V_t (2 mu (F - R) b_c + p_t dJ/dF b_c) (dR/dF's term vanishes: F - R
is R times a symmetric matrix), the Gauss-Newton blocks V_0 (2 mu (b_a . b_b) I + lambda_0 (dJ b_a)
(dJ b_b)^T) (tets.tet_law).
"""

import warp as wp

from .tets import ENTRY_PARAMS, ENTRY_TOPOLOGY, VOLUMETRIC, Entries, TetEntry, nodal_pressure, tet_law  # noqa: F401

# no adjoints: nothing here is differentiated (smaller code, faster compiles)
wp.set_module_options({"enable_backward": False})


@wp.func
def rotation(F: wp.mat33):
    # R of F = R S (S symmetric): U V^T of F's singular value decomposition, the column of U of the
    # smallest singular value negated where det(U V^T) < 0 (an inverted tet), so that R is a rotation
    U = wp.mat33()
    sigma = wp.vec3()
    V = wp.mat33()
    wp.svd3(F, U, sigma, V)
    R = U * wp.transpose(V)
    if wp.determinant(R) < 0.0:
        k = int(0)
        if sigma[1] < sigma[k]:
            k = 1
        if sigma[2] < sigma[k]:
            k = 2
        for i in range(3):
            U[i, k] = -U[i, k]
        R = U * wp.transpose(V)
    return R


@wp.func
def stress(F: wp.mat33, dJ: wp.mat33, mu: float, pressure: float):
    # the first Piola-Kirchhoff stress P = 2 mu (F - R) + p_t dJ
    return (2.0 * mu) * (F - rotation(F)) + pressure * dJ


vertex_force, implicit_row, static_row, tet_forces = tet_law(stress, shear=2.0, element_bulk=0.0)
"""The step kernels' functions (kernels/laws/tets.py)."""
