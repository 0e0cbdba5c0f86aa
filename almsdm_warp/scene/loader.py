"""Scenes: an organ mesh with its tissue, region and press parameters, read from a TOML file.

A scene file names every value's unit in its key (``depth_mm``, ``edge_stiffness_N_per_m``);
:func:`load_scene` checks it strictly (unknown sections and keys are errors, so a typo never
goes unnoticed) and converts it to SI units: :class:`Scene` holds metres, kilograms, seconds
and newtons. The project ships two scenes, ``stomach`` (the default) and ``liver``; see
``scenes/stomach.toml`` for the documented schema. Every problem is an :class:`InputError`
with one line that starts with the scene file's path.
"""

from __future__ import annotations

import difflib
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import InputError
from ..checks import AUTO, check_rings, check_value, describe, rings_text
from ..protocol.schedule import PressParams
from ..mesh.volume import VOLUME_CHOICES
from ..tissue.laws import LAWS
from ..tissue.material import Material, material_as_dict
from ..tissue.params import TissueParams
from ..tissue.presets import DEFAULT_PRESET, tissue_preset
from ..tissue.wall import WALL_CHOICES
from .schema import DEFAULT_TISSUE_MODEL, SCHEMA, TISSUE_MODELS
from .support import describe_support, parse_support, support_height

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

if TYPE_CHECKING:
    from ..tissue.lesion import Lesion
    from ..mesh.tissue_mesh import TissueMesh

DEFAULT_SCENE = "stomach"
"""The scene used when none is given."""
DEFAULT_LAW = None
"""The tissue law of a scene that names none ([tissue] law): None, the model's default for its mesh and
tissue (tissue.laws.default_law: neo-Hookean tets for a material on a tet mesh, else springs)."""


def check_choice(value, choices, what: str) -> str:
    """`value` if it is one of `choices`, else InputError naming them."""
    if not isinstance(value, str) or value not in choices:
        raise InputError(f"{what} = {value!r} is not one of {', '.join(map(repr, choices))}")
    return value


def check_law_name(law, what: str) -> str:
    """`law` if it names a tissue law (a key of tissue.laws.LAWS), else InputError naming the allowed ones."""
    if not isinstance(law, str) or law not in LAWS:
        raise InputError(f"{what} = {law!r} is not a tissue law (allowed: {', '.join(map(repr, LAWS))})")
    return law



