"""The `almsdm` command line. Bad input ends with one line on stderr and exit code 2.

Commands: ``palpate`` (the default: press the probe into a scene, report force, recovery and
speed) and ``touch`` (print the ring regions at the contact).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..errors import InputError

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, not usage + message
        raise InputError(f"{self.prog}: {message}")


def _path_arg(text):
    """A path argument: any text but one the operating system cannot take as a path."""
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"a path cannot hold a NUL byte: {text!r}")
    return text


_path_arg.__name__ = "path"


def _device(name):
    import warp as wp

    try:
        return wp.get_device(name)
    except (RuntimeError, ValueError) as exc:
        known = ", ".join(d.alias for d in wp.get_devices())
        raise InputError(f"unknown device {name!r} (available: {known})") from exc


def _quiet_warp():
    from ..warp_init import init_warp

    init_warp()


def cmd_touch(args) -> int:
    """Load a scene or mesh, touch it with the probe, build the ring region and print it."""
    from ..region.contact import find_contacts, top_vertex
    from ..export.output import check_writable, write_json
    from ..region.region import Region
    from ..scene.loader import resolve_scene_or_mesh

    if args.json:
        check_writable(args.json)
    if args.rings is not None and args.rings < 0:
        raise InputError(f"--rings must be >= 0, got {args.rings}")
    _quiet_warp()
    device = _device(args.device)
    scene = resolve_scene_or_mesh(args.scene)
    mesh = scene.load_mesh()
    for note in mesh.notes:
        print(f"note: {note}", file=sys.stderr)
    rings = scene.rings if args.rings is None else args.rings
    if not isinstance(rings, int):  # a scene's rings = "auto": sized during a press, not by touching
        raise InputError(f"the scene {scene.name!r} sizes its region during a press ([region] rings = {rings!r}): "
                         f"give --rings K to touch, or press it with almsdm palpate")
    print(mesh.summary())

    from .palpate import check_contact, probe_position

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
    region = Region(mesh, device)
    rows = []
    for k in range(1, rings + 1):
        t0 = time.perf_counter()
        region.build(int(contact.vertex), k)
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
            print(f"  rings {k + 1}..{rings}: the same region (it covers the mesh component of vertex {contact.vertex})")
            break
    if args.json:
        write_json(
            args.json,
            {
                "mesh": _mesh_json(mesh),
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
        )
        print(f"wrote {args.json}")
    return 0


# -- palpate ----------------------------------------------------------------------------------
def _mesh_json(mesh):
    return {
        "path": mesh.path,
        "vertices": mesh.vertex_count,
        "triangles": mesh.triangle_count,
        "tetrahedra": mesh.tet_count,
        "edges": mesh.edge_count,
    }


def build_parser() -> argparse.ArgumentParser:
    from ..solvers import INTEGRATORS
    from .palpate import _count_arg, _number_arg, _rings_arg, cmd_palpate
    from .record import add_record_args
    parser = _Parser(prog="almsdm", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)
    touch = sub.add_parser("touch", help="touch a scene or mesh with the probe and print the ring region")
    touch.add_argument("scene", nargs="?", default=None, type=_path_arg, help="scene (.toml) or mesh file; default: the stomach scene")
    touch.add_argument("--rings", type=int, default=None, help="rings to grow (default: the scene's)")
    touch.add_argument("--probe-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="probe position [mm]")
    touch.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ...")
    touch.add_argument("--json", default=None, type=_path_arg, help="write the result as JSON here")
    touch.set_defaults(func=cmd_touch)

    palpate = sub.add_parser(
        "palpate",
        help="press the probe into a scene or mesh; print force, recovery and speed (the default command)",
        description="Press the probe into a scene or mesh (the local ALMSDM region, or the whole mesh) and print "
        "the feedback force, the recovery after release and the speed of a step. Defaults come from the scene.",
    )
    palpate.add_argument("scene", nargs="?", default=None, type=_path_arg, metavar="MESH_OR_SCENE", help="scene (.toml), scene name or mesh file; default: the stomach scene")
    palpate.add_argument("--rings", type=_rings_arg, default=None, metavar="{N,auto,global,global-free}", help="rings of the local region (outermost fixed), auto (sized to --tol-mm), or a global model (default: the scene's)")
    palpate.add_argument("--tol-mm", type=_number_arg("> 0"), default=None, metavar="MM", help="--rings auto: grow the region until its fixed ring would move less than this [mm] (default 0.1)")
    palpate.add_argument("--integrator", choices=tuple(INTEGRATORS), default="explicit", help="explicit (semi-implicit Euler, the paper's) or implicit (backward Euler); default explicit")
    palpate.add_argument("--dt-ms", type=_number_arg("> 0"), default=1.0, metavar="MS", help="time step [ms] (default 1)")
    palpate.add_argument("--depth-mm", "--depth", dest="depth_mm", type=_number_arg("> 0"), default=None, metavar="MM", help="press depth [mm] (default: the scene's)")
    palpate.add_argument("--ramp-s", type=_number_arg(">= 0"), default=None, metavar="S", help="ramp time [s] (default: the scene's)")
    palpate.add_argument("--hold-s", type=_number_arg(">= 0"), default=None, metavar="S", help="hold time [s] (default: the scene's)")
    palpate.add_argument("--settle-s", type=_number_arg(">= 0"), default=None, metavar="S", help="settle window after release [s] (default: the scene's)")
    palpate.add_argument("--presses", type=_count_arg, default=1, metavar="N", help="presses at the same spot (default 1)")
    palpate.add_argument("--scale-mm", type=_number_arg("> 0"), default=None, metavar="MM", help="millimetres per mesh file unit, for a mesh file (default 1; 10 for cm, 1000 for m)")
    where = palpate.add_mutually_exclusive_group()
    where.add_argument("--vertex", type=int, default=None, metavar="V", help="contact vertex (a surface vertex id)")
    where.add_argument("--probe-mm", type=float, nargs=3, metavar=("X", "Y", "Z"), help="probe position [mm]; the contact is its nearest surface vertex")
    palpate.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ...")
    palpate.add_argument("--json", default=None, type=_path_arg, metavar="PATH", help="write the result as JSON here")
    palpate.add_argument("--progress", action=argparse.BooleanOptionalAction, default=None, help="progress bar on stderr (default: only on a terminal, for runs over ~2 s)")
    add_record_args(palpate)
    palpate.set_defaults(func=cmd_palpate)
    from .bench import add_parser as add_bench
    from .evaluate import add_parser as add_evaluate
    from .sweep import add_parser as add_sweep

    add_evaluate(sub)
    add_sweep(sub)
    add_bench(sub)
    return parser


COMMANDS = ("palpate", "touch", "evaluate", "sweep", "bench")


def _default_command(argv) -> bool:
    """True when argv names no command but is meant for palpate: nothing, an option first, or a
    scene or mesh first (a path, a file name, a shipped scene's name); `almsdm frobnicate` is not."""
    if not argv:
        return True
    first = argv[0]
    if first in COMMANDS or first in ("-h", "--help"):
        return False
    if first.startswith("-") or "/" in first or "\\" in first or "." in first:
        return True
    from pathlib import Path

    from ..scene.loader import scene_names

    try:
        return Path(first).exists() or first in scene_names()
    except (InputError, OSError):
        return False


def main(argv=None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if _default_command(argv):
        argv = ["palpate", *argv]  # `almsdm`, `almsdm --depth-mm 5`, `almsdm liver`, `almsdm my.obj`
    try:
        args = parser.parse_args(argv)
        return args.func(args)
    except InputError as exc:
        message = " ".join(str(exc).split())  # one line, whatever the message holds
        print(f"almsdm: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:  # the reader of our output went away (`almsdm ... | head`): not an error
        sys.stderr.close()  # nothing more can be said, and Python's exit flush must not complain
        return 0
    except OSError as exc:  # the file system refused a path given (a name too long, a loop of links, ...)
        name = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"almsdm: error: {name}{exc.strerror or ' '.join(str(exc).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("almsdm: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
