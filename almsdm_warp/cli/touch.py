"""`almsdm touch`: touch a scene or mesh with the probe and print the ring regions at the contact."""

from __future__ import annotations

import time

import numpy as np

from ..errors import InputError
from ..tissue.presets import PRESETS
from .args import (add_probe_radius_arg, auto_tol, check_contact, get_device, load_scene_and_mesh, mesh_json, number_arg, path_arg,
                   probe_position, quiet_warp, rings_arg, rings_text, scene_with_tissue_args)


def add_parser(sub) -> None:
    touch = sub.add_parser("touch", help="touch a scene or mesh with the probe and print the ring region")
    touch.add_argument("scene", nargs="?", default=None, type=path_arg, metavar="MESH_OR_SCENE", help="scene (.toml), scene name or mesh file; default: the stomach scene")
    touch.add_argument("--rings", type=rings_arg(("auto",)), default=None, metavar="{N,auto}", help="rings to grow (default: the scene's); auto: the rings an adaptive press grows to (as palpate's)")
    touch.add_argument("--tol-mm", type=number_arg("> 0"), default=None, metavar="MM", help="--rings auto: the displacement tolerance [mm] (default: the scene's, else 0.1)")
    touch.add_argument("--probe-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="probe position [mm]")
    add_probe_radius_arg(touch)
    touch.add_argument("--tissue", choices=tuple(PRESETS), default=None, help="a mesh file's tissue preset, whose sphere and rings it takes (default: liver)")
    touch.add_argument("--scale-mm", type=number_arg("> 0"), default=None, metavar="MM", help="millimetres per mesh file unit, for a mesh file (default: guessed from its size)")
    touch.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ...")
    touch.add_argument("--json", default=None, type=path_arg, help="write the result as JSON here")
    touch.set_defaults(func=cmd_touch)


def cmd_touch(args) -> int:
    """Load a scene or mesh, touch it with the probe, build the ring region and print it."""
    from ..export.writers import check_output, write_output
    from ..region.contact import find_contacts
    from ..region.region import Region

    if args.json:
        check_output(args.json, "record", "--json")
    quiet_warp()
    scene0, mesh = load_scene_and_mesh(args)
    scene = scene_with_tissue_args(args, scene0, mesh)
    device = get_device(args.device)
    scene, mesh = _on_tets(args, scene0, scene, mesh, device)
    print(mesh.summary())

    probe = _probe(args, mesh)
    contact = find_contacts(mesh, probe, device=device)
    check_contact(contact, probe, mesh)
    print(
        f"probe at {np.round(probe * 1e3, 2).tolist()} mm touches face {contact.face} at "
        f"{np.round(contact.point * 1e3, 2).tolist()} mm ({contact.distance * 1e3:.2f} mm away); "
        f"nearest vertex {contact.vertex}"
    )
    radius = scene.probe_radius if args.probe_radius_mm is None else args.probe_radius_mm * 1e-3
    vertex, depth = int(contact.vertex), scene.press.depth
    rings = scene.rings if args.rings is None else args.rings
    tol = auto_tol(args, rings, scene)
    if tol is not None:
        rings = _auto_rings(scene, mesh, vertex, tol, radius)
    seeds = _patch(mesh, vertex, radius, depth)
    if radius > 0:
        print(f"a {radius * 1e3:g} mm sphere pressed {depth * 1e3:g} mm covers {len(seeds)} surface vertices: ring 0")
    rows = _grow(Region(mesh, device), vertex, seeds, rings)
    if args.json:
        write_output(
            args.json,
            {
                "mesh": mesh_json(mesh),
                "device": str(device),
                "probe_mm": (probe * 1e3).tolist(),
                "contact": {
                    "point_mm": (contact.point * 1e3).tolist(),
                    "face": int(contact.face),
                    "vertex": int(contact.vertex),
                    "distance_mm": float(contact.distance * 1e3),
                },
                "regions": rows,
            },
            "record",
        )
        print(f"wrote {args.json}")
    return 0


def _on_tets(args, scene0, scene, mesh, device):
    """(scene, mesh): the scene's surface made tets where its [mesh] volume or [tissue] wall asks (as palpate's
    --volume and --wall, scene/volume.py), finest at the probe's contact for the scene's press; else as given."""
    from ..region.contact import find_contacts
    from .volume_arg import on_tets, tets_for

    kind = tets_for(args, scene, mesh)
    if kind is None:
        return scene, mesh
    contact = find_contacts(mesh, _probe(args, mesh), device=device)
    check_contact(contact, _probe(args, mesh), mesh)
    radius = scene.probe_radius if args.probe_radius_mm is None else args.probe_radius_mm * 1e-3
    return on_tets(args, scene0, kind, scene, mesh, np.asarray(contact.point), radius, scene.press.depth)


def _probe(args, mesh) -> np.ndarray:
    """--probe-mm, else 5 mm above the highest surface vertex (a press from the top) [m]."""
    from ..region.contact import top_vertex

    if args.probe_mm is not None:
        return probe_position(args.probe_mm)
    return mesh.vertices[top_vertex(mesh)] + np.array([0.0, 0.0, 5e-3])


def _patch(mesh, vertex: int, radius: float, depth: float) -> np.ndarray:
    """The region's ring 0: the patch a sphere of `radius` [m] pressed `depth` [m] at `vertex` covers, as a
    palpation's (region.patch.sphere_patches); the vertex alone for the paper's probe (radius 0)."""
    from types import SimpleNamespace

    from ..region.patch import sphere_patches
    from ..sim.model import vertex_normals

    if radius <= 0:
        return np.array([vertex])
    model = SimpleNamespace(mesh=mesh, vertex_normal_rest=vertex_normals(mesh.vertices, mesh.triangles))
    offsets, ids = sphere_patches(model, np.array([vertex]), radius, depth)
    return ids[offsets[0] : offsets[1]]


def _auto_rings(scene, mesh, vertex: int, tol: float, radius: float) -> int:
    """--rings auto: the rings an adaptive press of the scene's grows to at `vertex` (batch.sweep_auto.size_regions)."""
    from ..batch.sweep_auto import size_regions
    from ..solvers.stepper import SimulationDiverged

    p = scene.press
    try:
        rings = int(size_regions(mesh, scene.tissue, [vertex], tol, depth=p.depth, ramp=p.ramp, hold=p.hold,
                                 probe_radius=radius, fixed_below=scene.fixed_below, law=scene.law)[0])
    except (SimulationDiverged, ValueError) as exc:
        raise InputError(str(exc)) from exc
    print(f"auto rings: {rings_text(rings)} (tol {tol * 1e3:g} mm), the rings an adaptive {p.depth * 1e3:g} mm press grows to here")
    return rings


def _grow(region, vertex: int, seeds, rings: int) -> list[dict]:
    """Build the region of 1..`rings` rings around `seeds` (ring 0, `vertex` among them), print each and
    return their rows."""
    rows = []
    for k in range(1, rings + 1):
        t0 = time.perf_counter()
        region.build_seeds(seeds, k, contact=vertex)
        build_us = (time.perf_counter() - t0) * 1e6
        rows.append(
            {
                "rings": k,
                "region_vertices": region.vertex_count,
                "region_springs": region.spring_count,
                "fixed_vertices": region.boundary_count,
                "build_us": round(build_us, 1),
            }
        )
        print(f"  {region.summary()}")
        if k < rings and len(rows) > 1 and rows[-1]["region_vertices"] == rows[-2]["region_vertices"]:
            # the region covers the contact's component: more rings add nothing (and --rings 1e20 would loop for ever)
            print(f"  rings {k + 1}..{rings}: the same region (it covers the mesh component of vertex {vertex})")
            break
    return rows
