"""An independent large-deformation reference: compressible neo-Hookean P1 tets (NumPy/SciPy).

The classic compressible neo-Hookean energy (Ogden 1984; Bonet & Wood, Nonlinear Continuum
Mechanics for Finite Element Analysis, 2nd ed. 2008, ch. 6):

    Psi(F) = mu/2 (I_C - 3) - mu ln J + lambda/2 (ln J)^2,   I_C = tr F^T F,  J = det F,

with the Lame parameters of E and nu (fem.lame). It is deliberately not the product's stable variant
(mu/2 (I_C - 3) + lambda'/2 (J - alpha)^2, Smith, de Goes & Kim 2018): the comparison is against a
different, trusted formulation that shares no code with it. Both linearise at F = I to the same
tensor, mu (d_ik d_JL + d_iL d_Jk) + lambda d_iJ d_kL, so at small strain either is linear
elasticity with E and nu; they part at finite strain (and ln J makes this energy infinite as
J -> 0, so a line search on it never accepts an inverted tet).

The static solve minimises the total energy: Newton's method on the free dofs with the exact
tangent (sparse, assembled from vectorised per-tet blocks) and a backtracking line search on the
energy, the press depth and any prescribed displacements applied in load steps. A rigid
frictionless sphere is an augmented Lagrangian on the surface nodes with the sphere's true
(deformed, radial) gap g = |x - c| - R: per node (max(0, lambda_n - k g)^2 - lambda_n^2) / (2 k), a C1
energy that Newton and the line search treat like the elastic one, the multipliers updated
lambda_n <- max(0, lambda_n - k g) until the largest penetration is under a tolerance. Unlike a
plain penalty the converged answer does not depend on k (k only sets how many updates); unlike the
linear reference's active set (fem.solve_contact, gap along z) it follows the sphere's curvature,
which a deep press needs. P1 tets lock as nu -> 1/2 here as in fem.py: compare P1 with P1.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from . import fem


def neo_hookean_energy(f: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """Psi [Pa] of deformation gradients f [t, 3, 3]; inf where det F <= 0.

    Evaluated from H = F - I without the cancellations of I_C - 3 and ln J at small strain (the line
    search compares energies whose differences are second order in the strain): with
    J - 1 = tr H + ((tr H)^2 - tr H^2) / 2 + det H,
    I_C - 3 - 2 ln J = |H|^2 - ((tr H)^2 - tr H^2) - 2 det H + 2 (J - 1 - ln J).
    """
    h = f - np.eye(3)
    tr = np.einsum("tii->t", h)
    second = 0.5 * (tr**2 - np.einsum("tij,tji->t", h, h))
    det_h = np.linalg.det(h)
    j1 = tr + second + det_h
    ok = j1 > -1.0
    log_j = np.log1p(np.where(ok, j1, 0.0))
    psi = 0.5 * mu * (np.einsum("tij,tij->t", h, h) - 2.0 * second - 2.0 * det_h + 2.0 * (j1 - log_j)) + 0.5 * lam * log_j**2
    return np.where(ok, psi, np.inf)


def _per_tet(value, ndim: int):
    # a modulus [Pa], one for every tet or one each ([t]), shaped to broadcast against [t, ...] of `ndim` axes
    value = np.asarray(value, dtype=np.float64)
    return value.reshape((-1,) + (1,) * (ndim - 1)) if value.ndim else value


def neo_hookean_stress(f: np.ndarray, lam, mu) -> np.ndarray:
    """First Piola-Kirchhoff stress P = dPsi/dF = mu (F - F^-T) + lambda ln J F^-T [Pa], [t, 3, 3]
    (lam, mu: one for every tet, or one each)."""
    f_inv_t = np.transpose(np.linalg.inv(f), (0, 2, 1))
    log_j = np.log(np.linalg.det(f))
    return _per_tet(mu, 3) * (f - f_inv_t) + (lam * log_j)[:, None, None] * f_inv_t


def neo_hookean_moduli(f: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """A_iJkL = dP_iJ / dF_kL [Pa], [t, 3, 3, 3, 3]:
    mu d_ik d_JL + (mu - lambda ln J) F^-1_Jk F^-1_Li + lambda F^-1_Ji F^-1_Lk."""
    f_inv = np.linalg.inv(f)
    log_j = np.log(np.linalg.det(f))
    eye = np.eye(3)
    a = _per_tet(mu, 5) * np.einsum("ik,JL->iJkL", eye, eye)[None]
    a = a + (mu - lam * log_j)[:, None, None, None, None] * np.einsum("tJk,tLi->tiJkL", f_inv, f_inv)
    return a + _per_tet(lam, 5) * np.einsum("tJi,tLk->tiJkL", f_inv, f_inv)


class NeoHookeanBody:
    """P1 tets of a neo-Hookean material: total energy, internal force and tangent of displacements u [3n]."""

    def __init__(self, vertices, tets, young, poisson: float):
        # young [Pa]: one for every tet, or one each ([t]: a lesion)
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.tets = np.asarray(tets, dtype=np.int64)
        lam, mu = fem.lame(1.0, poisson)
        self.lam, self.mu = lam * np.asarray(young, dtype=np.float64), mu * np.asarray(young, dtype=np.float64)
        self.grads, self.volume = fem.barycentric_gradients(self.vertices[self.tets])
        if (self.volume <= 0).any():
            raise ValueError(f"tet {int(np.argmin(self.volume))} has volume {self.volume.min():.3g} m^3 (needs > 0)")
        self.dofs = (3 * self.tets[:, :, None] + np.arange(3)).reshape(len(self.tets), 12)
        self.size = 3 * len(self.vertices)

    def deformation(self, u: np.ndarray) -> np.ndarray:
        """F = I + sum_a u_a (x) grad N_a per tet, [t, 3, 3]."""
        ue = np.asarray(u).reshape(-1, 3)[self.tets]
        return np.eye(3) + np.einsum("tai,taj->tij", ue, self.grads)

    def energy(self, u: np.ndarray) -> float:
        """Stored energy [J] (inf if a tet inverts)."""
        return float(self.volume @ neo_hookean_energy(self.deformation(u), self.lam, self.mu))

    def force(self, u: np.ndarray) -> np.ndarray:
        """Internal force dE/du [N], [3n]: f_ai = V P_iJ dN_a/dX_J summed over tets."""
        p = neo_hookean_stress(self.deformation(u), self.lam, self.mu)
        fe = self.volume[:, None, None] * np.einsum("tij,taj->tai", p, self.grads)
        return np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=self.size)

    def tangent(self, u: np.ndarray) -> sp.csr_matrix:
        """Tangent stiffness d^2E/du^2 [N/m], [3n, 3n]: K_aibk = V dN_a/dX_J A_iJkL dN_b/dX_L."""
        a = neo_hookean_moduli(self.deformation(u), self.lam, self.mu)
        t = len(self.tets)
        a = np.transpose(a, (0, 2, 4, 1, 3)).reshape(t, 9, 9)  # [(J L), (i k)]
        gg = np.einsum("taJ,tbL->tabJL", self.grads, self.grads).reshape(t, 16, 9)
        ke = (self.volume[:, None, None] * np.matmul(gg, a)).reshape(t, 4, 4, 3, 3).transpose(0, 1, 3, 2, 4)
        rows = np.repeat(self.dofs, 12, axis=1).ravel()
        cols = np.tile(self.dofs, (1, 12)).ravel()
        return sp.csr_matrix((ke.reshape(-1), (rows, cols)), shape=(self.size, self.size))


@dataclasses.dataclass
class Sphere:
    """A rigid frictionless sphere lowered along -z until it first touches the body, then `depth` further."""

    radius: float
    depth: float
    centre_xy: tuple = (0.0, 0.0)

    def bottom(self, vertices: np.ndarray, depth: float) -> np.ndarray:
        """The sphere's lowest point [m] at `depth` below first touch of the rest positions."""
        r2 = (vertices[:, 0] - self.centre_xy[0]) ** 2 + (vertices[:, 1] - self.centre_xy[1]) ** 2
        inside = r2 < self.radius**2
        lift = self.radius - np.sqrt(self.radius**2 - r2[inside])
        touch = float((vertices[inside, 2] - lift).max())
        return np.array([self.centre_xy[0], self.centre_xy[1], touch - depth])


