"""--volume auto|off and --wall membrane|tets: a surface given for a volumetric tissue law made tets where it
is pressed (the rule: scene/volume.py; the meshers: mesh/volume.py, tissue/wall.py). palpate, sweep and trace
take both; a scene says [mesh] volume and [tissue] wall, a dataset spec [dataset] volume."""

from __future__ import annotations

import numpy as np

from ..mesh.volume import VOLUME_CHOICES
from ..scene.volume import make_tets, needs_volume, tets_wanted  # noqa: F401  (needs_volume: cli/args.py, tests)
from ..tissue.wall import WALL_CHOICES


def add_volume_arg(parser) -> None:
    """--volume and --wall (palpate, sweep, trace)."""
    parser.add_argument("--volume", choices=VOLUME_CHOICES, default=None,
                        help="auto: a closed surface with a material tissue and a volumetric law is tetrahedralized (fTetWild, "
                             "the volume extra; edges <= 0.45 x the contact radius where it is pressed, coarser away); "
                             "off: the mesh as read (default: the scene's [mesh] volume, else off)")
    parser.add_argument("--wall", choices=WALL_CHOICES, default=None,
                        help="a surface of a material with --thickness-mm: a membrane on a foundation (springs), or a wall "
                             "of tets that thick, its inner surface free, for a volumetric law (default: the scene's [tissue] "
                             "wall, else membrane)")


def tets_for(args, scene, mesh) -> str | None:
    """"wall", "volume" or None: what --volume, --wall (else the scene's keys) make of `mesh` (tets_wanted)."""
    return tets_wanted(scene, mesh, getattr(args, "volume", None), getattr(args, "wall", None))


def on_tets(args, scene0, kind, scene, mesh, near, probe_radius: float, depth: float):
    """(scene, tets): `mesh` made tets as `kind` for presses at `near` [m], then the scene's flags applied again on
    them (args.scene_with_tissue_args: the support resolved as for a tet mesh); the mesher's notes printed."""
    from .args import print_notes, scene_with_tissue_args

    tets = make_tets(kind, scene, mesh, near, probe_radius, depth)
    print_notes(tets)
    return scene_with_tissue_args(args, scene0, tets), tets


def path_contacts(mesh, centres, probe_radius: float):
    """(contacts [k, 3], depth [m]) of a sphere of `probe_radius` [m] moved along `centres` [n, 3] over `mesh` at
    rest: the closest surface points of the centres that touch it (their clearance along the surface's normal
    under the radius), sampled every radius / 8 along the path, and the deepest press among them (0: no touch)."""
    from ..protocol.stroke import RestSurface

    centres = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(centres, axis=0), axis=1))])
    keep = np.unique(np.concatenate([np.searchsorted(arc, np.arange(0.0, arc[-1], probe_radius / 8.0)), [len(arc) - 1]]))
    sample = centres[keep]
    closest, normal = RestSurface(mesh).project(sample)
    press = probe_radius - np.einsum("ij,ij->i", sample - closest, normal)
    touch = press > 0.0
    return closest[touch], float(press[touch].max(initial=0.0))