@dataclass(frozen=True)
class Scene:
    """An organ mesh and the parameters to simulate it with (SI units)."""

    path: Path | None
    """The scene file, or None for a scene made from a bare mesh file."""
    mesh_path: Path
    """The mesh file (absolute)."""
    scale_mm: float = 1.0
    """Millimetres per mesh file unit (1.0 for a file in mm, 10.0 for cm, 1000.0 for m)."""
    tissue: TissueParams | Material = field(default_factory=TissueParams)
    """The paper's per-spring constants (TissueParams, [tissue] model = "paper") or a material whose
    springs, anchors, masses and dampers are derived per edge and vertex (Material, model = "material")."""
    rings: int | str = 4
    """Rings grown from the contact vertex along mesh edges (the outermost ring fixed), or "auto":
    the region sized during each press to `tol` (AdaptivePalpation, ``--rings auto``)."""
    press: PressParams = field(default_factory=PressParams)
    """The press protocol."""
    lesion: "Lesion | None" = None
    """A sphere of stiffer tissue (the scene's optional [lesion] table), or None."""
    tol: float | None = None
    """With rings = "auto": the displacement tolerance [m] the region is sized to (None: the
    command line's default, almsdm_warp.cli.args.AUTO_TOL_MM); None otherwise."""
    fixed_below: float | None = None
    """[support] fixed_below_mm: every vertex with z below this height [m] is fixed (an organ on a
    plate, pressed from above, +z up); None: no supports."""
    probe_radius: float = 0.0
    """Radius of the spherical probe [m]; 0: the paper's probe (the contact vertex driven)."""
    law: str | None = DEFAULT_LAW
    """The tissue law ([tissue] law, a key of tissue.laws.LAWS): "springs" (the paper's), "neo-hookean"
    (stable neo-Hookean tets) or "corotational" (corotational linear tets), both for a material on a
    tet mesh; None: the model's default (tissue.laws.default_law)."""
    support: str | None = None
    """A support given relative to the organ (scene.support: "far-side", "below:FRACTION", "none"), or
    "auto" (far-side on a tet volume of a material, none otherwise), which `with_support` turns into
    `fixed_below` once the mesh and the contact are known; None: `fixed_below` as given."""
    preset: str | None = None
    """The tissue preset the tissue came from (tissue.presets.PRESETS), or None (the scene's own)."""
    volume: str = "off"
    """[mesh] volume (mesh.volume.VOLUME_CHOICES): "auto", a closed surface given for a volumetric law made a
    volume of tets, finest where it is pressed (cli/volume_arg.py); "off", the mesh as read."""
    wall: str = "membrane"
    """[tissue] wall (tissue.wall.WALL_CHOICES): a surface of a material with a thickness as a "membrane" on a
    foundation (springs), or as a layer of "tets" that thick (tissue/wall.py)."""

    def __post_init__(self):
        object.__setattr__(self, "mesh_path", Path(self.mesh_path))
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))
        object.__setattr__(self, "scale_mm", check_value(self.scale_mm, float, "> 0", "Scene.scale_mm"))
        check_rings(self.rings, "Scene.rings")
        if not isinstance(self.tissue, (TissueParams, Material)):
            raise TypeError(f"Scene.tissue must be a TissueParams or a Material, got {type(self.tissue).__name__}")
        if self.fixed_below is not None:
            object.__setattr__(self, "fixed_below", check_value(self.fixed_below, float, "number", "Scene.fixed_below"))
        object.__setattr__(self, "probe_radius", check_value(self.probe_radius, float, ">= 0", "Scene.probe_radius"))
        if self.law is not None:
            check_law_name(self.law, "Scene.law")
        if self.support not in (None, "auto"):
            object.__setattr__(self, "support", parse_support(self.support))
        check_choice(self.volume, VOLUME_CHOICES, "Scene.volume")
        check_choice(self.wall, WALL_CHOICES, "Scene.wall")
        if self.tol is not None:
            object.__setattr__(self, "tol", check_value(self.tol, float, "> 0", "Scene.tol"))
            if self.rings != AUTO:
                raise InputError(f"Scene.tol is for rings = {AUTO!r} (the region sized to a tolerance), "
                                 f"but rings = {self.rings!r}")

    @property
    def tissue_model(self) -> str:
        """"paper" or "material": the [tissue] model of this scene."""
        return "material" if isinstance(self.tissue, Material) else "paper"

    @property
    def name(self) -> str:
        """The scene file's stem, or the mesh file's for a bare mesh."""
        return (self.path or self.mesh_path).stem

    def with_support(self, mesh, contact_z: float) -> "Scene":
        """The scene with its relative support (`support`) made a plane (`fixed_below`) for `mesh` pressed
        from above at a contact of height `contact_z` [m]; itself where it has none."""
        rule = self.support
        if rule is None:
            return self
        if rule == "auto":
            rule = "far-side" if mesh.is_volume and isinstance(self.tissue, Material) else "none"
        return replace(self, support=rule, fixed_below=support_height(rule, mesh.vertices, contact_z))

    def support_text(self) -> str:
        """The support in a few words: "far-side (fixed below z = -12.3 mm)", "none", ..."""
        return describe_support(self.support, self.fixed_below)

    def load_mesh(self) -> TissueMesh:
        """Read, validate and repair the scene's mesh (metres); raises InputError."""
        from ..mesh.io import load_mesh

        return load_mesh(self.mesh_path, scale=self.scale_mm)

    def load_mesh_guessing_units(self, guess: bool = True) -> tuple["Scene", TissueMesh, str]:
        """(the scene at the unit guessed from its mesh's size, the mesh, one line saying so, "" where it is
        millimetres as read): a bare mesh file's unit is unknown (mesh.units.guess_scale); a scene file's is
        its own (no line). guess=False: the unit as given (--scale-mm), a line only where it makes no organ."""
        from ..mesh.units import guess_scale, is_organ_size, mesh_span

        mesh = self.load_mesh()
        if self.path is not None:
            return self, mesh, ""
        if not guess:  # the unit given: a note only where it makes no organ
            span = mesh_span(mesh.vertices) * 1e3
            return self, mesh, "" if is_organ_size(span) else (
                f"the mesh spans {span:.4g} mm at --scale-mm {self.scale_mm:g}: not an organ's size; is the unit right?")
        scale, line = guess_scale(mesh_span(mesh.vertices) * 1e3 / self.scale_mm)
        if scale == self.scale_mm:
            return self, mesh, ("" if is_organ_size(mesh_span(mesh.vertices) * 1e3) else line)  # millimetres: no news
        scene = replace(self, scale_mm=scale)
        return scene, scene.load_mesh(), line

    def rings_text(self) -> str:
        """"4 rings", or "auto rings (tol 0.1 mm)" ("tol: the default" when the scene gives none)."""
        if self.rings != AUTO:
            return rings_text(self.rings)
        return f"auto rings (tol {self.tol * 1e3:g} mm)" if self.tol is not None else "auto rings (tol: the default)"

    def as_dict(self) -> dict:
        """The scene in interface units, keyed as in a scene file (for JSON records)."""
        out: dict = {"scene": str(self.path) if self.path else None}
        for section, keys in SCHEMA.items():
            out[section] = {}
            if section == "tissue":
                out[section] = {"model": self.tissue_model, **({"law": self.law} if self.law is not None else {}),
                                **({"wall": self.wall} if self.wall != Scene.wall else {}), **self._tissue_dict()}
                continue
            for key, (attr, _kind, factor, _rule) in keys.items():
                value = _get(self, section, attr)
                if section == "mesh" and attr == "path":
                    value = str(self.mesh_path)
                elif factor != 1.0 and value is not None:
                    value = value * factor
                out[section][key] = value
        out["tissue"]["preset"] = self.preset
        out["support"]["rule"] = None if self.support == "auto" else self.support
        if self.lesion is not None:
            out["lesion"] = self.lesion.as_dict()
        return out

    def _tissue_dict(self) -> dict:
        if isinstance(self.tissue, Material):
            return material_as_dict(self.tissue)
        keys = TISSUE_MODELS["paper"]
        return {key: getattr(self.tissue, attr) * factor for key, (attr, _kind, factor, _rule) in keys.items()}

    def tissue_text(self) -> str:
        """The tissue in a few words: the paper's k_ij and k_i, or the material's E and nu."""
        t = self.tissue
        named = f"preset {self.preset}: " if self.preset else ""
        if isinstance(t, Material):
            return f"{named}E {t.youngs_modulus * 1e-3:g} kPa, nu {t.poisson_ratio:g}, rho {t.density:g} kg/m^3"
        return f"{named}k_ij {t.edge_stiffness:g} N/m, k_i {t.anchor_stiffness:g} N/m"

    def summary(self) -> str:
        """One line: the scene, its mesh and the parameters people ask about first."""
        support = f", fixed below z = {self.fixed_below * 1e3:g} mm" if self.fixed_below is not None else ""
        return (
            f"scene {self.name}: mesh {self.mesh_path.name} (x{self.scale_mm:g} mm), {self.rings_text()}, "
            f"{self.tissue_text()}{support}, press {self.press.depth * 1e3:g} mm"
        )


