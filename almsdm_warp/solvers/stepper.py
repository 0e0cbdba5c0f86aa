"""The host side of stepping, once for every protocol: substeps, the implicit fall-back, graph
capture, and the divergence check.

Palpation (and ProbeStroke, AdaptivePalpation), MultiPalpation and BatchPalpation plan their frames
with :func:`plan_substeps`, replay their captured steps through :func:`capture_step_pair` /
:func:`replayer`, and raise :class:`SimulationDiverged` through :func:`diverged` and
:func:`check_results`, so that they agree on when a run is one the model cannot hold and what they
say then.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..checks import LIMITS, substeps_for
from . import solver_class

FALLBACK = "implicit"
"""The integrator a protocol switches to where the one asked for would need more than
LIMITS["substeps"] substeps a frame: stable at any step (solvers.INTEGRATORS)."""

FORCE_BOUND_FACTOR = 100.0
"""A feedback force beyond this many times the stiffest vertex's stiffness (its law's
stiffness_bound) times the mesh's size is a run that diverged (a press the model holds stays far under it)."""


class SimulationDiverged(RuntimeError):
    """The simulation blew up: a force or position is not finite or beyond what the model can hold."""


def force_bound(model) -> float:
    """The largest feedback force [N] a run that has not diverged can report (see FORCE_BOUND_FACTOR)."""
    size = float(np.ptp(model.mesh.vertices, axis=0).max())
    bound = FORCE_BOUND_FACTOR * model.stiffness_bound() * size
    return bound if math.isfinite(bound) and bound > 0 else math.inf


@dataclass(frozen=True)
class SubstepPlan:
    """How a frame of dt is stepped: `substeps` steps of `integrator`; `critical_dt` [s] the explicit
    step's limit over the free vertices (inf where not asked); `note` what changed on its own, or None."""

    substeps: int
    integrator: str
    critical_dt: float = math.inf
    note: str | None = None


def plan_substeps(integrator: str, dt: float, critical, fixed: int | None = None, what: str = "it") -> SubstepPlan:
    """The plan for frames of `dt` [s] with `integrator`: a conditionally stable one takes `fixed`
    substeps, or (None) as many as keep each under 0.9 x critical() [s] (a callable, asked only
    here); past LIMITS["substeps"], one step of FALLBACK instead, with a note naming `what` runs it."""
    if not solver_class(integrator).conditionally_stable:
        return SubstepPlan(1, integrator)
    crit = critical()
    if fixed is not None:
        return SubstepPlan(int(fixed), integrator, crit)
    n = substeps_for(dt, crit)
    if n > LIMITS["substeps"]:
        note = (f"the {integrator} integrator would need more than {LIMITS['substeps']} substeps of dt {dt * 1e3:g} ms "
                f"(critical step {crit * 1e3:.3g} ms): {what} runs the {FALLBACK} integrator instead")
        return SubstepPlan(1, FALLBACK, crit, note)
    return SubstepPlan(n, integrator, crit)


def diverged(integrator: str, what: str, dt: float, substeps: int, critical_dt: float = math.inf) -> SimulationDiverged:
    """The error for a run of `integrator` that diverged `what` (where, and what it read: a force not
    finite or past its bound), with its frame dt [s], substeps and critical step [s]."""
    crit = f", critical step {critical_dt * 1e3:.3g} ms" if math.isfinite(critical_dt) else ""
    return SimulationDiverged(f"the {integrator} integrator diverged{what} (dt {dt * 1e3:g} ms in {substeps} substep(s){crit}); "
                              f"{remedies(integrator)}")


def remedies(integrator: str) -> str:
    """What to try after a run of `integrator` diverged, most likely first (the flags of the command line)."""
    other = f"--integrator {FALLBACK} (stable at any step), " if integrator != FALLBACK else ""
    return (f"try {other}a smaller --dt-ms (more substeps), or a shallower --depth-mm; a mesh of slivers "
            f"(see its quality note) or a tissue stiffer than the mesh resolves may need remeshing")