class SphereContact:
    """The augmented Lagrangian of a rigid sphere on some nodes: energy, gradient, Hessian of u [3n]."""

    def __init__(self, vertices, nodes, penalty: float, radius: float):
        self.vertices, self.nodes, self.k = vertices, np.asarray(nodes, dtype=np.int64), penalty
        self.multipliers = np.zeros(len(self.nodes))
        self.bottom, self.radius = np.zeros(3), radius
        self.size = 3 * len(vertices)

    def _geometry(self, u):
        """(outward unit normals, distances from the centre, gaps) of the nodes.

        Relative to the sphere's lowest point b, not its centre: with y = x - b and d = y - R e_z,
        g = |d| - R = (|y|^2 - 2 R y_z) / (|d| + R) keeps its relative precision however large R is
        (|x - c| - R loses about eps R, which a flat 100 m sphere makes visible)."""
        y = self.vertices[self.nodes] + np.asarray(u).reshape(-1, 3)[self.nodes] - self.bottom
        d = y - np.array([0.0, 0.0, self.radius])
        r = np.linalg.norm(d, axis=1)
        return d / r[:, None], r, (np.einsum("ij,ij->i", y, y) - 2.0 * self.radius * y[:, 2]) / (r + self.radius)

    def pressure(self, u) -> np.ndarray:
        """Contact force magnitudes [N] on the nodes, >= 0: max(0, lambda - k g)."""
        return np.maximum(0.0, self.multipliers - self.k * self._geometry(u)[2])

    def gaps(self, u) -> np.ndarray:
        """Signed gaps [m] of the nodes to the sphere (negative: inside)."""
        return self._geometry(u)[2]

    def energy(self, u) -> float:
        """(p^2 - lambda^2) / (2 k) summed, as -g (p + lambda) / 2 where p > 0 (no cancellation)."""
        g = self._geometry(u)[2]
        p = np.maximum(0.0, self.multipliers - self.k * g)
        return float(np.where(p > 0.0, -0.5 * g * (p + self.multipliers), -0.5 * self.multipliers**2 / self.k).sum())

    def gradient(self, u) -> np.ndarray:
        """dE/du [N], [3n]: -p n on each node (the body feels +p n, pushed out of the sphere)."""
        n = self._geometry(u)[0]
        out = np.zeros((self.size // 3, 3))
        out[self.nodes] = -self.pressure(u)[:, None] * n
        return out.ravel()

    def hessian(self, u) -> sp.csr_matrix:
        """d^2E/du^2 [N/m]: k n n^T - p (I - n n^T) / r on the nodes pressed (p > 0)."""
        n, r, _ = self._geometry(u)
        p = self.pressure(u)
        on = p > 0.0
        n, r, p = n[on], r[on], p[on]
        blocks = self.k * np.einsum("ti,tj->tij", n, n) - (p / r)[:, None, None] * (np.eye(3) - np.einsum("ti,tj->tij", n, n))
        dofs = 3 * self.nodes[on][:, None] + np.arange(3)
        rows = np.repeat(dofs, 3, axis=1).ravel()
        cols = np.tile(dofs, (1, 3)).ravel()
        return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(self.size, self.size))


@dataclasses.dataclass
class NeoHookeanResult:
    """A neo-Hookean static solve at its final load step."""

    force: float
    """Upward force [N] on the sphere, all copies of the part (0 without a sphere)."""
    reactions: np.ndarray
    """Internal force at the fixed dofs [N], [n, 3] (the supports' and driven nodes' force on the body; 0 elsewhere)."""
    displacement: np.ndarray
    """Nodal displacements [m], [n, 3]."""
    contact_force: np.ndarray
    """The sphere's force on each node [N], [n, 3]."""
    contact_radius: float
    """Largest distance [m] from the press axis of a node in contact (rest positions)."""
    max_penetration: float
    """Largest penetration [m] of a node into the sphere left at the end (>= 0)."""
    newton_iterations: list
    """Newton iterations of each load step (all multiplier updates together)."""


def _line_search(energy, u, free, du, slope, e0):
    """Backtracking (Armijo) on the total energy along du: the accepted state."""
    step = 1.0
    while step > 1e-10:
        trial = u.copy()
        trial[free] += step * du
        e = energy(trial)
        # the second test: near convergence the energy's change is below its rounding
        if e <= e0 + 1e-4 * step * slope or (np.isfinite(e) and abs(e - e0) <= 1e-12 * abs(e0) and step == 1.0):
            return trial
        step *= 0.5
    raise RuntimeError("the line search found no decrease of the energy (steps too large? try more load steps)")


def minimise(body, contact, u, free, rtol: float, atol: float, max_iter: int = 60):
    """Newton with a line search on body + contact energy over the dofs `free` (int ids): (u, iterations).

    Converged when every free dof's residual is under rtol x the largest internal force (the load's
    scale: reactions included) + atol [N]."""
    parts = (body,) if contact is None else (body, contact)
    energy = lambda x: sum(p.energy(x) for p in parts)  # noqa: E731
    for iteration in range(max_iter):
        internal = body.force(u)
        r = (internal + (0.0 if contact is None else contact.gradient(u)))[free]
        tol = rtol * np.abs(internal).max() + atol
        if np.abs(r).max() <= tol:
            return u, iteration
        k = body.tangent(u) if contact is None else body.tangent(u) + contact.hessian(u)
        du = fem.factor_spd(k[free][:, free]).solve(-r)
        slope = float(r @ du)
        if slope >= 0.0:  # not a descent direction (indefinite tangent): steepest descent instead
            du, slope = -r, -float(r @ r)
        u = _line_search(energy, u, free, du, slope, energy(u))
    raise RuntimeError(f"Newton did not converge in {max_iter} iterations (residual {np.abs(r).max():.3g} N > {tol:.3g} N)")


def _predict(body, u, fixed, target):
    """Move the fixed dofs to `target` and the free ones by the tangent's linear response (a Newton predictor)."""
    step = target - u[fixed]
    free = np.flatnonzero(~fixed)
    k = body.tangent(u)
    out = u.copy()
    out[fixed] = target
    if np.any(step):
        out[free] -= fem.factor_spd(k[free][:, free]).solve(k[free][:, np.flatnonzero(fixed)] @ step)
    if not np.isfinite(body.energy(out)):
        raise RuntimeError("a load step inverts tets: use more steps")
    return out


def _load_step(body, contact, u, fixed, target, tols, gap_tol, max_updates=30):
    """One load step: predictor, then Newton solves and multiplier updates until the gap closes: (u, iterations)."""
    u = _predict(body, u, fixed, target)
    free = np.flatnonzero(~fixed)
    total = 0
    for _ in range(max_updates):
        u, iterations = minimise(body, contact, u, free, *tols)
        total += iterations
        if contact is None:
            return u, total
        if max(0.0, -contact.gaps(u).min()) <= gap_tol:
            return u, total  # the multipliers stay those of this equilibrium: pressure(u) is its contact force
        contact.multipliers = contact.pressure(u)
    raise RuntimeError(f"the contact's multipliers did not settle in {max_updates} updates")


def solve(vertices, tets, *, young, poisson, fixed, values=None, sphere: Sphere | None = None, steps: int = 10,
          copies: int = 1, rtol: float = 1e-9, penalty: float = 100.0, gap_rtol: float = 1e-6) -> NeoHookeanResult:
    """The static equilibrium of a neo-Hookean body of P1 tets, loaded in `steps` equal steps.

    vertices [m], tets [t, 4]; young [Pa]: one E, or one a tet (a lesion); fixed: the fixed-dof mask [n, 3] or a function of the vertices that
    returns it (fem.clamped_below, fem.symmetry_planes); values: the fixed dofs' final displacements
    [m], [n, 3] (default zero; a driven vertex or face); sphere: a rigid frictionless sphere pressed
    into the top (its depth applied in steps too) on the surface nodes not fixed along z; copies: how
    many copies of this part the body is (4 for a quarter model). Newton stops when every free
    dof's residual is under rtol x the largest internal force + 1e-15 x E x (the body's diagonal)^2
    [N]; the contact when no node is more than gap_rtol x depth inside the sphere. penalty:
    k = penalty x E x (mean edge) [N/m], about `penalty` times a node's stiffness (each multiplier
    update cuts the penetration about as much).
    """
    body = NeoHookeanBody(vertices, tets, young, poisson)
    x = body.vertices
    fixed = np.asarray(fixed(x) if callable(fixed) else fixed, dtype=bool).reshape(-1)
    values = np.zeros(body.size) if values is None else np.asarray(values, dtype=np.float64).reshape(-1)
    diagonal = float(np.linalg.norm(x.max(axis=0) - x.min(axis=0)))
    young = float(np.max(young))  # the stiffest tet's scales the tolerances and the contact's penalty
    tols = (rtol, 1e-15 * young * diagonal**2)
    contact = None
    if sphere is not None:
        edge = float(np.cbrt(6.0 * np.sqrt(2.0) * body.volume).mean())  # a regular tet's edge of each volume
        surface = fem.surface_nodes(body.tets)
        contact = SphereContact(x, surface[~fixed[3 * surface + 2]], penalty * young * edge, sphere.radius)
    u = np.zeros(body.size)
    iterations = []
    for step in range(1, steps + 1):
        if contact is not None:
            contact.bottom = sphere.bottom(x, sphere.depth * step / steps)
        u, count = _load_step(body, contact, u, fixed, values[fixed] * step / steps, tols,
                              0.0 if sphere is None else gap_rtol * sphere.depth)
        iterations.append(count)
    return _result(body, contact, u, fixed, iterations, sphere, copies)


def _result(body, contact, u, fixed, iterations, sphere, copies) -> NeoHookeanResult:
    n = len(body.vertices)
    reactions = np.where(fixed, body.force(u), 0.0).reshape(n, 3)
    contact_force = np.zeros((n, 3)) if contact is None else -contact.gradient(u).reshape(n, 3)
    touching = np.zeros(0, dtype=np.int64) if contact is None else contact.nodes[contact.pressure(u) > 0.0]
    radial = np.hypot(*(body.vertices[touching, :2] - np.asarray(sphere.centre_xy if sphere else (0.0, 0.0))).T)
    return NeoHookeanResult(
        force=-float(contact_force[:, 2].sum()) * copies,
        reactions=reactions,
        displacement=u.reshape(n, 3),
        contact_force=contact_force,
        contact_radius=float(radial.max()) if len(radial) else 0.0,
        max_penetration=0.0 if contact is None else max(0.0, -float(contact.gaps(u).min())),
        newton_iterations=iterations,
    )
