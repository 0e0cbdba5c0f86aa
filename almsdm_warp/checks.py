"""Checks of the values a user gives (scene files, parameter classes): one line each, naming where.

Every problem is an InputError whose message starts with the `name` it was given
(``[tissue] thickness_mm``, ``TissueParams.density``); a scene loader adds the file's path.
Rules: "path" (a non-empty string), "> 0", ">= 0", ">= 1" (integers).
"""

from __future__ import annotations

import math

from .errors import InputError

MAGNITUDE = (1.0e-12, 1.0e12)
"""A number in a scene is 0 (where allowed) or of magnitude within these bounds, in the file's units
as in SI: products of such values stay far inside float32 (the device's), no tissue is outside
them, and a value outside them is a typo or a unit mix-up."""

AUTO = "auto"
"""[region] rings = "auto": the region sized to [region] tol_mm during each press (docs/adaptive.md)."""

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
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{name} must be {_TOML_TYPE[kind]}, got {describe(value)}")
    if kind is int:
        if not isinstance(value, int):
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