def _get(scene: Scene, section: str, attr: str):
    if section == "tissue":
        return getattr(scene.tissue, attr)
    if section == "press":
        return getattr(scene.press, attr)
    return getattr(scene, attr)


def load_scene(path) -> Scene:
    """Read and check a scene file (TOML); returns a :class:`Scene` in SI units.

    Keys left out take the defaults (the stomach scene's values), except ``[mesh] path``,
    which is required and is relative to the scene file. Raises InputError, one line naming
    the file: no such file, a TOML syntax error (with line and column), an unknown section or
    key (with the allowed ones), a value of the wrong type, a non-finite or out-of-range value,
    a missing mesh file.
    """
    where = str(path)
    p = Path(path)
    data = read_toml(p, where)
    lesion = None
    if "lesion" in data:  # an optional table of its own (an array and scalars: almsdm_warp/tissue/lesion.py)
        from ..tissue.lesion import parse_lesion

        lesion = parse_lesion(data.pop("lesion"), where)
    values = _section_values(data, where)
    region = values["region"]
    if "tol" in region and region.get("rings") != AUTO:
        rings = f"rings = {region['rings']!r}" if "rings" in region else f"rings is not given (default {Scene.rings})"
        raise InputError(f"{where}: [region] tol_mm is for rings = {AUTO!r} (the region sized to a tolerance), but {rings}")
    if len(values["support"]) > 1:
        raise InputError(f"{where}: [support] rule and fixed_below_mm both given: give one (a rule relative to the organ, or a height)")
    mesh_path = _mesh_path(values["mesh"].get("path"), p, where)
    law = values["tissue"].pop("law", DEFAULT_LAW)
    law = None if law is None else check_law_name(law, f"{where}: [tissue] law")
    wall = check_choice(values["tissue"].pop("wall", Scene.wall), WALL_CHOICES, f"{where}: [tissue] wall")
    volume = check_choice(values["mesh"].get("volume", Scene.volume), VOLUME_CHOICES, f"{where}: [mesh] volume")
    tissue = _tissue(data.get("tissue", {}), values["tissue"], where)

    try:  # the SI values are checked again: say which file they came from
        return Scene(
            path=Path(os.path.abspath(p)),
            mesh_path=mesh_path,
            scale_mm=values["mesh"].get("scale_mm", 1.0),
            tissue=tissue,
            rings=region.get("rings", Scene.rings),
            tol=region.get("tol"),
            press=PressParams(**values["press"]),
            lesion=lesion,
            fixed_below=values["support"].get("fixed_below"),
            support=values["support"].get("support"),
            probe_radius=values["probe"].get("probe_radius", 0.0),
            law=law,
            volume=volume,
            wall=wall,
        )
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _tissue(table: dict, values: dict, where: str) -> TissueParams | Material:
    """The [tissue] table as its model's parameters; a key of the other model is an error."""
    model = values.pop("model", DEFAULT_TISSUE_MODEL)
    if model not in TISSUE_MODELS:
        raise InputError(f"{where}: [tissue] model = {model!r} is not one of {', '.join(map(repr, TISSUE_MODELS))}")
    keys = TISSUE_MODELS[model]
    for key in table:
        if key not in ("model", "law", "wall") and key not in keys:
            default = " (the default)" if "model" not in table else ""
            raise InputError(f"{where}: [tissue] {key} is a key of another tissue model, not of model = {model!r}{default}; "
                             f"allowed with it: model, law, wall, {', '.join(keys)}")
    if model == "material" and "youngs_modulus" not in values:
        raise InputError(f"{where}: [tissue] model = 'material' needs youngs_modulus_kPa (Young's modulus [kPa])")
    try:
        return Material(**values) if model == "material" else TissueParams(**values)
    except (TypeError, ValueError) as exc:  # Material's own checks (nu in range, one kind of damping)
        raise InputError(f"{where}: {exc}") from None


