"""What the subcommands of `almsdm` share: the parser class, argument types, the device, the
contact from --probe-mm, and the JSON summary of a mesh. Bad input is an InputError (exit code 2)."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from ..errors import InputError

GLOBAL_RINGS = ("global", "global-free")
"""--rings values of the global model (anchored, or free with no anchors)."""
AUTO_TOL_MM = 0.1
"""--tol-mm when --rings auto is given without it [mm]."""


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (an InputError), not usage + message."""

    def error(self, message):
        raise InputError(f"{self.prog}: {message}")


def path_arg(text):
    """A path argument: any text but one the operating system cannot take as a path."""
    if "\0" in text:
        raise argparse.ArgumentTypeError(f"a path cannot hold a NUL byte: {text!r}")
    return text


path_arg.__name__ = "path"


def rings_arg(words=("auto", *GLOBAL_RINGS)):
    """An argparse type for --rings: an integer >= 1 or one of `words`."""
    items = ["an integer >= 1", *(repr(w) for w in words)]
    allowed = ", ".join(items[:-1]) + " or " + items[-1]

    def parse(text):
        if text in words:
            return text
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"unknown value {text!r} (allowed: {allowed})") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"must be >= 1 (ring 0 is the contact vertex alone; allowed: {allowed}), got {value}")
        return value

    return parse


def number_arg(rule):
    """An argparse type: a finite float that is "> 0" or ">= 0"."""

    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text!r}")
        if (rule == "> 0" and not value > 0) or (rule == ">= 0" and not value >= 0):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return value

    parse.__name__ = "number"
    return parse


def count_arg(text):
    """An argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def int_list(text):
    """An argparse type: a comma list of integers >= 1."""
    try:
        values = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a comma list of integers: {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"must be integers >= 1, got {text!r}")
    return values


def auto_tol(args, rings, scene=None):
    """The tolerance [m] of rings "auto" (--tol-mm, else the scene's [region] tol_mm, else AUTO_TOL_MM),
    None for the others; --tol-mm with a fixed ring count is an error."""
    if rings != "auto":
        if args.tol_mm is not None:
            where = f"--rings {rings}" if args.rings is not None else f"the scene's [region] rings = {rings}"
            raise InputError(f"--tol-mm is for --rings auto (the region sized to a tolerance), not {where}")
        return None
    if args.tol_mm is not None:
        return args.tol_mm * 1e-3
    tol = getattr(scene, "tol", None)
    return tol if tol is not None else AUTO_TOL_MM * 1e-3


def get_device(name):
    """The Warp device named `name`; InputError listing the devices present for an unknown one."""
    import warp as wp

    try:
        return wp.get_device(name)
    except (RuntimeError, ValueError) as exc:
        known = ", ".join(d.alias for d in wp.get_devices())
        raise InputError(f"unknown device {name!r} (available: {known})") from exc


def quiet_warp():
    """Initialize Warp without its start-up messages."""
    from ..warp_init import init_warp

    init_warp()


def press_steps(dt, ramp, hold, settle) -> int:
    """Steps of one press, counted as Palpation.press counts them (for progress bars only)."""
    from ..protocol.schedule import PressSchedule

    return PressSchedule.from_times(dt, ramp, hold, settle).total


def finite(value):
    """A float for JSON, or None where it is not finite (JSON has no inf or nan)."""
    value = float(value)
    return value if math.isfinite(value) else None


def mesh_json(mesh):
    """The mesh's file and sizes, for a JSON record."""
    return {
        "path": mesh.path,
        "vertices": mesh.vertex_count,
        "triangles": mesh.triangle_count,
        "tetrahedra": mesh.tet_count,
        "edges": mesh.edge_count,
    }


def probe_position(probe_mm, flag="--probe-mm"):
    """--probe-mm X Y Z -> metres, finite and within the +-1 km that meshes are held to."""
    from ..mesh.validate import MAX_COORDINATE_M

    probe = np.asarray(probe_mm, dtype=np.float64) * 1e-3
    if not np.all(np.isfinite(probe)):
        raise InputError(f"{flag} must be finite, got {list(probe_mm)}")
    if np.abs(probe).max() > MAX_COORDINATE_M:
        raise InputError(f"{flag} {list(probe_mm)} is more than {MAX_COORDINATE_M * 1e3:g} mm from the origin, "
                         f"beyond any mesh the simulator holds")
    return probe


def check_contact(contact, probe, mesh):
    """A contact that found no surface vertex is an InputError, not a vertex id of -1."""
    if int(contact.vertex) < 0 or int(contact.face) < 0:
        raise InputError(f"the probe at {np.round(probe * 1e3, 3).tolist()} mm finds no surface of {mesh.name} "
                         f"(it is too far from the mesh)")


ORGAN_SPAN_MM = (2.0, 2000.0)
"""An organ's largest extent lies between these [mm]; outside, the mesh's unit is likely not mm."""


def units_hint(mesh) -> str | None:
    """A note when the mesh's largest extent suggests its file is not in millimetres, else None."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    span = float(np.ptp(vertices, axis=0).max()) * 1e3 if len(vertices) else 0.0
    lo, hi = ORGAN_SPAN_MM
    if 0.0 < span < lo:
        return f"the mesh spans {span:.4g} mm; if its file is in metres or centimetres, give --scale-mm 1000 or 10"
    if span > hi:
        return f"the mesh spans {span:.4g} mm; if its file is in micrometres or tenths of a millimetre, give --scale-mm 0.001 or 0.1"
    return None


def print_notes(mesh):
    """The mesh's validation notes, and a units hint where its size suggests one, one line each on stderr."""
    hint = units_hint(mesh)
    for note in [*mesh.notes, *([hint] if hint else [])]:
        print(f"note: {note}", file=sys.stderr)
