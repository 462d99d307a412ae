"""Scene files: a whole experiment (object, material, planes, sweep, initial states, time) in one TOML file.

A scene file says what ``licrom generate``, ``licrom compare`` and ``licrom demo`` simulate.
The built-in presets are scene files shipped in the package (``licrom/scenes/*.toml``:
``cheese``, ``sphere``, ``demo``) and are read by the same loader, so any of them is a
template (``licrom scene cheese -o my-scene.toml``). Every value is checked on loading;
an error names the key (``planes[1].friction``) and the accepted range, and unknown keys
and unknown versions are refused. The schema, version 1 (SI units; every table but
``object`` is optional):

```toml
version = 1                      # required
name = "my-scene"                # default: the file name
description = "..."
gravity = [0.0, 0.0, -9.81]      # m/s^2

[object]                         # required
mesh = "cheese"                  # box | sphere | cheese, or a tet mesh file (relative to this file)
resolution = 12                  # procedural shapes: cells along the longest side
size = [0.2, 0.12, 0.1]          # box, cheese: edge lengths, m
radius = 0.05                    # sphere: radius, m

[material]                       # youngs_modulus (Pa, > 0), poisson_ratio (-1, 0.5), density (kg/m^3, > 0),
                                 # viscosity (Kelvin-Voigt damping, Pa s, >= 0; default 0)
[contact]                        # normal_stiffness (N/m^3), normal_damping (N s/m^3), friction_stiffness (N s/m^3)
[solver]                         # tolerance, reduced_tolerance (m/s), max_iterations, on_failure ("raise" | "record")
[time]                           # dt (s, > 0), steps (>= 1), record_every (>= 1),
                                 # integrator ("backward_euler" | "bdf2": full simulation only),
                                 # impact_window (s, >= 0; default 0.05: every step kept this long after
                                 # each impact where record_every > 1, for training)

[[planes]]                       # any number; default: one horizontal ground, mu 0.5
slope = 20.0                     # deg in [0, 90); or normal = [nx, ny, nz] instead of slope/azimuth
azimuth = 0.0                    # deg: downhill direction, from +x towards +y
offset = 0.0                     # m: the plane is normal . x + offset >= 0
friction = 0.5                   # Coulomb mu, >= 0

[sweep]                          # one run per friction x slope x initial state
frictions = [0.1, 0.5, 0.9]      # each run gives every plane this mu
slopes = [10.0, 20.0]            # each run tilts the first plane to this slope (its azimuth and offset kept)

[[initial]]                      # any number; default: resting on the first plane
drop_height = 0.02               # m: lowest point above the first plane, or translation = [...] (world frame)
rotation = [0.0, 0.0, 0.0]       # rad, rotation vector
velocity = [0.0, 0.0, 0.0]       # m/s; with drop_height, over a horizontal ground carried onto the plane
angular_velocity = [0.0, 0.0, 0.0]  # rad/s

[[held_out]]                     # scenes kept out of training: compare and demo run them
slope = 20.0                     # deg (default: the first plane's)
friction = 0.25                  # mu (default: the first plane's)
```

The guide ``docs/guide/own-mesh.md`` walks through a scene file of one's own object.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from .._io import name_too_long
from ..errors import ConfigError, FileFormatError
from ..geometry.mesh import Mesh
from ..scene.scene import INTEGRATORS, ContactParams, InitialState, Material, Plane, Scene, SolverParams, _rotation, _vec3
from ..scene.sweep import DEFAULT_FRICTION, check_friction, held_out_pairs, slope_friction_pairs, sweep, sweep_axis, sweep_count, tilted, with_friction
from .checked_table import Table, checked_integer, checked_number
from .dataset import IMPACT_WINDOW, DatasetSpec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = [
    "SCENE_FILE_VERSION",
    "DropSpec",
    "HeldOut",
    "ObjectSpec",
    "SceneFile",
    "builtin_scenes",
    "load_scene",
    "with_mesh_file",
]

SCENE_FILE_VERSION = 1
PROCEDURAL_SHAPES = ("box", "sphere", "cheese")
_T = TypeVar("_T")


# --- the parts of a scene file --------------------------------------------------------------
@dataclass(frozen=True)
class ObjectSpec:
    """The simulated object: a procedural shape or a tet mesh file.

    Attributes:
        mesh: ``"box"``, ``"sphere"``, ``"cheese"``, or the path of a tet mesh file.
        resolution: procedural shapes: cells along the longest side (None: the shape's default).
        size: box and cheese: edge lengths in m (None: the default).
        radius: sphere: radius in m (None: the default).
    """

    mesh: str
    resolution: int | None = None
    size: tuple[float, float, float] | None = None
    radius: float | None = None

    @classmethod
    def parse(cls, source: str, resolution: int | None = None) -> ObjectSpec:
        """``box``, ``sphere``, ``cheese`` (optionally ``:RES``), or a tet mesh file (``--mesh`` on the command line)."""
        kind, sep, res = source.partition(":")
        if kind in PROCEDURAL_SHAPES:
            if sep:
                if not res.isdigit():
                    raise ConfigError(f"--mesh {kind}:RES needs an integer resolution RES, got {source!r}")
                resolution = int(res)
            return cls(kind, resolution)
        return cls(str(Path(source)), None)

    @property
    def procedural(self) -> bool:
        return self.mesh in PROCEDURAL_SHAPES

    def check(self) -> None:
        """Check, without reading it, that the mesh file exists and is not a surface (procedural shapes pass).

        Raises:
            FileFormatError: the mesh file does not exist (or is a folder).
            ConfigError: it is a surface (``.obj``, ``.stl``, ...), to be filled with tets first.
        """
        if self.procedural:
            return
        from ..geometry.surface import SURFACE_SUFFIXES

        if Path(self.mesh).suffix.lower() in SURFACE_SUFFIXES:
            raise ConfigError(f"object mesh '{self.mesh}' is a surface; fill it with tets first: licrom mesh {self.mesh} -o object.msh")
        if not Path(self.mesh).is_file():
            raise FileFormatError(f"mesh file not found: '{self.mesh}'" + (" (it is a folder)" if Path(self.mesh).is_dir() else ""))

    def build(self) -> Mesh:
        """The tet mesh: generated, or read from the file."""
        from ..geometry import meshes

        if not self.procedural:
            from ..geometry.surface import SURFACE_SUFFIXES

            if Path(self.mesh).suffix.lower() in SURFACE_SUFFIXES:
                raise ConfigError(f"object mesh '{self.mesh}' is a surface; fill it with tets first: licrom mesh {self.mesh} -o object.msh")
            return Mesh.load(self.mesh)
        kwargs: dict[str, Any] = {}
        if self.resolution is not None:
            kwargs["resolution"] = self.resolution
        if self.size is not None:
            kwargs["size"] = self.size
        if self.radius is not None:
            kwargs["radius"] = self.radius
        return meshes.PROCEDURAL[self.mesh](**kwargs)

    def describe(self) -> str:
        if not self.procedural:
            return self.mesh
        extra = [f"{k} {v}" for k, v in (("resolution", self.resolution), ("size", self.size), ("radius", self.radius)) if v is not None]
        return f"{self.mesh} ({', '.join(extra)})" if extra else self.mesh


@dataclass(frozen=True)
class DropSpec:
    """An initial state over the ground, carried onto the first plane of each run.

    Attributes:
        drop_height: height of the lowest point of the rotated object above the plane, m.
        rotation: rotation vector (axis times angle) applied first, rad.
        velocity: linear velocity over a horizontal ground (carried onto the plane), m/s.
        angular_velocity: angular velocity over a horizontal ground, rad/s.
    """

    drop_height: float = 0.0
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        _rotation("DropSpec.rotation", _vec3("DropSpec.rotation", self.rotation))

    def state(self, mesh: Mesh, density: float) -> InitialState:
        """The state over the ground ``z = 0`` (see :func:`licrom.scene.placement.drop_state`)."""
        from ..scene.placement import drop_state

        return drop_state(mesh, density, self.drop_height, self.rotation, self.velocity, self.angular_velocity)


@dataclass(frozen=True)
class HeldOut:
    """A scene kept out of training: the first plane's slope and the friction of every plane.

    Attributes:
        slope: incline in degrees, [0, 90) (None: the first plane's).
        friction: Coulomb coefficient, >= 0 (None: the first plane's).
    """

    slope: float | None = None
    friction: float | None = None


@dataclass(frozen=True)
class SceneFile:
    """A checked scene file: the object, the base scene, the sweep, the initial states, the held-out scenes.

    Attributes:
        name: the scene's name.
        description: free text.
        source: where it was read from (a path, or ``built-in NAME``).
        object: the simulated object.
        scene: material, contact, solver, gravity, time step and planes of every run.
        frictions: the friction sweep (None: the planes keep their own).
        slopes: the slope sweep of the first plane in degrees (None: the planes as given).
        initial: initial states: all :class:`DropSpec` (placed on each run's first plane) or all
            :class:`InitialState` (world frame).
        steps: time steps per run.
        record_every: record every n-th step.
        impact_window: s, every step kept this long after each impact where ``record_every > 1``
            (:data:`~licrom.data.dataset.IMPACT_WINDOW`).
        held_out: scenes kept out of training.
    """

    name: str
    description: str
    source: str
    object: ObjectSpec
    scene: Scene
    frictions: tuple[float, ...] | None = None
    slopes: tuple[float, ...] | None = None
    initial: tuple[DropSpec, ...] | tuple[InitialState, ...] = (DropSpec(),)
    steps: int = 200
    record_every: int = 1
    held_out: tuple[HeldOut, ...] = field(default=())
    impact_window: float = IMPACT_WINDOW

    def replace(self, **changes: Any) -> SceneFile:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return replace(self, **changes)

    def overridden(self, *, mesh: str | None = None, resolution: int | None = None, youngs_modulus: float | None = None,
                   poisson_ratio: float | None = None, density: float | None = None, viscosity: float | None = None, frictions: tuple[float, ...] | None = None,
                   slopes: tuple[float, ...] | None = None, dt: float | None = None, steps: int | None = None,
                   record_every: int | None = None, impact_window: float | None = None) -> SceneFile:
        """A copy with the given values replaced (None keeps the file's); the values are checked.

        ``mesh`` is ``box``, ``sphere``, ``cheese`` (optionally ``:RES``) or a tet mesh file;
        ``resolution`` applies to procedural shapes; ``frictions`` and ``slopes`` replace the sweep.

        Raises:
            ConfigError: a value out of range; the message names the option.
        """
        obj = self.object if mesh is None else ObjectSpec.parse(mesh)
        if resolution is not None:
            if not obj.procedural:
                raise ConfigError(f"resolution applies to procedural shapes ({', '.join(PROCEDURAL_SHAPES)}), not to the mesh file '{obj.mesh}'")
            obj = replace(obj, resolution=checked_integer(resolution, "resolution", 4 if obj.mesh != "box" else 1))
        m = self.scene.material
        material = Material(
            youngs_modulus=m.youngs_modulus if youngs_modulus is None else checked_number(youngs_modulus, "youngs_modulus", 0.0, lo_open=True, unit="Pa"),
            poisson_ratio=m.poisson_ratio if poisson_ratio is None else checked_number(poisson_ratio, "poisson_ratio", -1.0, 0.5, True, True),
            density=m.density if density is None else checked_number(density, "density", 0.0, lo_open=True, unit="kg/m^3"),
            viscosity=m.viscosity if viscosity is None else checked_number(viscosity, "viscosity", 0.0, unit="Pa s"),
        )
        if frictions is not None:
            frictions = tuple(check_friction(v, f"friction {v!r}") for v in frictions) or None
        if slopes is not None:
            slopes = tuple(checked_number(v, f"slope {v!r}", 0.0, 90.0, hi_open=True, unit="deg") for v in slopes) or None
            if slopes and not self.scene.planes:
                raise ConfigError(f"a slope tilts the first plane, but scene '{self.name}' has no planes")
        scene = self.scene.replace(material=material, dt=self.scene.dt if dt is None else checked_number(dt, "dt", 0.0, lo_open=True, unit="s"))
        return replace(
            self, object=obj, scene=scene, frictions=self.frictions if frictions is None else frictions,
            slopes=self.slopes if slopes is None else slopes, steps=self.steps if steps is None else checked_integer(steps, "steps", 1),
            record_every=self.record_every if record_every is None else checked_integer(record_every, "record_every", 1),
            impact_window=self.impact_window if impact_window is None else checked_number(impact_window, "impact_window", 0.0, hi_open=True, unit="s"),
        )

    @property
    def dropped(self) -> bool:
        """True when the initial states are drops placed on each run's first plane."""
        return isinstance(self.initial[0], DropSpec)

    @property
    def n_runs(self) -> int:
        """How many runs the sweep has: frictions x slopes x initial states (:func:`licrom.scene.sweep.sweep_count`)."""
        return sweep_count(self.frictions, self.slopes, self.initial)

    def initial_states(self, mesh: Mesh) -> tuple[InitialState, ...]:
        """The initial states for ``mesh`` (drops over the ground ``z = 0``, or world-frame states)."""
        density = self.scene.material.density
        return tuple(s.state(mesh, density) if isinstance(s, DropSpec) else s for s in self.initial)

    def dataset_spec(self, mesh: Mesh | None = None) -> DatasetSpec:
        """The sweep as a :class:`~licrom.data.dataset.DatasetSpec` (mesh built from :attr:`object` unless given)."""
        mesh = self.object.build() if mesh is None else mesh
        return DatasetSpec(
            name=self.name,
            mesh=mesh,
            base_scene=self.scene,
            frictions=self.frictions,
            planes=None if self.slopes is None else tuple(tilted(self.scene.planes, s) for s in self.slopes),
            initial_states=self.initial_states(mesh),
            steps=self.steps,
            record_every=self.record_every,
            initial_frame="plane" if self.dropped else "world",
            description=self.description,
            impact_window=self.impact_window,
        )

    def cases(self, mesh: Mesh, slopes: tuple[float, ...] = (), frictions: tuple[float, ...] = ()) -> list[tuple[str, Scene]]:
        """Labelled scenes to compare full and reduced on.

        ``slopes`` x ``frictions`` when either is given (the other defaults to the first
        plane's), else the held-out scenes, else every run of the sweep. Each starts from the
        first initial state.
        """
        from ..scene.placement import initial_state_on_plane

        if not self.scene.planes:
            raise ConfigError(f"scene '{self.name}' has no planes; comparisons need at least one")
        first = self.scene.planes[0]
        if slopes or frictions:
            pairs = slope_friction_pairs(slopes, frictions, first)
        elif self.held_out:
            pairs = held_out_pairs(((h.slope, h.friction) for h in self.held_out), first)
        else:  # the sweep's order: frictions outermost
            pairs = [(s, m) for m, s in sweep(sweep_axis(self.frictions, first.friction), sweep_axis(self.slopes, first.slope_deg))]
        state = self.initial_states(mesh)[0]
        out = []
        for slope, mu in pairs:
            planes = with_friction(tilted(self.scene.planes, slope, mu), mu)
            initial = initial_state_on_plane(state, planes[0], mesh, self.scene.material.density) if self.dropped else state
            out.append((f"slope {slope:g} deg, mu {mu:g}", self.scene.replace(planes=planes, initial=initial)))
        return out

    def summary(self) -> str:
        """What the file describes, in a few lines."""
        m = self.scene.material
        lines = [
            f"scene {self.name} ({self.source}): {self.description}".rstrip(": "),
            f"object     {self.object.describe()}",
            f"material   E {m.youngs_modulus:g} Pa, nu {m.poisson_ratio:g}, density {m.density:g} kg/m^3"
            + (f", viscosity {m.viscosity:g} Pa s" if m.viscosity else ""),
            f"time       dt {self.scene.dt:g} s x {self.steps} steps (record every {self.record_every}), {self.scene.integrator}",
        ]
        for i, p in enumerate(self.scene.planes):
            lines.append(f"planes[{i}]  slope {p.slope_deg:.4g} deg, azimuth {p.azimuth_deg:.4g} deg, offset {p.offset:g} m, mu {p.friction:g}")
        if not self.scene.planes:
            lines.append("planes     none")
        sweep = [f"frictions {list(self.frictions)}" if self.frictions else "", f"slopes {list(self.slopes)}" if self.slopes else ""]
        lines.append(f"sweep      {' x '.join(s for s in sweep if s) or 'none'} x {len(self.initial)} initial state(s) = {self.n_runs} runs")
        if self.held_out:
            lines.append("held out   " + ", ".join(f"(slope {h.slope}, mu {h.friction})" for h in self.held_out))
        return "\n".join(lines)


# --- loading --------------------------------------------------------------------------------
def builtin_scenes() -> tuple[str, ...]:
    """Names of the scene files shipped with licrom."""
    return tuple(sorted(p.name[:-5] for p in resources.files("licrom").joinpath("scenes").iterdir() if p.name.endswith(".toml")))


def builtin_scene_text(name: str) -> str:
    """The text of a shipped scene file."""
    if name not in builtin_scenes():
        raise ConfigError(f"no scene file {name!r} and no built-in scene of that name; built-in: {', '.join(builtin_scenes())}")
    return resources.files("licrom").joinpath("scenes", f"{name}.toml").read_text(encoding="utf-8")


def with_mesh_file(text: str, mesh: str | Path, scene_path: str | Path) -> str:
    """A scene file's ``text`` with its ``[object]`` set to the tet mesh file ``mesh``, written
    relative to the folder of ``scene_path`` (where the scene file goes), and the procedural
    shape's ``resolution`` removed (a mesh file has its own): a template for one's own object.

    Raises:
        ConfigError: the text has no ``[object]`` table with a ``mesh`` key.
    """
    mesh, folder = Path(mesh), Path(scene_path).resolve().parent
    where = mesh if mesh.is_absolute() else Path(os.path.relpath(mesh.resolve(), folder))
    lines, table, found = [], None, False
    for line in text.splitlines(keepends=True):
        head = re.match(r"\s*\[+([^\]]+)\]+", line)
        if head:
            table = head.group(1).strip()
        key = re.match(r"\s*(\w+)\s*=", line)
        if table == "object" and key and key.group(1) == "mesh":
            lines.append(f"mesh = {json.dumps(where.as_posix())}\n")
            found = True
        elif not (table == "object" and key and key.group(1) == "resolution"):
            lines.append(line)
    if not found:
        raise ConfigError("the scene file has no [object] table with a mesh key to set")
    return "".join(lines)


def load_scene(source: str | Path) -> SceneFile:
    """Read and check a scene file, or a built-in scene by name (``cheese``, ``sphere``, ``demo``).

    Raises:
        FileFormatError: the file is missing or not valid TOML.
        ConfigError: a value is missing, unknown or out of range; the message names the key.
    """
    p = Path(source)
    too_long = name_too_long(p)
    if too_long:
        raise FileFormatError(f"cannot read scene file '{p}': {too_long}")
    if p.suffix == ".toml" or p.exists():
        if not p.is_file():
            raise FileFormatError(f"scene file not found: '{p}'")
        try:
            text = p.read_text(encoding="utf-8")
        except UnicodeDecodeError as exc:
            raise FileFormatError(f"scene file '{p}' is not UTF-8 text (byte {exc.start} is {exc.object[exc.start:exc.start + 1]!r}); "
                                  "TOML files must be UTF-8: re-save it as UTF-8") from None
        except OSError as exc:
            raise FileFormatError(f"scene file '{p}' cannot be read: {exc.strerror or exc}") from None
        where, base = f"'{p}'", p.resolve().parent
        default_name = p.stem
    else:
        text, where, base, default_name = builtin_scene_text(str(source)), f"built-in {source}", None, str(source)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"scene file {where} is not valid TOML: {exc}") from None
    except RecursionError:
        raise FileFormatError(f"scene file {where} is nested too deeply to be a scene file (arrays or tables within each other "
                              "hundreds of levels deep)") from None
    try:
        return _parse(data, where, base, default_name)
    except ConfigError as exc:
        raise ConfigError(f"scene file {where}: {exc}") from None
    except RecursionError:
        raise ConfigError(f"scene file {where}: a value is nested too deeply (arrays within arrays); "
                          "scene values are numbers, strings, lists of numbers and tables") from None


def _parse(data: dict[str, Any], where: str, base: Path | None, default_name: str) -> SceneFile:
    top = Table(data, "")
    version = top.raw("version", None)
    if version is None:
        raise ConfigError(f"version is required (version = {SCENE_FILE_VERSION})")
    if isinstance(version, bool) or version != SCENE_FILE_VERSION:
        raise ConfigError(f"version {version!r} is not supported; this licrom reads version {SCENE_FILE_VERSION}")
    name = top.string("name", default_name)
    description = top.string("description", "")
    gravity = top.vector("gravity", (0.0, 0.0, -9.81), "m/s^2")

    obj = top.table("object", required=True)
    mesh = obj.string("mesh")
    resolution = obj.integer("resolution", None, lo=4 if mesh in ("sphere", "cheese") else 1)
    size = obj.vector("size", None, "m")
    if size is not None and min(size) <= 0:
        raise ConfigError(f"object.size must be 3 lengths > 0 (m), got {list(size)}")
    radius = obj.number("radius", None, 0.0, lo_open=True, unit="m")
    obj.done()
    if mesh not in PROCEDURAL_SHAPES:
        given = [k for k, v in (("resolution", resolution), ("size", size), ("radius", radius)) if v is not None]
        if given:
            raise ConfigError(f"object.{given[0]} applies to procedural shapes ({', '.join(PROCEDURAL_SHAPES)}) only, not to the mesh file '{mesh}'")
        mesh_path = Path(mesh)
        mesh = str(mesh_path if mesh_path.is_absolute() or base is None else base / mesh_path)
    elif size is not None and mesh == "sphere":
        raise ConfigError("object.size applies to box and cheese; a sphere takes object.radius")
    elif radius is not None and mesh != "sphere":
        raise ConfigError(f"object.radius applies to the sphere; a {mesh} takes object.size")
    spec = ObjectSpec(mesh, resolution, size, radius)

    positive = {"lo": 0.0, "lo_open": True}
    material = _number_table(top, "material", Material, youngs_modulus={**positive, "unit": "Pa"},
                             poisson_ratio={"lo": -1.0, "hi": 0.5, "lo_open": True, "hi_open": True}, density={**positive, "unit": "kg/m^3"},
                             viscosity={"lo": 0.0, "unit": "Pa s"})
    contact = _number_table(top, "contact", ContactParams, normal_stiffness={**positive, "unit": "N/m^3"},
                            normal_damping={"lo": 0.0, "unit": "N s/m^3"}, friction_stiffness={**positive, "unit": "N s/m^3"})
    st = top.table("solver")
    s = SolverParams()
    solver = SolverParams(
        tolerance=st.number("tolerance", s.tolerance, 0.0, lo_open=True, unit="m/s"),
        max_iterations=st.integer("max_iterations", s.max_iterations),
        on_failure=st.string("on_failure", s.on_failure, ("raise", "record")),
        reduced_tolerance=st.number("reduced_tolerance", s.reduced_tolerance, 0.0, lo_open=True, unit="m/s"),
    )
    st.done()
    tt = top.table("time")
    dt = tt.number("dt", 0.01, 0.0, lo_open=True, unit="s")
    steps = tt.integer("steps", 200)
    record_every = tt.integer("record_every", 1)
    impact_window = tt.number("impact_window", IMPACT_WINDOW, 0.0, hi_open=True, unit="s")
    integrator = tt.string("integrator", "backward_euler", INTEGRATORS)
    tt.done()

    plane_tables = top.tables("planes")
    planes = (Plane(),) if plane_tables is None else tuple(_plane(t) for t in plane_tables)

    sw = top.table("sweep")
    frictions = sw.numbers("frictions", 0.0, check=check_friction)
    slopes = sw.numbers("slopes", 0.0, 90.0, hi_open=True, unit="deg")
    sw.done()
    if slopes is not None and not planes:
        raise ConfigError("sweep.slopes tilts the first plane, but planes is empty")

    initial_tables = top.tables("initial")
    initial: tuple[DropSpec, ...] | tuple[InitialState, ...]
    if initial_tables:
        initial = _initial_states(initial_tables, bool(planes))
    elif initial_tables is None:
        initial = (DropSpec(),) if planes else (InitialState(),)
    else:
        raise ConfigError("initial must hold at least one [[initial]] table")

    held_out = []
    for t in top.tables("held_out") or []:
        h = HeldOut(slope=t.number("slope", None, 0.0, 90.0, hi_open=True, unit="deg"), friction=t.friction("friction", None))
        t.done()
        if h.slope is None and h.friction is None:
            raise ConfigError(f"{t.path} needs a slope, a friction or both")
        if not planes:
            raise ConfigError(f"{t.path} changes the first plane, but planes is empty")
        held_out.append(h)
    top.done()

    scene = Scene(material=material, planes=planes, gravity=gravity, dt=dt, integrator=integrator, contact=contact, solver=solver)
    return SceneFile(name=name, description=description, source=where, object=spec, scene=scene, frictions=frictions, slopes=slopes,
                     initial=initial, steps=steps, record_every=record_every, held_out=tuple(held_out), impact_window=impact_window)


def _number_table(top: Table, name: str, cls: type[_T], **fields: dict[str, Any]) -> _T:
    """The table ``name`` of ``top`` as a ``cls`` of numbers: each of ``fields`` read by :meth:`Table.number`
    with its keyword arguments (bounds, unit), defaulting to ``cls()``'s value."""
    table = top.table(name)
    default = cls()
    value = cls(**{field: table.number(field, getattr(default, field), **bounds) for field, bounds in fields.items()})
    table.done()
    return value


def _plane(t: Table) -> Plane:
    slope = t.number("slope", None, 0.0, 90.0, hi_open=True, unit="deg")
    azimuth = t.number("azimuth", None, unit="deg")
    normal = t.vector("normal", None)
    offset = t.number("offset", 0.0, unit="m")
    friction = t.friction("friction", DEFAULT_FRICTION)
    t.done()
    if normal is None:
        return Plane.incline(slope or 0.0, friction, offset=offset, azimuth_deg=azimuth or 0.0)
    if slope is not None or azimuth is not None:
        raise ConfigError(f"{t.path} takes either normal or slope/azimuth, not both")
    if math.hypot(*normal) < 1e-12:
        raise ConfigError(f"{t.key('normal')} must be a non-zero vector, got {list(normal)}")
    return Plane(normal=normal, offset=offset, friction=friction)


def _initial_states(tables: list[Table], has_planes: bool) -> tuple[DropSpec, ...] | tuple[InitialState, ...]:
    drops = [t.has("drop_height") for t in tables]
    if any(drops) and not all(drops):
        first_world = tables[drops.index(False)]
        raise ConfigError(f"{first_world.path}: give every initial state a drop_height (placed on the first plane) or none (world frame)")
    states: list[Any] = []
    for t in tables:
        height = t.number("drop_height", None, 0.0, unit="m")
        translation = t.vector("translation", None, "m")
        rotation = _rotation(t.key("rotation"), t.vector("rotation", (0.0, 0.0, 0.0), "rad"))
        velocity = t.vector("velocity", (0.0, 0.0, 0.0), "m/s")
        angular = t.vector("angular_velocity", (0.0, 0.0, 0.0), "rad/s")
        t.done()
        if height is None:
            states.append(InitialState(translation or (0.0, 0.0, 0.0), rotation, velocity, angular))
        elif translation is not None:
            raise ConfigError(f"{t.path} takes drop_height (placed on the first plane) or translation (world frame), not both")
        elif not has_planes:
            raise ConfigError(f"{t.key('drop_height')} places the object on the first plane, but planes is empty")
        else:
            states.append(DropSpec(height, rotation, velocity, angular))
    return tuple(states)
