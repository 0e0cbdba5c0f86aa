"""--volume auto|off: a closed surface given for a volumetric tissue law is tetrahedralized
(mesh/volume.py), finest at the press; off (the default) keeps the mesh as it is read."""

from __future__ import annotations

import math

VOLUME_CHOICES = ("off", "auto")


def add_volume_arg(parser) -> None:
    """--volume (palpate)."""
    parser.add_argument("--volume", choices=VOLUME_CHOICES, default="off",
                        help="auto: a closed surface with a material tissue and a volumetric law is tetrahedralized "
                             "(fTetWild, the volume extra; edges <= 0.45 x the contact radius at the press); default off")


def needs_volume(choice: str, mesh, tissue, law: str | None = None) -> bool:
    """Whether --volume `choice` makes `mesh` a volume: auto, a surface mesh, a Material and a
    volumetric law (tissue/laws.py; None: the law a volume would get, default_law)."""
    from ..tissue.laws import LAWS, default_law
    from ..tissue.material import Material

    law = default_law(True, tissue) if law is None else law
    return (choice == "auto" and not mesh.is_volume and isinstance(tissue, Material)
            and law in LAWS and LAWS[law].volumetric)


def volume_for_press(mesh, point, probe_radius: float, depth: float):
    """The surface `mesh` tetrahedralized with the resolved edge near `point` [m] for a sphere of
    `probe_radius` [m] pressed `depth` [m] (a uniform edge for the paper's probe, radius 0)."""
    from ..mesh.volume import contact_edge, tetrahedralize

    if probe_radius > 0.0 and depth > 0.0 and math.isfinite(probe_radius):
        return tetrahedralize(mesh, near=point, near_edge=contact_edge(probe_radius, depth))
    return tetrahedralize(mesh)