def read_toml(p: Path, where: str, what: str = "scene file") -> dict:
    """A TOML document (a scene file, a dataset spec), read through the bounded reader; InputError when it
    is missing, not a regular file, unreadable, not TOML or nested past the parser's recursion."""
    from ..mesh.io import read_bounded

    if not p.exists():
        raise InputError(f"{where}: no such {what}")
    data = read_bounded(p, where, what=what)
    try:
        return tomllib.loads(data.decode("utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{where}: TOML syntax error: {exc}") from exc
    except RecursionError:  # the parser recurses once per level of nested arrays or tables
        raise InputError(f"{where}: arrays or tables nested too deeply (a {what} needs two levels)") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{where}: not a UTF-8 text file (TOML), byte {exc.start} is 0x{exc.object[exc.start]:02x}") from exc


def _section_values(data: dict, where: str) -> dict[str, dict[str, object]]:
    """Section -> attribute -> value in SI units, every key checked against SCHEMA."""
    allowed_sections = ", ".join(f"[{s}]" for s in SCHEMA)
    values: dict[str, dict[str, object]] = {section: {} for section in SCHEMA}
    for section, table in data.items():
        if section not in SCHEMA:
            what = "section" if isinstance(table, dict) else "top-level key"
            raise InputError(
                f"{where}: unknown {what} {section!r}{_did_you_mean(section, SCHEMA, '[{}]')}; "
                f"allowed sections: {allowed_sections}"
            )
        if not isinstance(table, dict):
            raise InputError(f"{where}: [{section}] must be a table (a [{section}] section), got {describe(table)}")
        keys = SCHEMA[section]
        for key, value in table.items():
            if key not in keys:
                raise InputError(
                    f"{where}: unknown key {key!r} in [{section}]{_did_you_mean(key, keys, '{}')}; "
                    f"allowed: {', '.join(keys)}"
                )
            attr, kind, factor, rule = keys[key]
            try:
                if (section, key) == ("region", "rings"):
                    value = check_rings(value, f"[{section}] {key}")
                else:
                    value = check_value(value, kind, rule, f"[{section}] {key}")
            except InputError as exc:
                raise InputError(f"{where}: {exc}") from None
            if kind is float and factor != 1.0:
                value = value / factor  # mm -> m: divide (correctly rounded: 10 mm is exactly 0.01)
            values[section][attr] = value
    return values


def _mesh_path(raw_mesh, scene_path: Path, where: str) -> Path:
    """[mesh] path, absolute (relative to the scene file's folder); it must name a file."""
    if raw_mesh is None:
        raise InputError(f"{where}: missing [mesh] path (the mesh file, relative to the scene file)")
    mesh_path = Path(os.path.abspath(scene_path.parent / Path(str(raw_mesh)).expanduser()))
    if not mesh_path.exists():
        raise InputError(f"{where}: mesh file not found: {mesh_path} ([mesh] path = {raw_mesh!r})")
    if mesh_path.is_dir():
        raise InputError(f"{where}: [mesh] path = {raw_mesh!r} is a directory, not a mesh file ({mesh_path})")
    return mesh_path


def _did_you_mean(word: str, choices, fmt: str) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {fmt.format(close[0])}?)" if close else ""


