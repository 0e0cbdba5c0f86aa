"""`almsdm touch`: touch a scene or mesh with the probe and print the ring regions at the contact."""

from __future__ import annotations

import time

import numpy as np

from ..errors import InputError
from .args import check_contact, get_device, mesh_json, path_arg, print_notes, probe_position, quiet_warp


def add_parser(sub) -> None:
    touch = sub.add_parser("touch", help="touch a scene or mesh with the probe and print the ring region")
    touch.add_argument("scene", nargs="?", default=None, type=path_arg, help="scene (.toml) or mesh file; default: the stomach scene")
    touch.add_argument("--rings", type=int, default=None, help="rings to grow (default: the scene's)")
    touch.add_argument("--probe-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="probe position [mm]")
    touch.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ...")
    touch.add_argument("--json", default=None, type=path_arg, help="write the result as JSON here")
    touch.set_defaults(func=cmd_touch)


def cmd_touch(args) -> int:
    """Load a scene or mesh, touch it with the probe, build the ring region and print it."""
    from ..export.writers import check_output, write_output
    from ..region.contact import find_contacts, top_vertex
    from ..region.region import Region
    from ..scene.loader import resolve_scene_or_mesh

    if args.json:
        check_output(args.json, "record", "--json")
    if args.rings is not None and args.rings < 0:
        raise InputError(f"--rings must be >= 0, got {args.rings}")
    quiet_warp()
    device = get_device(args.device)
    scene = resolve_scene_or_mesh(args.scene)
    mesh = scene.load_mesh()
    print_notes(mesh)
    rings = scene.rings if args.rings is None else args.rings
    if not isinstance(rings, int):  # a scene's rings = "auto": sized during a press, not by touching
        raise InputError(f"the scene {scene.name!r} sizes its region during a press ([region] rings = {rings!r}): "
                         f"give --rings K to touch, or press it with almsdm palpate")
    print(mesh.summary())

    if args.probe_mm is not None:
        probe = probe_position(args.probe_mm)
    else:
        # above the highest surface vertex: a press from the top
        top = top_vertex(mesh)
        probe = mesh.vertices[top] + np.array([0.0, 0.0, 5e-3])
    contact = find_contacts(mesh, probe, device=device)
    check_contact(contact, probe, mesh)
    print(
        f"probe at {np.round(probe * 1e3, 2).tolist()} mm touches face {contact.face} at "
        f"{np.round(contact.point * 1e3, 2).tolist()} mm ({contact.distance * 1e3:.2f} mm away); "
        f"nearest vertex {contact.vertex}"
    )
    rows = _grow(Region(mesh, device), int(contact.vertex), rings)
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


def _grow(region, vertex: int, rings: int) -> list[dict]:
    """Build the region of 1..`rings` rings around `vertex`, print each and return their rows."""
    rows = []
    for k in range(1, rings + 1):
        t0 = time.perf_counter()
        region.build(vertex, k)
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