REPRESSES = 2
"""How many times a press of planned substeps (substeps "auto") that diverged is pressed again from where
it began, each time at twice the substeps (4x the plan's at most, never past LIMITS["substeps"]): the
plan's margin (0.9 of the critical step) is taken at rest, and a deep press stiffens a tet law's
compressed elements past it (a stiff lesion pressed 10 mm: docs/datasets.md). Palpation.press,
MultiPalpation.press and the batches' presses (batch/batch_palpation.py), each by may_press_again."""


def may_press_again(left: int, integrator: str, substeps: int) -> bool:
    """Whether a press of planned substeps that diverged is pressed again (REPRESSES): re-presses `left`, a
    conditionally stable `integrator` (more substeps make it stable) and room for twice `substeps`."""
    return left > 0 and solver_class(integrator).conditionally_stable and 2 * substeps <= LIMITS["substeps"]


def snapshot_states(states, current: int):
    """Where a press pressed again starts from (REPRESSES): `current` (which of `states` is the current one)
    and a copy of each state's positions and velocities; restore_states puts them back."""
    return current, [(wp.clone(s.particle_q), wp.clone(s.particle_qd)) for s in states]


def restore_states(states, snapshot) -> int:
    """Copy snapshot_states' copies back into `states`; returns the index of the current state they held."""
    current, saved = snapshot
    for state, (q, qd) in zip(states, saved):
        wp.copy(state.particle_q, q)
        wp.copy(state.particle_qd, qd)
    return current


def diverged_rows(peak, recovery, bound: float, size: float, hold=None) -> np.ndarray:
    """Which of several presses diverged (bool): a peak force [N] (or `hold` force) or recovery [m] not
    finite, a force past `bound` [N] or a recovery past twice the mesh's `size` [m]."""
    peak, recovery = np.asarray(peak, dtype=np.float64), np.asarray(recovery, dtype=np.float64)
    bad = ~(np.isfinite(peak) & np.isfinite(recovery)) | (peak > bound) | (recovery > 2.0 * size)
    if hold is not None:
        bad |= ~np.isfinite(np.asarray(hold, dtype=np.float64))
    return bad


def check_results(integrator: str, vertices, peak, recovery, bound: float, size: float, dt: float, substeps: int,
                  critical_dt: float = math.inf, hold=None) -> None:
    """SimulationDiverged naming the first of several presses (at mesh `vertices`) that diverged
    (diverged_rows)."""
    bad = diverged_rows(peak, recovery, bound, size, hold)
    if np.any(bad):
        peak, recovery = np.asarray(peak, dtype=np.float64), np.asarray(recovery, dtype=np.float64)
        b = int(np.flatnonzero(bad)[0])
        raise diverged(integrator, f" at {int(bad.sum())} of {len(bad)} contacts, the first at vertex {int(vertices[b])}: peak force "
                                   f"{peak[b]:.3g} N, recovery {recovery[b] * 1e3:.3g} mm", dt, substeps, critical_dt)


def replayer(graph, device):
    """A call that replays `graph` (and, on CUDA, waits for it so the pinned outputs are readable).

    On the CPU it binds Warp's native replay of a live capture directly: `wp.capture_launch` checks
    the graph's kind in Python first, ~0.3-0.8 us a step at these sizes (docs/performance.md).
    """
    if device.is_cpu:
        try:
            import warp._src.context as wpc

            native = wpc.runtime.core.wp_apic_cpu_replay_state
            state = graph.apic_state
            if graph._native_graph is None and state is not None:
                replay = functools.partial(native, state)
                replay.graph = graph  # the graph owns `state`: keep it alive as long as the call
                return replay
        except AttributeError:  # another Warp version: the public path
            pass
        return functools.partial(wp.capture_launch, graph)

    def replay():
        wp.capture_launch(graph)
        wp.synchronize_device(device)

    return replay


def capture_step_pair(launch_step, states, device):
    """Two replays: launch_step(states[0], states[1]) and back, each captured once (see replayer)."""
    replays = []
    for i in (0, 1):
        with wp.ScopedCapture(device=device, force_module_load=False) as cap:
            launch_step(states[i], states[1 - i])
        replays.append(replayer(cap.graph, device))
    return replays
