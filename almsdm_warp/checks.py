"""Checks of the values a user gives (scene files, parameter classes): one line each, naming where.

Every problem is an InputError whose message starts with the `name` it was given
(``[tissue] thickness_mm``, ``TissueParams.density``); a scene loader adds the file's path.
Rules: "path" (a non-empty string), "> 0", ">= 0", ">= 1" (integers).
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .errors import InputError

MAGNITUDE = (1.0e-12, 1.0e12)
"""A number in a scene is 0 (where allowed) or of magnitude within these bounds, in the file's units
as in SI: products of such values stay far inside float32 (the device's), no tissue is outside
them, and a value outside them is a typo or a unit mix-up."""

AUTO = "auto"
"""[region] rings = "auto": the region sized to [region] tol_mm during each press (docs/adaptive.md)."""
AUTO_TOL = 1.0e-4
"""The tolerance [m] of rings "auto" when none is given (0.1 mm): --tol-mm's default, a scene's, a dataset's."""

_TOML_TYPE = {str: "a string", float: "a number", int: "an integer"}


def describe(value) -> str:
    """A TOML value as the user wrote it, with its TOML type."""
    if isinstance(value, bool):
        return f"boolean {str(value).lower()}"
    if isinstance(value, str):
        return f"string {value!r}"
    if isinstance(value, int):
        return f"integer {value}"
    if isinstance(value, float):
        return f"float {value!r}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    return f"{type(value).__name__} {value!r}"  # dates and times


def check_rings(value, name: str):
    """[region] rings: an integer >= 1 or the string "auto"."""
    if isinstance(value, str):
        if value != AUTO:
            raise InputError(f"{name} must be an integer >= 1 or {AUTO!r}, got {describe(value)}")
        return value
    return check_value(value, int, ">= 1", name)


def check_value(value, kind: type, rule: str, name: str):
    """The value converted to `kind`, or InputError('<name> must ...'); `name` says where."""
    if kind is str:
        if not isinstance(value, str):
            raise InputError(f"{name} must be a string, got {describe(value)}")
        if not value.strip():
            raise InputError(f"{name} must not be empty")
        return value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(f"{name} must be {_TOML_TYPE[kind]}, got {describe(value)}")
    if kind is int:
        if not isinstance(value, numbers.Integral):
            raise InputError(f"{name} must be an integer, got {describe(value)}")
    else:
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f"{name} must be finite, got {value!r}")
        lo, hi = MAGNITUDE
        if value != 0 and not lo <= abs(value) <= hi:
            raise InputError(f"{name} must be 0 or of magnitude {lo:g} to {hi:g}, got {value!r}")
    if rule == "> 0" and not value > 0:
        raise InputError(f"{name} must be > 0, got {value!r}")
    if rule == ">= 0" and not value >= 0:
        raise InputError(f"{name} must be >= 0, got {value!r}")
    if rule == ">= 1" and not value >= 1:
        raise InputError(f"{name} must be >= 1, got {value!r}")
    return value


# -- the limits of a run: one validator for palpate, sweep and bench -------------------------------
LIMITS = {
    "duration_s": 1.0e6,
    "steps": 10_000_000,
    "substeps": 64,
    "points": 10_000_000,
    "batch": 1_000_000,
    "region_steps": 2.0e9,
    "lesion_factor": 1.0e6,
}
"""The largest value each part of a run may take; beyond it the input is a typo, not a run to wait for.

duration_s: a ramp, hold or settle window [s]. steps: the frames of one run (every press together:
a hundred minutes at a few us a step). substeps: explicit steps in one frame before the run falls
back to the implicit integrator. points: a sweep's contacts. batch: palpations in one batch.
region_steps: a sweep's points x frames x substeps, unless the user raises it (--max-region-steps).
lesion_factor: how much stiffer a lesion may be (past it float32 stiffness and the critical step
lose their meaning)."""


_LIMIT_WORDS = {"duration_s": "duration [s]", "lesion_factor": "lesion stiffness factor", "region_steps": "region-steps"}


def check_fields(params, keys: dict) -> None:
    """Check every float field of a parameter dataclass against the rule its scene-file key gives
    (`keys`: key -> (attribute, type, file units per SI unit, rule)); InputError naming the first bad one."""
    from dataclasses import fields

    rules = {attr: rule for attr, _kind, _factor, rule in keys.values()}
    for f in fields(params):
        check_value(getattr(params, f.name), float, rules[f.name], f"{type(params).__name__}.{f.name}")


