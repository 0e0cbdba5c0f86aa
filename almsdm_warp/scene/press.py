"""A scene's palpation, made one way for the command line and for Python: `palpation(source)` presses what
`almsdm palpate SOURCE` presses (the same tissue preset, sphere, rings, support and contact).

    import almsdm_warp as am
    pal = am.palpation("organ.stl")             # the default preset, its sphere, auto rings, a support
    result = pal.press(0.01, 0.1, 0.2, 1.0)     # depth [m], ramp, hold, settle [s]
    print(result.peak_force_N, result.recovery_error_mm)
"""

from __future__ import annotations

from dataclasses import replace

from ..errors import InputError
from .loader import Scene, resolve_scene_or_mesh


def build_palpation(scene: Scene, mesh, *, rings=None, tol: float | None = None, integrator: str = "explicit",
                    dt: float = 1e-3, device=None, probe_radius: float | None = None, capture: bool = True):
    """The palpation of `scene` on `mesh` (its tissue, law, lesion, support and probe; `rings` and
    `probe_radius` [m] override the scene's): an AdaptivePalpation sized to `tol` [m] (default: the
    scene's, else AdaptivePalpation's) for rings "auto", a Palpation otherwise. Not touched yet."""
    from ..protocol.adaptive import AdaptivePalpation
    from ..protocol.palpation import Palpation

    rings = scene.rings if rings is None else rings
    radius = scene.probe_radius if probe_radius is None else probe_radius
    scales = scene.lesion.model_scales(mesh, scene.tissue, scene.law) if scene.lesion is not None else {}
    kw = dict(integrator=integrator, dt=dt, device=device, probe_radius=radius, law=scene.law, fixed_below=scene.fixed_below,
              capture=capture, **scales)
    if rings == "auto":
        tol = scene.tol if tol is None else tol
        return AdaptivePalpation(mesh, scene.tissue, **({} if tol is None else {"tol": tol}), **kw)
    return Palpation(mesh, scene.tissue, rings=rings, **kw)


def palpation(source=None, *, tissue: str | None = None, support: str | None = None, scale_mm: float | None = None,
              vertex: int | None = None, **options):
    """The palpation `almsdm palpate SOURCE` presses, touched at its contact (`vertex`, default the top of
    the organ): `source` a scene name, a scene file or a mesh file (None: the default scene). A mesh file
    takes the tissue preset `tissue` (tissue.presets, default DEFAULT_PRESET) with its sphere and rings,
    its unit guessed from its size unless `scale_mm` is given, and a support chosen from the mesh (on a
    tet volume of a material, its far side) unless `support` ("far-side", "below:FRACTION", "none") names
    one; `tissue` on a scene file replaces its material. `options`: build_palpation's (rings, tol,
    integrator, dt, device, probe_radius). Raises InputError for a bad source or value."""
    from ..region.contact import top_vertex
    from ..tissue.presets import tissue_preset

    scene = resolve_scene_or_mesh(source, scale_mm=1.0 if scale_mm is None else scale_mm, tissue=tissue)
    if scale_mm is None:
        scene, mesh, _line = scene.load_mesh_guessing_units()
    else:
        mesh = scene.load_mesh()
    if tissue is not None and scene.preset != tissue:
        try:
            scene = replace(scene, tissue=tissue_preset(tissue).tissue, preset=tissue)
        except ValueError as exc:
            raise InputError(str(exc)) from None
    if support is not None:
        scene = replace(scene, support=support, fixed_below=None)
    vertex = top_vertex(mesh) if vertex is None else int(vertex)
    scene, mesh, vertex = _on_tets(scene, mesh, vertex, options.get("probe_radius"))
    scene = scene.with_support(mesh, float(mesh.vertices[vertex, 2]))
    pal = build_palpation(scene, mesh, **options)
    radius = pal.probe_radius
    pal.touch(vertex, scene.press.depth if radius > 0 else None)
    pal.scene = scene
    return pal


def _on_tets(scene: Scene, mesh, vertex: int, probe_radius: float | None):
    """(scene, mesh, vertex): the surface made tets where the scene's [mesh] volume or [tissue] wall asks
    (scene/volume.py), finest at `vertex` for the scene's press, and the contact the nearest surface vertex
    of the tets; else as given."""
    import numpy as np

    from .volume import make_tets, snap_to, tets_wanted

    kind = tets_wanted(scene, mesh)
    if kind is None:
        return scene, mesh, vertex
    point = mesh.vertices[vertex]
    radius = scene.probe_radius if probe_radius is None else probe_radius
    tets = make_tets(kind, scene, mesh, point, radius, scene.press.depth)
    return scene, tets, int(snap_to(tets, np.asarray([point]))[1][0])

