"""Solvers: one step of the region's free vertices, state_in -> state_out under a Control.

Integrators by registration: a new one is a SolverBase subclass in its own file plus one line in
INTEGRATORS; the command line's choices and the protocols read the keys.
"""

from .base import SolverBase
from .explicit import SolverExplicit
from .implicit import SolverImplicit

INTEGRATORS = {"explicit": SolverExplicit, "implicit": SolverImplicit}
"""Integrator name -> solver class (a SolverBase taking the model and its own keywords)."""


def solver_class(integrator: str) -> type:
    """The solver class of `integrator`; ValueError naming the known ones for any other."""
    try:
        return INTEGRATORS[integrator]
    except (KeyError, TypeError):
        raise ValueError(f"unknown integrator {integrator!r} (known: {', '.join(INTEGRATORS)})") from None


def make_solver(model, integrator: str = "explicit", **kw) -> SolverBase:
    """A solver of `integrator` on `model`; kw: the integrator's own options (implicit: cg_max_iterations, cg_tolerance)."""
    return solver_class(integrator)(model, **kw)


__all__ = ["INTEGRATORS", "SolverBase", "SolverExplicit", "SolverImplicit", "make_solver", "solver_class"]
