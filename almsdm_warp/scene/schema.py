"""The schema of a scene file: sections, keys, units and rules (the checks: almsdm_warp.checks).

Every problem is an InputError with one line; almsdm_warp.scene adds the file's path.
"""

from __future__ import annotations

from ..protocol.schedule import PRESS_KEYS
from ..tissue.material import MATERIAL_KEYS
from ..tissue.params import TISSUE_KEYS

TISSUE_MODELS: dict[str, dict[str, tuple[str, type, float, str]]] = {"paper": TISSUE_KEYS, "material": MATERIAL_KEYS}
"""[tissue] model -> the keys it takes: the paper's per-spring constants (TissueParams, the default)
or a material whose springs are derived per edge (Material)."""
DEFAULT_TISSUE_MODEL = "paper"


# -- the schema ------------------------------------------------------------------------------
# section -> key -> (attribute, type, file units per SI unit (1000 for mm), rule)
# rules: "path" (or any non-empty string), "> 0", ">= 0", ">= 1" (integers), "number" (any finite)
SCHEMA: dict[str, dict[str, tuple[str, type, float, str]]] = {
    "mesh": {
        "path": ("path", str, 1.0, "path"),
        "scale_mm": ("scale_mm", float, 1.0, "> 0"),
        "volume": ("volume", str, 1.0, "path"),  # "off" or "auto" (mesh.volume.VOLUME_CHOICES)
    },
    "tissue": {"model": ("model", str, 1.0, "path"), "law": ("law", str, 1.0, "path"),  # law: tissue.laws.LAWS
               "wall": ("wall", str, 1.0, "path"),  # a surface's wall: "membrane" or "tets" (tissue.wall.WALL_CHOICES)
               **TISSUE_KEYS, **MATERIAL_KEYS},  # per model: TISSUE_MODELS
    "region": {
        "rings": ("rings", int, 1.0, ">= 1"),  # or the string "auto"
        "tol_mm": ("tol", float, 1000.0, "> 0"),  # only with rings = "auto"
    },
    "press": PRESS_KEYS,
    "support": {
        "fixed_below_mm": ("fixed_below", float, 1000.0, "number"),  # vertices with z below it are fixed
        "rule": ("support", str, 1.0, "path"),  # or relative to the organ: scene.support.RULES (--support)
    },
    "probe": {
        "radius_mm": ("probe_radius", float, 1000.0, ">= 0"),  # 0: the paper's probe, one driven vertex
    },
}
"""Every section and key a scene file may hold: attribute, type, file units per SI unit, rule."""

FIELD_RULE = {(section, attr): rule for section, keys in SCHEMA.items() for attr, _k, _f, rule in keys.values()}
"""(section, attribute) -> rule, for the parameter classes' own checks."""

