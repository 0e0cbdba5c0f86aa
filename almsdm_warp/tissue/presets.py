"""Named tissue presets: a material from the literature (docs/calibration.md), the probe that presses
it and the region it is simulated on, for a bare mesh given with no scene (``--tissue NAME``).

A preset holds what a scene's [tissue], [probe] and [region] tables hold. On a tet volume the material
is the organ's body; on a surface its wall (``thickness``) on a Winkler foundation (``foundation``):
the same table serves both. The tissue law is not a preset's: the scene's default law applies.
``paper`` is the paper's per-spring constants and one-vertex probe (the scenes ``paper_stomach`` and
``paper_liver``), only on request.
"""

from __future__ import annotations

from dataclasses import dataclass

from .material import Material
from .params import TissueParams


@dataclass(frozen=True)
class TissuePreset:
    """A named tissue: its parameters, the probe's radius [m] and the region's rings."""

    name: str
    tissue: Material | TissueParams
    """A Material (every spring derived from it) or the paper's per-spring constants."""
    probe_radius: float
    """Radius of the spherical probe [m]; 0: the paper's one-vertex probe."""
    rings: int | str
    """Rings of the local region, or "auto" (sized to a tolerance during each press)."""
    about: str
    """One line: where the values come from."""

    @property
    def supported(self) -> bool:
        """Whether a tet volume of this tissue needs a support (a material has no anchors on tets)."""
        return isinstance(self.tissue, Material)


FINGERTIP = 10.0e-3
"""The presets' probe: a 10 mm rigid sphere, a fingertip [m]."""
WALL = dict(thickness=3.0e-3, foundation=0.1e6, rayleigh_alpha=60.0)
"""On a surface: a 3 mm wall on a 0.1 kPa/mm Winkler foundation (the contents and organs behind it),
Rayleigh mass damping 60 /s (docs/calibration.md, "The default scenes on a material")."""

PRESETS = {
    "liver": TissuePreset("liver", Material(5.2e3, 0.45, 1060.0, **WALL), FINGERTIP, "auto",
                          "liver: E 5.2 kPa (shear modulus 1.8 kPa), nu 0.45, rho 1060 kg/m^3"),
    "stomach": TissuePreset("stomach", Material(1.85e3, 0.45, 1058.0, **WALL), FINGERTIP, "auto",
                            "stomach: E 1.85 kPa (shear modulus 0.637 kPa), nu 0.45, rho 1058 kg/m^3"),
    "paper": TissuePreset("paper", TissueParams(), 0.0, 4,
                          "the paper's per-spring constants (k_ij 62 N/m, k_i 124 N/m) and one-vertex probe"),
}
"""Preset name -> preset. Values and sources: docs/calibration.md, "Literature values for liver and stomach"."""

DEFAULT_PRESET = "liver"
"""The preset a bare mesh gets when none is named: a solid organ's parenchyma."""


def tissue_preset(name: str) -> TissuePreset:
    """The preset `name`; ValueError naming the known ones for any other."""
    try:
        return PRESETS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown tissue preset {name!r} (known: {', '.join(PRESETS)})") from None
