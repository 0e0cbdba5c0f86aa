"""Supports given relative to the organ (``--support``): what holds a body of tissue while it is pressed.

A tet volume on a material has no anchors (a foundation acts on a surface): with no support only the
local region's fixed outer ring holds it, and a lobe swings on that ring after a press
(docs/calibration.md, "A tet liver with nothing under it"). The rules below turn a support given in
words into the height of the support plane (vertices below it fixed: Model's ``fixed_below``), so that
every command (palpate, sweep, trace) holds the same vertices for the same scene and press:

- ``far-side``: the organ held on the far side of a press from above, every vertex lower than
  FAR_SIDE of the way from the organ's bottom to the contact;
- ``below:FRACTION``: every vertex in the lowest FRACTION of the organ's height;
- ``none``: nothing (the tissue's own anchors or foundation, the region's fixed ring).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

FAR_SIDE = 0.3
"""far-side: the fraction of the height from the organ's bottom to the contact that is held (the shipped
liver scene holds the lowest 28% of its 89 mm: docs/calibration.md)."""
RULES = ("far-side", "below:FRACTION", "none")
"""The --support rules, as --help names them."""


def parse_support(text: str) -> str:
    """`text` if it is a support rule (RULES; FRACTION a number in [0, 1)), else InputError naming them."""
    if text in ("far-side", "none"):
        return text
    if isinstance(text, str) and text.startswith("below:"):
        try:
            fraction = float(text.removeprefix("below:"))
        except ValueError:
            fraction = math.nan
        if 0.0 <= fraction < 1.0:
            return f"below:{fraction:g}"
        raise InputError(f"support {text!r}: FRACTION must be a number in [0, 1) (below:0.3 holds the lowest 30% of the organ)")
    raise InputError(f"unknown support {text!r} (allowed: {', '.join(RULES)})")


def support_height(rule: str, vertices, contact_z: float) -> float | None:
    """The support plane's height [m] for `rule` on a body of `vertices` [m] pressed from above at a
    contact of height `contact_z` [m] (vertices below it are fixed), or None for "none"."""
    rule = parse_support(rule)
    if rule == "none":
        return None
    z = np.asarray(vertices, dtype=np.float64)[:, 2]
    bottom = float(z.min())
    if rule == "far-side":
        return bottom + FAR_SIDE * (float(contact_z) - bottom)
    return bottom + float(rule.removeprefix("below:")) * (float(z.max()) - bottom)


def describe_support(rule: str | None, fixed_below: float | None) -> str:
    """A few words: "far-side (fixed below z = -12.3 mm)", "fixed below z = -20 mm", "none"."""
    plane = f"fixed below z = {fixed_below * 1e3:.4g} mm" if fixed_below is not None else ""
    if rule in (None, "none"):
        return plane or "none"
    return f"{rule} ({plane})" if plane else rule
