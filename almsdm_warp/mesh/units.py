"""The unit of a mesh file, guessed from its size: an organ spans a few centimetres to a few decimetres.

A mesh file carries no unit. Read in millimetres (the default), a liver that spans 6.5 file units is
a 6.5 mm organ, which no 10 mm press fits: the file is in centimetres. `guess_scale` picks the first
of millimetres, centimetres, metres and micrometres that puts the mesh's largest extent within
ORGAN_SPAN_MM, and says so in one line.
"""

from __future__ import annotations

import numpy as np

ORGAN_SPAN_MM = (15.0, 2000.0)
"""An organ's largest extent lies between these [mm]: a 12.8 mm "organ" is one of 12.8 cm."""
UNITS = ((1.0, "millimetres"), (10.0, "centimetres"), (1000.0, "metres"), (1.0e-3, "micrometres"))
"""(millimetres per file unit, its name), in the order they are tried."""


def mesh_span(vertices) -> float:
    """The largest extent of `vertices` along x, y or z (in their own units); 0 for none."""
    v = np.asarray(vertices, dtype=np.float64)
    return float(np.ptp(v, axis=0).max()) if len(v) else 0.0


def is_organ_size(span_mm: float) -> bool:
    """Whether a largest extent of `span_mm` [mm] is an organ's (within ORGAN_SPAN_MM)."""
    lo, hi = ORGAN_SPAN_MM
    return lo <= span_mm <= hi


def guess_scale(span: float) -> tuple[float, str]:
    """(millimetres per file unit, one line saying why) for a mesh of largest extent `span` file units:
    the first of UNITS that makes it an organ's size, or 1 (millimetres) where none does."""
    lo, hi = ORGAN_SPAN_MM
    for scale, name in UNITS:
        if is_organ_size(span * scale):
            how = "" if scale == 1.0 else f" (x{scale:g} mm a file unit)"
            return scale, (f"read in {name}{how}, guessed from its size: {span:.4g} file units across, a "
                           f"{span * scale:.4g} mm organ; --scale-mm sets the unit")
    return 1.0, (f"read in millimetres, though it spans {span:.4g} file units: no unit makes it an organ's size "
                 f"({lo:g}-{hi:g} mm); --scale-mm sets the unit")
