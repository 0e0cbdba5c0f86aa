"""What the subcommands of `almsdm` share: the parser class, argument types, the device, the
contact from --probe-mm, and the JSON summary of a mesh. Bad input is an InputError (exit code 2)."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from ..checks import AUTO_TOL, rings_text  # noqa: F401  (the commands take rings_text from here)
from ..errors import InputError

GLOBAL_RINGS = ("global", "global-free")
"""--rings values of the global model (anchored, or free with no anchors)."""
AUTO_TOL_MM = AUTO_TOL * 1e3
"""--tol-mm when --rings auto is given without it [mm]."""


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (an InputError), not usage + message."""

    def error(self, message):
        command = self.prog.split()[1:]  # "almsdm palpate" -> the subcommand; the line already starts "almsdm:"
        raise InputError(f"{' '.join(command)}: {message}" if command else message)


def add_command(sub, name: str, summary: str, description: str):
    """A subcommand's parser (`summary` in `almsdm --help`, `description` in its own) with --device."""
    p = sub.add_parser(name, help=summary, description=description)
    p.add_argument("--device", default="cpu", help="Warp device: cpu, cuda, cuda:0, ... (default cpu)")
    return p


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
        return count_arg(text, allowed=allowed, note="ring 0 is the contact vertex alone")

    return parse


def number_arg(rule):
    """An argparse type: a float that is "> 0", ">= 0" or any "number", and 0 or of the magnitude every
    physical parameter is held to wherever it enters (checks.check_value: a flag, a scene, a spec, the API)."""
    from ..checks import check_value

    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        try:
            return check_value(value, float, rule, "")
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc).strip()) from None

    parse.__name__ = "number"
    return parse


def count_arg(text, allowed=None, note=None):
    """An argparse type: an integer >= 1. `allowed` (the values a caller accepts, words too) and
    `note` go into the messages."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"unknown value {text!r} (allowed: {allowed})" if allowed else f"not an integer: {text!r}") from None
    if value < 1:
        why = "; ".join(x for x in (note, allowed and f"allowed: {allowed}") if x)
        raise argparse.ArgumentTypeError(f"must be >= 1{f' ({why})' if why else ''}, got {value}")
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


def print_notes(mesh, extra: str = ""):
    """The mesh's validation notes (and `extra`, a line on its unit), one line each on stderr."""
    for note in [*mesh.notes, *([extra] if extra else [])]:
        print(f"note: {note}", file=sys.stderr)


def load_scene_and_mesh(args):
    """(scene, mesh) as every command reads them: the scene or mesh file (args.scene), a mesh file at
    --scale-mm or else at the unit guessed from its size, with --tissue's preset; the mesh's notes
    and the unit line printed. InputError for --scale-mm on a scene file."""
    from ..scene.loader import resolve_scene_or_mesh

    scale = getattr(args, "scale_mm", None)
    scene = resolve_scene_or_mesh(args.scene, scale_mm=1.0 if scale is None else scale, tissue=getattr(args, "tissue", None))
    if scale is not None and scene.path is not None:
        raise InputError(f"--scale-mm is for a mesh file; the scene {scene.name!r} sets its own ([mesh] scale_mm)")
    scene, mesh, units = scene.load_mesh_guessing_units(guess=scale is None)
    print_notes(mesh, units)
    return scene, mesh


MATERIAL_FLAGS = {
    "youngs_modulus_kpa": ("--youngs-modulus-kpa", "youngs_modulus", 1.0e-3, "> 0", "KPA", "Young's modulus E [kPa]"),
    "poisson_ratio": ("--poisson-ratio", "poisson_ratio", 1.0, "number", "NU", "Poisson ratio nu, in (-1, 0.5) (default 0.45)"),
    "density_kg_per_m3": ("--density-kg-per-m3", "density", 1.0, "> 0", "RHO", "density [kg/m^3] (default 1000)", "--density-kg-m3"),
    "thickness_mm": ("--thickness-mm", "thickness", 1.0e3, ">= 0", "MM", "membrane thickness of a surface mesh [mm] (needed there)"),
    "foundation_kpa_per_mm": ("--foundation-kpa-per-mm", "foundation", 1.0e-6, ">= 0", "K",
                              "Winkler foundation of a surface mesh [kPa/mm]: anchors k_i = K x area (default 0)"),
    "damping_ratio": ("--damping-ratio", "damping_ratio", 1.0, ">= 0", "ZETA", "each damper as a fraction of its spring's critical damping"),
    "rayleigh_alpha_per_s": ("--rayleigh-alpha-per-s", "rayleigh_alpha", 1.0, ">= 0", "A", "mass-proportional Rayleigh damping [1/s]"),
    "rayleigh_beta_s": ("--rayleigh-beta-s", "rayleigh_beta", 1.0, ">= 0", "B", "stiffness-proportional Rayleigh damping [s]"),
}
"""The tissue-as-a-material flags: dest -> (flag, Material attribute, flag units per SI unit, rule, metavar, help,
old spellings still taken). Named as the scene's keys are (tissue.material.MATERIAL_KEYS), lower case. Any of
them switches the run to the material model (tissue/material.py) with the scene's values as defaults."""