def check_limit(value, key: str, flag: str) -> None:
    """InputError('<flag> <value> is more than the largest <key> (<limit>)') past LIMITS[key]."""
    limit = LIMITS[key]
    if not value <= limit:
        what = _LIMIT_WORDS.get(key, key)
        raise InputError(f"{flag} {value:g} is more than the largest {what} a run takes ({limit:,g}); "
                         f"it is most likely a typo or a unit mix-up")


def check_ring_count(rings, vertex_count: int, flag: str) -> None:
    """An integer ring count no larger than the mesh's vertex count (a larger region is the whole mesh)."""
    if isinstance(rings, int) and rings > vertex_count:
        raise InputError(f"{flag} {rings} is more than the mesh's {vertex_count} vertices; "
                         f"a region that large is the whole mesh: use --rings global")


def check_protocol(depth, dt, ramp, hold, settle, presses, extent) -> int:
    """A press the simulator can run: depth within the organ's `extent` [m], each duration within
    LIMITS, dt no longer than the ramp or the settle window, and no more than LIMITS["steps"] frames
    in all (floats first: 1e300 / 1e-300 is inf). Returns the frames of one press."""
    if not dt > 0:
        raise InputError(f"dt must be > 0, got {dt!r} s (--dt-ms underflows)")
    for name, value, flag in (("ramp", ramp, "--ramp-s"), ("hold", hold, "--hold-s"), ("settle window", settle, "--settle-s")):
        check_limit(value, "duration_s", flag)
    if depth > extent:
        raise InputError(f"press depth {depth * 1e3:g} mm is more than the mesh's extent ({extent * 1e3:.4g} mm): "
                         f"the probe would go through the organ")
    for name, value, flag in (("ramp", ramp, "--ramp-s"), ("settle window", settle, "--settle-s")):
        if value > 0 and dt > value:
            raise InputError(f"dt {dt * 1e3:g} ms is longer than the {name} ({value:g} s): the press would not be "
                             f"resolved; use a smaller --dt-ms or a longer {flag}")
    per_press = max(ramp / dt, 1.0) + hold / dt + max(settle / dt, 1.0)
    steps = presses * per_press
    if not steps <= LIMITS["steps"]:
        raise InputError(f"the run would take {steps:.3g} steps ({presses} x (ramp {ramp:g} s + hold {hold:g} s + "
                         f"settle {settle:g} s) at dt {dt * 1e3:g} ms), more than the {LIMITS['steps']:,} a run may take; "
                         f"use a larger --dt-ms or shorter times")
    return int(per_press)


def substeps_for(dt: float, critical: float, safety: float = 0.9) -> int:
    """Explicit steps in one frame of `dt` [s] that keep each under `safety` x the `critical` step [s]."""
    if not math.isfinite(critical):
        return 1
    if not critical > 0:
        return LIMITS["substeps"] + 1
    n = dt / (safety * critical)
    return max(1, math.ceil(n)) if n <= LIMITS["substeps"] else LIMITS["substeps"] + 1


def check_region_steps(points: int, frames: int, substeps: int, limit: float, flag: str = "--max-region-steps") -> float:
    """A sweep's cost, points x frames x substeps region-steps [-], or InputError past `limit`."""
    cost = float(points) * frames * substeps
    if not cost <= limit:
        raise InputError(f"the sweep would take {cost:.3g} region-steps ({points} points x {frames} frames x {substeps} "
                         f"substep(s)), more than the {limit:.3g} allowed; give {flag} {cost:.2g} to run it anyway, "
                         f"or fewer points, shorter times or a larger --dt-ms")
    return cost


def fixed_substeps(substeps):
    """`substeps` of Palpation and BatchPalpation: None for "auto", else an int >= 1 (ValueError otherwise)."""
    if substeps == AUTO:
        return None
    if isinstance(substeps, bool) or not isinstance(substeps, numbers.Integral) or substeps < 1:
        raise ValueError(f"substeps must be {AUTO!r} or an int >= 1, got {substeps!r}")
    return int(substeps)


def rings_text(rings) -> str:
    """"1 ring", "4 rings", "auto rings", "global": a ring count in words."""
    if isinstance(rings, (int, np.integer)) and not isinstance(rings, bool):
        return f"{int(rings)} ring{'' if rings == 1 else 's'}"
    return f"{rings} rings" if rings == AUTO else str(rings)
