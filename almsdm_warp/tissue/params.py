"""The tissue's mass, spring and damper parameters (SI units) and their scene-file keys."""

from __future__ import annotations

from dataclasses import dataclass

from ..checks import check_fields

TISSUE_KEYS: dict[str, tuple[str, type, float, str]] = {
    "density_kg_per_m3": ("density", float, 1.0, "> 0"),
    "thickness_mm": ("thickness", float, 1000.0, "> 0"),
    "edge_stiffness_N_per_m": ("edge_stiffness", float, 1.0, "> 0"),
    "edge_damping_Ns_per_m": ("edge_damping", float, 1.0, ">= 0"),
    "anchor_stiffness_N_per_m": ("anchor_stiffness", float, 1.0, ">= 0"),
    "anchor_damping_Ns_per_m": ("anchor_damping", float, 1.0, ">= 0"),
}
"""The [tissue] section of a scene file: key -> (attribute, type, file units per SI unit, rule)."""


@dataclass(frozen=True)
class TissueParams:
    """Mass, spring and damper parameters of the tissue, in SI units.

    The defaults are the stomach scene's, calibrated so that a 10 mm press with 4 rings gives the
    paper's feedback force (about 2.4 N, Table 1) and the explicit scheme is stable at dt = 1 ms
    (docs/calibration.md).
    """

    density: float = 1000.0
    """Tissue density [kg/m^3], for the lumped vertex masses."""
    thickness: float = 25.0e-3
    """Shell thickness [m] of a surface mesh, for its lumped masses (area x thickness x density);
    ignored for a tet mesh, whose masses come from the tet volumes."""
    edge_stiffness: float = 62.0
    """k_ij [N/m]: stiffness of the spring on each mesh edge, eqs. (4)-(6)."""
    edge_damping: float = 0.02
    """d_ij [N s/m]: damping along each mesh edge, eqs. (4)-(6)."""
    anchor_stiffness: float = 124.0
    """k_i [N/m]: stiffness of the spring that pulls each vertex back to its rest position, eq. (3)."""
    anchor_damping: float = 0.1
    """d_i [N s/m]: damping of each vertex's velocity, eq. (3)."""

    def __post_init__(self):
        check_fields(self, TISSUE_KEYS)
