"""The press protocol (DESIGN.md, evaluation protocol): its parameters and its steps.

PressParams holds a press in seconds and metres (a scene's [press] table); PressSchedule counts
its steps at a time step dt. Every press loop (one palpation, several probes, a batch, a sweep's
progress, the evaluation's hold) counts its steps and its ramp through PressSchedule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..checks import check_fields

PRESS_KEYS: dict[str, tuple[str, type, float, str]] = {
    "depth_mm": ("depth", float, 1000.0, "> 0"),
    "ramp_s": ("ramp", float, 1.0, "> 0"),
    "hold_s": ("hold", float, 1.0, ">= 0"),
    "settle_s": ("settle", float, 1.0, "> 0"),
}
"""The [press] section of a scene file: key -> (attribute, type, file units per SI unit, rule)."""


@dataclass(frozen=True)
class PressParams:
    """The press protocol (DESIGN.md, evaluation protocol), in SI units."""

    depth: float = 10.0e-3
    """Indentation depth [m]: how far the contact vertex is driven along the inward surface normal."""
    ramp: float = 0.1
    """Ramp time [s] from rest to full depth."""
    hold: float = 0.2
    """Hold time [s] at full depth."""
    settle: float = 1.0
    """Settle window [s] after release; the recovery error is measured at its end."""

    def __post_init__(self):
        check_fields(self, PRESS_KEYS)


AMPLITUDES = ("depth", "force")
"""A press's amplitude (metres or newtons): > 0; its times (ramp, hold, settle [s]) are >= 0."""


def check_press(**values) -> None:
    """ValueError (an InputError) naming the first of `values` (name=seconds, metres or newtons) that is
    not a finite number of the magnitude every parameter is held to (checks.check_value), > 0 for the
    amplitude (a press of depth 0 has no stiffness) and >= 0 for the times."""
    from ..checks import check_value

    for name, value in values.items():
        check_value(value, float, "> 0" if name in AMPLITUDES else ">= 0", f"press {name}")


@dataclass(frozen=True)
class PressSchedule:
    """The steps of one press at step dt: ramp_n steps to full depth, hold_n held, settle_n released.

    Step s (0-based) of the ramp and hold drives the probe to `fraction(s)` of the depth (or force);
    from `release_step` on the probe is off.
    """

    ramp_n: int
    hold_n: int
    settle_n: int

    @classmethod
    def from_times(cls, dt: float, ramp: float, hold: float, settle: float = 0.0) -> "PressSchedule":
        """Steps of `ramp`, `hold` and `settle` [s] at `dt` [s]: each rounded to the nearest step, the
        ramp and the settle window at least one step."""
        return cls(max(int(round(ramp / dt)), 1), int(round(hold / dt)), max(int(round(settle / dt)), 1))

    @property
    def release_step(self) -> int:
        """The first step with the probe off (ramp and hold steps before it)."""
        return self.ramp_n + self.hold_n

    @property
    def total(self) -> int:
        """Steps of the whole press: ramp, hold and settle."""
        return self.ramp_n + self.hold_n + self.settle_n

    def fraction(self, s: int) -> float:
        """Fraction of the depth (or force) commanded at step s of the ramp and hold."""
        return min((s + 1) / self.ramp_n, 1.0)