# -- the scenes shipped with the package -----------------------------------------------------
def scenes_dir() -> Path:
    """The folder of the scenes shipped with the package.

    Installed: ``almsdm_warp/scenes`` inside the package (where pyproject maps ``scenes/``).
    Source checkout: ``scenes/`` next to the package folder.
    """
    here = Path(__file__).resolve().parents[1]  # the package folder
    candidates = [here / "scenes", here.parent / "scenes"]
    for folder in candidates:
        if (folder / f"{DEFAULT_SCENE}.toml").is_file():
            return folder
    tried = ", ".join(str(c) for c in candidates)
    raise InputError(f"the package's scenes are missing (looked in {tried}); reinstall almsdm_warp")


def scene_names() -> list[str]:
    """The names of the scenes shipped with the package (sorted)."""
    return sorted(p.stem for p in scenes_dir().glob("*.toml"))


def default_scene_path(name: str = DEFAULT_SCENE) -> Path:
    """The path of a scene shipped with the package: ``stomach`` (the default) or ``liver``."""
    stem = name[:-5] if name.lower().endswith(".toml") else name
    path = scenes_dir() / f"{stem}.toml"
    if not path.is_file():
        raise InputError(f"no scene named {name!r}; the package has: {', '.join(scene_names())}")
    return path


def resolve_scene_or_mesh(arg=None, *, scale_mm: float = 1.0, tissue: str | None = None) -> Scene:
    """A scene from what a user typed.

    None: the default scene (stomach). A path ending in ``.toml``: that scene file. The name
    of a shipped scene (``liver``) that is not a file here: that scene. Anything else: a mesh
    file, read at `scale_mm` millimetres per file unit, with the press defaults and the tissue
    preset `tissue` (tissue.presets; default DEFAULT_PRESET): its material, probe and rings, and a
    support chosen from the mesh (Scene.support "auto").
    """
    if arg is None:
        return load_scene(default_scene_path())
    p = Path(arg)
    if p.suffix.lower() == ".toml":
        return load_scene(p)
    if not p.exists() and p.suffix == "" and p.name == str(arg):
        try:
            scene = default_scene_path(p.name)
        except InputError:
            scene = None
        if scene is not None:
            return load_scene(scene)
    if not p.exists():
        hint = f", or one of the scenes: {', '.join(scene_names())}" if p.suffix == "" else ""
        raise InputError(f"{arg}: no such file (give a scene .toml or a mesh file{hint})")
    if p.is_dir():
        raise InputError(f"{arg}: is a directory, not a scene or mesh file")
    scale_mm = check_value(scale_mm, float, "> 0", "scale_mm")
    return mesh_scene(Path(os.path.abspath(p)), scale_mm, tissue)


def mesh_scene(mesh_path, scale_mm: float = 1.0, tissue: str | None = None) -> Scene:
    """The scene of a bare mesh file: the tissue preset `tissue` (default DEFAULT_PRESET) with its probe and
    rings, the press defaults, and the support chosen from the mesh ("auto"). InputError for an unknown preset."""
    try:
        preset = tissue_preset(DEFAULT_PRESET if tissue is None else tissue)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    return Scene(path=None, mesh_path=Path(mesh_path), scale_mm=scale_mm, tissue=preset.tissue, rings=preset.rings,
                 probe_radius=preset.probe_radius, support="auto", preset=preset.name)
