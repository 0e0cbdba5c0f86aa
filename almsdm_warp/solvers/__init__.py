"""Solvers: one step of the region's free vertices, state_in -> state_out under a Control, and a batch's press.

Integrators by registration: a new one is a SolverBase subclass in its own file (its one-region
`integrate` and its batch's `press_batch`, each launching the kernels its folder in kernels/ makes
for the model's tissue law) plus one line in INTEGRATORS. Every protocol (Palpation, ProbeStroke,
MultiPalpation, BatchPalpation and the sweeps and datasets on it) and every command's --integrator
choices read the keys; the host stepper (solvers/stepper.py) plans their substeps.
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


def integrators(batch: bool = False) -> tuple[str, ...]:
    """The integrators' names; with batch, those that also press a batch (every one today)."""
    return tuple(name for name, cls in INTEGRATORS.items() if not batch or cls.has_batch())


def make_solver(model, integrator: str = "explicit", **kw) -> SolverBase:
    """A solver of `integrator` on `model`; kw: the integrator's own options (implicit: cg_max_iterations, cg_tolerance).
    ValueError where the model's tissue law has no kernels for it."""
    cls = solver_class(integrator)
    model.law_entry.require(integrator=integrator)
    return cls(model, **kw)


__all__ = ["INTEGRATORS", "SolverBase", "SolverExplicit", "SolverImplicit", "integrators", "make_solver", "solver_class"]
