"""A virtual coupling between a haptic device and the simulated tool (Colgate, Stanley & Brown 1995).

The device's position x_d is read every T (the haptic period, 1 ms at 1 kHz); the tool x_t is what
the simulation moves (the probe sphere's centre). A spring k_c and a damper b_c join them, so the
tool follows the device through the coupling against the tissue's force F_e on the tool:

    m_t x_t'' = k_c (x_d - x_t) + b_c (v_d - v_t) + F_e               (the tool, mass m_t)
    F_d       = k_c (x_t - x_d) + b_c (v_t - v_d)                    (the force sent to the device)

The tool is integrated by backward Euler in the coupling (the spring and damper at the new state:
no step limit from k_c or b_c) and forward in F_e (the tissue's force from the last step, as the
simulation reports it); v_d is the backward difference of the sampled device positions.

Passivity (Colgate & Schenkel 1997; Colgate, Stanley & Brown 1995): a device with physical damping b
that renders, through a zero-order hold at period T, a spring K and a damper B (by backward
difference) is passive when

    b > K T / 2 + |B|.

However stiff the tissue, the device never feels more than the coupling (k_c, b_c) in series with
it, so the coupling is chosen to meet that condition with K = k_c, B = b_c; `passive_stiffness`
gives the largest k_c a device and rate allow. A coupling that violates it is refused (ValueError).
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_TOOL_MASS = 0.02
"""The tool's mass [kg] (a 20 g probe): light enough to follow the device within a few ms."""


def passivity_margin(stiffness: float, damping: float, device_damping: float, period: float) -> float:
    """b - (K T / 2 + |B|) [N s/m]: > 0 for a passive sampled coupling (Colgate & Schenkel 1997)."""
    return float(device_damping) - (float(stiffness) * float(period) / 2.0 + abs(float(damping)))


def passive_stiffness(device_damping: float, period: float, damping: float = 0.0, safety: float = 0.5) -> float:
    """The coupling stiffness [N/m] `safety` x the largest that keeps b > K T / 2 + |B| for a device
    of damping `device_damping` [N s/m] sampled every `period` [s], with coupling damping `damping`."""
    if not 0.0 < safety < 1.0:
        raise ValueError(f"safety must be in (0, 1), got {safety!r}")
    _check_positive(period, "period")
    free = float(device_damping) - abs(float(damping))
    if not free > 0.0:
        raise ValueError(f"a device damping of {device_damping:g} N s/m leaves nothing for a spring after the "
                         f"coupling damping {damping:g} N s/m (passivity needs b > K T / 2 + |B|)")
    return safety * 2.0 * free / float(period)


def _check_positive(value, name, allow_zero=False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v < 0.0 or (v == 0.0 and not allow_zero):
        raise ValueError(f"{name} must be finite and {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return v


class VirtualCoupling:
    """A spring-damper between a sampled device position and a simulated tool of mass `tool_mass`.

    stiffness k_c [N/m], damping b_c [N s/m], period T [s] (the haptic loop's), device_damping b
    [N s/m] (the device's physical damping, for the passivity check b > k_c T / 2 + |b_c|).
    Positions are 3-vectors [m]. Call ``reset(x)`` with the device's first position, then each
    period ``update(x_d, f_env)`` with the device's position and the tissue's force on the tool at
    the current tool position [N]: it moves the tool (``tool``) and returns the force for the
    device [N].
    """

    def __init__(self, stiffness: float, damping: float, period: float, device_damping: float,
                 tool_mass: float = DEFAULT_TOOL_MASS):
        self.stiffness = _check_positive(stiffness, "coupling stiffness k_c [N/m]")
        self.damping = _check_positive(damping, "coupling damping b_c [N s/m]", allow_zero=True)
        self.period = _check_positive(period, "period T [s]")
        self.device_damping = _check_positive(device_damping, "device damping b [N s/m]", allow_zero=True)
        self.tool_mass = _check_positive(tool_mass, "tool mass [kg]")
        margin = passivity_margin(self.stiffness, self.damping, self.device_damping, self.period)
        if not margin > 0.0:
            k_max = 2.0 * (self.device_damping - self.damping) / self.period
            most = f"; at most {k_max:.4g} N/m ({k_max * 1e-3:.4g} N/mm) with this damping" if k_max > 0 else \
                "; the coupling damping alone already exceeds the device's"
            raise ValueError(
                f"the coupling k_c {self.stiffness:g} N/m, b_c {self.damping:g} N s/m is not passive at T "
                f"{self.period * 1e3:g} ms with a device damping b {self.device_damping:g} N s/m: passivity needs "
                f"b > k_c T / 2 + |b_c| = {self.stiffness * self.period / 2 + self.damping:.4g} N s/m{most}")
        self.tool = np.zeros(3)
        """The tool's position [m]."""
        self.tool_velocity = np.zeros(3)
        """The tool's velocity [m/s]."""
        self.device = np.zeros(3)
        """The device's last position [m]."""
        self.device_force = np.zeros(3)
        """The last force sent to the device [N]."""

    def reset(self, position) -> None:
        """Device and tool at `position` [m], at rest."""
        x = np.asarray(position, dtype=np.float64).reshape(3)
        self.tool = x.copy()
        self.device = x.copy()
        self.tool_velocity = np.zeros(3)
        self.device_force = np.zeros(3)

    def update(self, device_position, env_force) -> np.ndarray:
        """One period: the device is at `device_position` [m]; the tissue pushes the tool with
        `env_force` [N]. Moves the tool and returns the force for the device [N]."""
        k, b, T, m = self.stiffness, self.damping, self.period, self.tool_mass
        x_d = np.asarray(device_position, dtype=np.float64).reshape(3)
        v_d = (x_d - self.device) / T  # backward difference of the samples
        f_e = np.asarray(env_force, dtype=np.float64).reshape(3)
        # backward Euler in the coupling: m (v' - v) / T = k (x_d - x - T v') + b (v_d - v') + F_e
        v = (m / T * self.tool_velocity + k * (x_d - self.tool) + b * v_d + f_e) / (m / T + k * T + b)
        self.tool = self.tool + T * v
        self.tool_velocity = v
        self.device = x_d
        self.device_force = k * (self.tool - x_d) + b * (v - v_d)
        return self.device_force