def add_integrator_arg(parser, batch: bool = False) -> None:
    """--integrator, the names of solvers.INTEGRATORS (with batch, those that press a batch: sweep)."""
    from ..solvers import integrators

    parser.add_argument("--integrator", choices=integrators(batch), default="explicit", help="explicit (semi-implicit Euler, the paper's) or implicit (backward Euler); default explicit")


def add_law_arg(parser, path: str) -> None:
    """--law, a tissue law (tissue.laws.LAWS) with kernels for the protocol `path` ("palpation",
    "batch", "stroke"): any other is a one-line error naming why."""
    from ..tissue.laws import LAWS

    def parse(text):
        try:
            return require_law(text, path, "--law")
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("--law ")) from None

    parse.__name__ = "law"
    usable = [name for name, law in LAWS.items() if law.has(path=path)]
    parser.add_argument("--law", type=parse, default=None, metavar="{" + ",".join(usable) + "}",
                        help=f"tissue law: {' or '.join(usable)} (default: the scene's [tissue] law, else neo-hookean for a material "
                             "on a tet mesh and springs otherwise)")


def require_law(law, path: str, what: str) -> str:
    """`law` where it is a tissue law with kernels for the protocol `path`; else InputError starting with `what`."""
    from ..tissue.laws import LAWS

    if law not in LAWS:
        raise InputError(f"{what} {law!r} is not a tissue law (allowed: {', '.join(LAWS)})")
    try:
        LAWS[law].require(path=path)
    except ValueError as exc:
        raise InputError(f"{what} {law}: {exc}") from None
    return law


def check_law(scene, mesh, integrator: str, path: str, why: str = ""):
    """The scene with its tissue law named (None: the default for `mesh` and its tissue, default_law);
    InputError, one line (`why` first), where that law has no `integrator` step or no kernels for the
    protocol `path`, or cannot model the mesh or tissue (before any work)."""
    from dataclasses import replace

    from ..tissue.laws import LAWS, resolve_law

    scene = replace(scene, law=resolve_law(scene.law, mesh, scene.tissue))
    law = LAWS[scene.law]
    try:
        law.require(integrator=integrator, path=path)
        if law.check is not None:
            law.check(law.name, mesh, scene.tissue)
    except ValueError as exc:
        raise InputError(f"{why}{exc}") from None
    return scene


def add_probe_radius_arg(parser) -> None:
    """--probe-radius-mm [mm] (palpate, trace)."""
    parser.add_argument("--probe-radius-mm", type=number_arg(">= 0"), default=None, metavar="MM", help="radius of the spherical probe [mm]; 0: the paper's probe, the contact vertex driven (default: the scene's [probe] radius_mm, else 0)")


def add_tissue_args(parser, supports: bool = True) -> None:
    """--tissue, the material flags and (with `supports`) --support and --fixed-below-mm, in their own group."""
    from ..tissue.presets import DEFAULT_PRESET, PRESETS

    group = parser.add_argument_group("tissue as a material (any of these replaces the scene's per-spring constants)")
    group.add_argument("--tissue", choices=tuple(PRESETS), default=None,
                       help=f"a tissue preset (docs/calibration.md): its material and, for a mesh file, its probe and region "
                            f"(default: the scene's; a mesh file's: {DEFAULT_PRESET}); paper: the paper's per-spring constants")
    for dest, (flag, _attr, _factor, rule, metavar, text, *aliases) in MATERIAL_FLAGS.items():
        group.add_argument(flag, dest=dest, type=number_arg(rule), default=None, metavar=metavar, help=text)
        for alias in aliases:  # an old spelling, still taken, not listed
            group.add_argument(alias, dest=dest, type=number_arg(rule), default=None, help=argparse.SUPPRESS)
    if supports:
        where = group.add_mutually_exclusive_group()
        where.add_argument("--support", type=support_arg, default=None, metavar="{far-side,below:FRACTION,none}",
                           help="what holds the organ: far-side (every vertex lower than 30%% of the way from its bottom to the "
                                "contact), below:FRACTION (its lowest FRACTION of height) or none (default: the scene's; a mesh "
                                "file's: far-side on a tet volume of a material, none on a surface, held by its foundation)")
        where.add_argument("--fixed-below-mm", type=number_arg("number"), default=None, metavar="Z",
                           help="support: every vertex with z below Z [mm] is fixed (an organ on a plate, +z up; default: the scene's)")


