"""The schema of a scene file (sections, keys, units, rules) and the checks of its values.

Every problem is an InputError with one line; almsdm_warp.scene adds the file's path.
"""

from __future__ import annotations

import math

from ..errors import InputError


# -- the schema ------------------------------------------------------------------------------
# section -> key -> (attribute, type, file units per SI unit (1000 for mm), rule)
# rules: "path", "> 0", ">= 0", ">= 1" (integers)
SCHEMA: dict[str, dict[str, tuple[str, type, float, str]]] = {
    "mesh": {
        "path": ("path", str, 1.0, "path"),
        "scale_mm": ("scale_mm", float, 1.0, "> 0"),
    },
    "tissue": {
        "density_kg_per_m3": ("density", float, 1.0, "> 0"),
        "thickness_mm": ("thickness", float, 1000.0, "> 0"),
        "edge_stiffness_N_per_m": ("edge_stiffness", float, 1.0, "> 0"),
        "edge_damping_Ns_per_m": ("edge_damping", float, 1.0, ">= 0"),
        "anchor_stiffness_N_per_m": ("anchor_stiffness", float, 1.0, ">= 0"),
        "anchor_damping_Ns_per_m": ("anchor_damping", float, 1.0, ">= 0"),
    },
    "region": {
        "rings": ("rings", int, 1.0, ">= 1"),  # or the string "auto"
        "tol_mm": ("tol", float, 1000.0, "> 0"),  # only with rings = "auto"
    },
    "press": {
        "depth_mm": ("depth", float, 1000.0, "> 0"),
        "ramp_s": ("ramp", float, 1.0, "> 0"),
        "hold_s": ("hold", float, 1.0, ">= 0"),
        "settle_s": ("settle", float, 1.0, "> 0"),
    },
}
"""Every section and key a scene file may hold: attribute, type, file units per SI unit, rule."""

MAGNITUDE = (1.0e-12, 1.0e12)
"""A number in a scene is 0 (where allowed) or of magnitude within these bounds, in the file's units
as in SI: products of such values stay far inside float32 (the device's), no tissue is outside
them, and a value outside them is a typo or a unit mix-up."""

AUTO = "auto"
"""[region] rings = "auto": the region sized to [region] tol_mm during each press (docs/adaptive.md)."""

_FIELD_RULE = {(section, attr): rule for section, keys in SCHEMA.items() for attr, _k, _f, rule in keys.values()}
_TOML_TYPE = {str: "a string", float: "a number", int: "an integer"}


def _describe(value) -> str:
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


def _check_rings(value, name: str):
    """[region] rings: an integer >= 1 or the string "auto"."""
    if isinstance(value, str):
        if value != AUTO:
            raise InputError(f"{name} must be an integer >= 1 or {AUTO!r}, got {_describe(value)}")
        return value
    return _check_value(value, int, ">= 1", name)


def _check_value(value, kind: type, rule: str, name: str):
    """The value converted to `kind`, or InputError('<name> must ...'); `name` says where."""
    if kind is str:
        if not isinstance(value, str):
            raise InputError(f"{name} must be a string, got {_describe(value)}")
        if not value.strip():
            raise InputError(f"{name} must not be empty")
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(f"{name} must be {_TOML_TYPE[kind]}, got {_describe(value)}")
    if kind is int:
        if not isinstance(value, int):
            raise InputError(f"{name} must be an integer, got {_describe(value)}")
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


# -- loading ---------------------------------------------------------------------------------
