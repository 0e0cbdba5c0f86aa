"""Hertz's closed form for a frictionless elastic contact of spheres (SI units).

A rigid sphere of radius R1 pressed to depth d into an elastic half-space (R2 = inf) or into an
elastic sphere of radius R2: the contact is a disc of radius a = sqrt(R_eff d) and the force is
F = 4/3 E* sqrt(R_eff) d^(3/2), with R_eff = R1 R2 / (R1 + R2) and E* = E / (1 - nu^2) for a rigid
indenter. Valid for small strain and a >> mesh size, a << the bodies (Johnson, Contact Mechanics, 4.2).
"""

from __future__ import annotations

import math


def effective_radius(radius1: float, radius2: float = math.inf) -> float:
    """R_eff = R1 R2 / (R1 + R2) [m]; R2 = inf (a half-space) gives R1."""
    if radius1 <= 0 or radius2 <= 0:
        raise ValueError(f"radii must be positive, got {radius1} and {radius2}")
    return radius1 if math.isinf(radius2) else radius1 * radius2 / (radius1 + radius2)


def effective_modulus(young: float, poisson: float) -> float:
    """E* = E / (1 - nu^2) [Pa] of an elastic body against a rigid one."""
    if young <= 0 or not -1.0 < poisson < 0.5:
        raise ValueError(f"need E > 0 and -1 < nu < 0.5, got E={young}, nu={poisson}")
    return young / (1.0 - poisson * poisson)


def hertz_force(young: float, poisson: float, radius1: float, depth: float, radius2: float = math.inf) -> float:
    """Contact force [N] of a rigid sphere (radius1 [m]) pressed `depth` [m] into the body."""
    r_eff = effective_radius(radius1, radius2)
    return 4.0 / 3.0 * effective_modulus(young, poisson) * math.sqrt(r_eff) * max(depth, 0.0) ** 1.5


def hertz_contact_radius(radius1: float, depth: float, radius2: float = math.inf) -> float:
    """Radius [m] of the contact disc, a = sqrt(R_eff d)."""
    return math.sqrt(effective_radius(radius1, radius2) * max(depth, 0.0))