def support_arg(text):
    """An argparse type for --support (scene.support.parse_support)."""
    from ..scene.support import parse_support

    try:
        return parse_support(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


support_arg.__name__ = "support"


def scene_with_tissue_args(args, scene, mesh, contact_z: float | None = None):
    """The scene with --tissue, the material flags, --law and the support (--support, --fixed-below-mm, or the
    scene's relative rule made a plane for a press from above at `contact_z` [m], default the top vertex's)
    applied; InputError for a material that cannot be (no E to start from, a surface with no thickness, nu
    out of range) or a support that holds every vertex."""
    from dataclasses import replace

    scene = _with_preset(args, scene)
    tissue = _material_from_flags(args, scene, mesh)
    law = scene.law if getattr(args, "law", None) is None else args.law
    scene = replace(scene, tissue=tissue, law=law)
    flag_z, rule = getattr(args, "fixed_below_mm", None), getattr(args, "support", None)
    if flag_z is not None:
        scene = replace(scene, support=None, fixed_below=flag_z * 1e-3)
    elif rule is not None:
        scene = replace(scene, support=rule)
    if contact_z is None:
        from ..region.contact import top_vertex

        contact_z = float(mesh.vertices[top_vertex(mesh), 2])
    scene = scene.with_support(mesh, contact_z)
    fixed_below = scene.fixed_below
    if fixed_below is not None and not (mesh.vertices[:, 2] >= fixed_below).any():
        where = f"--fixed-below-mm {flag_z:g}" if flag_z is not None else "the scene's [support] fixed_below_mm"
        raise InputError(f"{where} is above every vertex of {mesh.name} (highest z {mesh.vertices[:, 2].max() * 1e3:.4g} mm): "
                         f"nothing could move")
    return scene


def _with_preset(args, scene):
    """The scene with --tissue's material in place of its own (a mesh file took the preset when read)."""
    from dataclasses import replace

    from ..tissue.presets import tissue_preset

    name = getattr(args, "tissue", None)
    if name is None or scene.preset == name:
        return scene
    return replace(scene, tissue=tissue_preset(name).tissue, preset=name)


def _material_from_flags(args, scene, mesh):
    """The scene's tissue with the material flags applied (none given: the scene's tissue)."""
    from dataclasses import asdict

    from ..tissue.material import Material

    given = {attr: getattr(args, dest) / factor for dest, (_f, attr, factor, *_rest) in MATERIAL_FLAGS.items()
             if getattr(args, dest, None) is not None}
    tissue = scene.tissue
    if given:
        base = asdict(tissue) if isinstance(tissue, Material) else {}
        if "youngs_modulus" not in given and not base:
            flags = ", ".join(MATERIAL_FLAGS[d][0] for d in MATERIAL_FLAGS if getattr(args, d, None) is not None)
            raise InputError(f"{flags} make the tissue a material, which needs --youngs-modulus-kpa "
                             f"(the scene {scene.name!r} gives per-spring constants, not a material)")
        if "damping_ratio" in given:  # one kind of damping: the flag replaces the scene's
            base.update(rayleigh_alpha=0.0, rayleigh_beta=0.0)
        elif "rayleigh_alpha" in given or "rayleigh_beta" in given:
            base.update(damping_ratio=0.0)
        base.update(given)
        try:
            tissue = Material(**base)
        except (TypeError, ValueError) as exc:
            flag = next((f"{f}: " for f, attr, *_r in MATERIAL_FLAGS.values() if f"Material.{attr} " in str(exc)), "")
            raise InputError(f"{flag}{exc}") from None
    if isinstance(tissue, Material) and not mesh.is_volume and not tissue.thickness > 0.0:  # from the flags or the scene
        from ..tissue.laws import LAWS, default_law

        law = getattr(args, "law", None) or scene.law or default_law(True, tissue)
        if not ((getattr(args, "volume", None) or scene.volume) == "auto" and law in LAWS and LAWS[law].volumetric):
            raise InputError(f"{mesh.name} is a surface mesh: the material model needs a membrane --thickness-mm > 0 "
                             f"(or the scene's [tissue] thickness_mm)")
    return tissue
