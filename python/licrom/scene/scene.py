"""Scene description: material, contact planes, contact stiffnesses, time step, initial state.

All quantities are SI. Every dataclass is frozen and validated on construction,
so a scene that exists is a scene that can be simulated. ``Scene.to_json`` /
``Scene.from_json`` round-trip exactly and carry a format version.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from .._io import check_version
from ..errors import ConfigError, FileFormatError

__all__ = [
    "INTEGRATORS",
    "MAX_PLANE_OFFSET",
    "ROTATION_LIMIT",
    "SCENE_FORMAT_VERSION",
    "ContactParams",
    "InitialState",
    "Material",
    "Plane",
    "Scene",
    "SolverParams",
]

SCENE_FORMAT_VERSION = 1

INTEGRATORS = ("backward_euler", "bdf2")
"""Accepted ``Scene.integrator`` values: backward Euler, or the second-order backward differentiation formula
(BDF2, full simulation only for now; its first step after a start or ``set_state`` is backward Euler)."""


def _finite(name: str, value: float, *, positive: bool = False, nonnegative: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ConfigError(f"{name} must be finite, got {v}")
    if positive and v <= 0.0:
        raise ConfigError(f"{name} must be > 0, got {v}")
    if nonnegative and v < 0.0:
        raise ConfigError(f"{name} must be >= 0, got {v}")
    return v


ROTATION_LIMIT = 1e6
"""Largest accepted length of a rotation vector (axis times angle), rad: about 160,000 turns. Beyond it
the angle's float64 spacing passes 1e-10 rad, and past about 1e154 its length overflows to inf."""


def _rotation(name: str, value: tuple[float, float, float]) -> tuple[float, float, float]:
    """``value`` (3 finite numbers) if its length is at most :data:`ROTATION_LIMIT`, else a ConfigError naming ``name``."""
    angle = math.hypot(*value)
    if not angle <= ROTATION_LIMIT:
        raise ConfigError(f"{name} must be a rotation vector of length <= {ROTATION_LIMIT:g} rad (axis times angle), "
                          f"got length {angle:.4g} rad")
    return value


def _vec3(name: str, value: Any) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be 3 real numbers, got {value!r}") from None
    if arr.shape != (3,):
        raise ConfigError(f"{name} must be 3 real numbers, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got {arr.tolist()}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@dataclass(frozen=True)
class Material:
    """Homogeneous stable Neo-Hookean material (Smith et al. 2018), with an optional Kelvin-Voigt damping.

    The damping is a dissipation potential on the rate of the Green strain ``E = (F^T F - I)/2``,
    ``eta/2 |dE/dt|^2`` per unit volume: a viscous stress that resists deformation and leaves a rigid
    motion (a spin included) undamped. Without it an undamped soft body rings at small time steps, and
    the full simulation does not converge in h (docs/results.md, section 12).

    Attributes:
        youngs_modulus: Young's modulus E in Pa, > 0.
        poisson_ratio: Poisson ratio nu, in (-1, 0.5).
        density: mass density rho in kg/m^3, > 0.
        viscosity: Kelvin-Voigt viscosity eta in Pa s, >= 0 (0: no material damping). ``eta / E`` is the
            time over which a strain relaxes: 400 Pa s on E = 20 kPa is 20 ms.
    """

    youngs_modulus: float = 1.0e5
    poisson_ratio: float = 0.3
    density: float = 1000.0
    viscosity: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "youngs_modulus", _finite("Material.youngs_modulus (Pa)", self.youngs_modulus, positive=True))
        nu = _finite("Material.poisson_ratio", self.poisson_ratio)
        if not -1.0 < nu < 0.5:
            raise ConfigError(f"Material.poisson_ratio must be in (-1, 0.5), got {nu}")
        object.__setattr__(self, "poisson_ratio", nu)
        object.__setattr__(self, "density", _finite("Material.density (kg/m^3)", self.density, positive=True))
        object.__setattr__(self, "viscosity", _finite("Material.viscosity (Pa s)", self.viscosity, nonnegative=True))

    @property
    def lame(self) -> tuple[float, float]:
        """Linear-elastic Lame parameters ``(mu, lambda)`` in Pa."""
        e, nu = self.youngs_modulus, self.poisson_ratio
        return e / (2.0 * (1.0 + nu)), e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def snh_parameters(self) -> tuple[float, float]:
        """Stable Neo-Hookean ``(mu, lambda)`` in Pa that match linear elasticity at small strain.

        Smith et al. 2018, section 3.4: ``mu' = 4/3 mu``, ``lambda' = lambda + 5/6 mu``.
        """
        mu, lam = self.lame
        return 4.0 / 3.0 * mu, lam + 5.0 / 6.0 * mu


MAX_PLANE_OFFSET = 1.0e6
"""Largest distance of a plane from the origin, m: the gap and the penalty energy
``k_n/2 gap^2`` of a point stay far inside double precision."""


@dataclass(frozen=True)
class Plane:
    """A frictional half-space ``normal . x + offset >= 0`` (the solid stays on the positive side).

    The normal is normalised on construction, and the offset scaled with it, so the
    half-space is the one given. Any finite non-zero normal is accepted (it is scaled
    by its largest component before its length is taken, so neither a huge nor a tiny
    one over- or underflows); the scaled offset, the plane's distance from the origin,
    must be within ``MAX_PLANE_OFFSET``.

    Attributes:
        normal: outward normal of the ground (3 finite numbers, not all zero).
        offset: signed offset in m; ``|offset| / |normal| <= MAX_PLANE_OFFSET`` (1e6 m).
        friction: Coulomb friction coefficient mu (dimensionless, >= 0).
    """

    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    offset: float = 0.0
    friction: float = 0.5

    def __post_init__(self) -> None:
        n = np.asarray(_vec3("Plane.normal", self.normal))
        largest = float(np.abs(n).max())
        if largest == 0.0:
            raise ConfigError(f"Plane.normal must be a non-zero vector, got {n.tolist()}")
        scaled = n / largest  # largest component +-1: the norm neither over- nor underflows
        length = float(np.linalg.norm(scaled))
        offset = _finite("Plane.offset (m)", self.offset)
        distance = offset / largest / length  # Python floats: inf on overflow, no exception
        if not abs(distance) <= MAX_PLANE_OFFSET:
            raise ConfigError(
                f"Plane.offset / |Plane.normal| (the plane's distance from the origin) must be within "
                f"[-{MAX_PLANE_OFFSET:g}, {MAX_PLANE_OFFSET:g}] m, got offset {offset!r} with normal {n.tolist()}"
            )
        object.__setattr__(self, "normal", tuple(float(c) for c in scaled / length))
        object.__setattr__(self, "offset", float(distance))
        object.__setattr__(self, "friction", _finite("Plane.friction", self.friction, nonnegative=True))

    @classmethod
    def incline(cls, angle_deg: float, friction: float, axis: str = "x", offset: float = 0.0, azimuth_deg: float = 0.0) -> Plane:
        """A plane through the origin (shifted by ``offset``) sloping by ``angle_deg`` in [0, 90) degrees.

        With z up, the downhill direction is +x for ``azimuth_deg = 0`` (a tilt about the y axis),
        turned towards +y by ``azimuth_deg``.
        """
        if axis != "x":
            raise ConfigError(f"Plane.incline axis must be 'x', got {axis!r}")
        angle = _finite("Plane.incline angle (deg)", angle_deg)
        if not 0.0 <= angle < 90.0:
            raise ConfigError(f"Plane.incline angle must be in [0, 90) degrees (a slope; azimuth_deg sets the downhill direction), got {angle:g}")
        t = math.radians(angle)
        a = math.radians(_finite("Plane.incline azimuth (deg)", azimuth_deg))
        return cls(normal=(math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)), offset=offset, friction=friction)

    @property
    def azimuth_deg(self) -> float:
        """Downhill direction in degrees from +x towards +y (0 for a horizontal plane)."""
        nx, ny = self.normal[0], self.normal[1]
        return math.degrees(math.atan2(ny, nx)) if math.hypot(nx, ny) > 1e-12 else 0.0

    @property
    def slope_deg(self) -> float:
        """Angle between the plane and the horizontal (z up) in degrees."""
        return math.degrees(math.acos(min(1.0, abs(self.normal[2]))))


@dataclass(frozen=True)
class ContactParams:
    """Penalty contact and implicit friction stiffnesses, per unit contact area.

    Each contact point carries its share of the boundary area ``a``, so forces
    scale with area and a coarse mesh, a fine mesh or a subsampled set of
    contact points behave alike.

    Attributes:
        normal_stiffness: k_n in N/m^3 (pressure per metre of penetration), > 0.
        normal_damping: k_d in N s/m^3 (pressure per m/s of approach speed), >= 0;
            acts only on points in contact that are approaching the plane.
        friction_stiffness: k_f in N s/m^3 (tangential traction per m/s of slip
            below the Coulomb limit), > 0. Large values make sticking stiff.
    """

    normal_stiffness: float = 1.0e7
    normal_damping: float = 0.0
    friction_stiffness: float = 1.0e7

    def __post_init__(self) -> None:
        object.__setattr__(self, "normal_stiffness", _finite("ContactParams.normal_stiffness (N/m^3)", self.normal_stiffness, positive=True))
        object.__setattr__(self, "normal_damping", _finite("ContactParams.normal_damping (N s/m^3)", self.normal_damping, nonnegative=True))
        object.__setattr__(self, "friction_stiffness", _finite("ContactParams.friction_stiffness (N s/m^3)", self.friction_stiffness, positive=True))


@dataclass(frozen=True)
class SolverParams:
    """Newton solver settings of the full and the reduced simulation.

    Convergence is measured by the mass-weighted RMS length of the Newton step,
    divided by the time step: ``sqrt(dx^T M dx / m_total) / h`` in m/s. It is
    invariant under a change of basis, so a full and a reduced solve given the
    same threshold stop at the same accuracy.

    The reduced solvers stop at their own, looser threshold by default: a reduced
    model differs from the full one by percents of the motion, and solving its
    equations beyond 1e-4 m/s changed no measured error (held-out runs of four
    objects: non-rigid error and final centre of mass the same to 0.1 point,
    chaotic runs within their noise floor) while it cost a fifth to a third of the
    Newton iterations (docs/results.md section 11, "The reduced solver's tolerance").

    Attributes:
        tolerance: the full simulation's threshold on that velocity, in m/s, > 0.
        max_iterations: Newton iterations allowed per step before giving up.
        on_failure: ``"raise"`` (raise SolverError) or ``"record"`` (keep the last
            iterate, flag the step as unconverged in the trajectory).
        reduced_tolerance: the reduced simulations' threshold (``ReducedSim``,
            ``BodyFrameSim``), in m/s, > 0. Set it to ``tolerance`` to solve a
            reduced model as tightly as the full one (a full-space basis then
            reproduces the full run to that accuracy).
    """

    tolerance: float = 1.0e-6
    max_iterations: int = 100
    on_failure: str = "raise"
    reduced_tolerance: float = 1.0e-4

    def __post_init__(self) -> None:
        object.__setattr__(self, "tolerance", _finite("SolverParams.tolerance (m/s)", self.tolerance, positive=True))
        object.__setattr__(self, "reduced_tolerance", _finite("SolverParams.reduced_tolerance (m/s)", self.reduced_tolerance, positive=True))
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, (int, np.integer)) or self.max_iterations < 1:
            raise ConfigError(f"SolverParams.max_iterations must be an integer >= 1, got {self.max_iterations!r}")
        object.__setattr__(self, "max_iterations", int(self.max_iterations))
        if self.on_failure not in ("raise", "record"):
            raise ConfigError(f"SolverParams.on_failure must be 'raise' or 'record', got {self.on_failure!r}")


@dataclass(frozen=True)
class InitialState:
    """Rigid placement and velocity of the rest mesh at t = 0.

    The rest mesh is rotated about its centre of mass, then translated.

    Attributes:
        translation: displacement of the centre of mass in m.
        rotation: rotation vector (axis times angle) in rad.
        velocity: linear velocity in m/s.
        angular_velocity: angular velocity in rad/s (about the centre of mass).
    """

    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("translation", "rotation", "velocity", "angular_velocity"):
            object.__setattr__(self, name, _vec3(f"InitialState.{name}", getattr(self, name)))
        _rotation("InitialState.rotation", self.rotation)

    def rotation_matrix(self) -> np.ndarray:
        """The 3x3 rotation matrix of ``rotation`` (Rodrigues' formula)."""
        r = np.asarray(self.rotation)
        angle = float(np.linalg.norm(r))
        if angle < 1e-15:
            return np.eye(3)
        k = r / angle
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * kx @ kx

    def apply(self, rest_positions: np.ndarray, masses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(positions, velocities)`` (n, 3) of the placed, moving rest shape."""
        com = (masses[:, None] * rest_positions).sum(0) / masses.sum()
        arm = (rest_positions - com) @ self.rotation_matrix().T
        positions = com + arm + np.asarray(self.translation)
        velocities = np.asarray(self.velocity) + np.cross(np.asarray(self.angular_velocity), arm)
        return positions, velocities


@dataclass(frozen=True)
class Scene:
    """Everything a simulation needs besides the mesh.

    Attributes:
        material: the solid's material.
        planes: frictional ground planes (any number, may be empty).
        gravity: gravitational acceleration in m/s^2 (z is up by convention).
        dt: time step h in s, > 0.
        integrator: time integration, one of :data:`INTEGRATORS`: ``"backward_euler"`` (first order,
            damps oscillations at large h) or ``"bdf2"`` (second order, far less damping; the full
            simulation only, the reduced simulations refuse it for now).
        contact: contact and friction stiffnesses.
        solver: Newton settings.
        initial: initial placement and velocity.
    """

    material: Material = field(default_factory=Material)
    planes: tuple[Plane, ...] = (Plane(),)
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    dt: float = 0.01
    integrator: str = "backward_euler"
    contact: ContactParams = field(default_factory=ContactParams)
    solver: SolverParams = field(default_factory=SolverParams)
    initial: InitialState = field(default_factory=InitialState)

    def __post_init__(self) -> None:
        for name, cls in (("material", Material), ("contact", ContactParams), ("solver", SolverParams), ("initial", InitialState)):
            if not isinstance(getattr(self, name), cls):
                raise ConfigError(f"Scene.{name} must be a {cls.__name__}, got {type(getattr(self, name)).__name__}")
        if isinstance(self.planes, (Plane, str, bytes)) or not hasattr(self.planes, "__iter__"):
            raise ConfigError(f"Scene.planes must be a sequence of Plane objects (planes=(Plane(...),) for one, () for "
                              f"none), got a {type(self.planes).__name__}")
        planes = tuple(self.planes)
        for p in planes:
            if not isinstance(p, Plane):
                raise ConfigError(f"Scene.planes must hold Plane objects, got {type(p).__name__}")
        object.__setattr__(self, "planes", planes)
        object.__setattr__(self, "gravity", _vec3("Scene.gravity (m/s^2)", self.gravity))
        object.__setattr__(self, "dt", _finite("Scene.dt (s)", self.dt, positive=True))
        if not isinstance(self.integrator, str) or self.integrator not in INTEGRATORS:
            raise ConfigError(f"Scene.integrator must be one of {', '.join(repr(i) for i in INTEGRATORS)}, got {self.integrator!r}")

    def replace(self, **changes: Any) -> Scene:
        """A copy with some fields changed (``dataclasses.replace``)."""
        return replace(self, **changes)

    def plane_array(self) -> np.ndarray:
        """Planes as a (p, 5) float64 array of ``[nx, ny, nz, offset, friction]``."""
        if not self.planes:
            return np.zeros((0, 5))
        return np.array([[*p.normal, p.offset, p.friction] for p in self.planes], dtype=np.float64)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict with ``format`` and ``version`` keys."""
        d = asdict(self)
        d["planes"] = [asdict(p) for p in self.planes]
        return {"format": "licrom.scene", "version": SCENE_FORMAT_VERSION, **d}

    def to_json(self, indent: int | None = 2) -> str:
        """Serialise to JSON text."""
        return json.dumps(self.to_dict(), indent=indent)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scene:
        """Inverse of :meth:`to_dict`.

        Raises:
            FileFormatError: not a licrom scene, or an unknown format version.
            ConfigError: a value is out of range.
        """
        if not isinstance(d, dict) or d.get("format") != "licrom.scene":
            raise FileFormatError("not a licrom scene: expected a JSON object with \"format\": \"licrom.scene\"")
        check_version(d.get("version"), SCENE_FORMAT_VERSION, "scene JSON")
        try:
            return cls(
                material=Material(**d["material"]),
                planes=tuple(Plane(**p) for p in d["planes"]),
                gravity=tuple(d["gravity"]),
                dt=d["dt"],
                integrator=d.get("integrator", "backward_euler"),  # absent in scenes written before BDF2
                contact=ContactParams(**d["contact"]),
                solver=SolverParams(**d["solver"]),
                initial=InitialState(**d["initial"]),
            )
        except (KeyError, TypeError) as exc:
            raise FileFormatError(f"scene JSON is missing or has unexpected fields: {exc}") from exc
        except RecursionError:
            raise FileFormatError("scene JSON is nested too deeply to be a licrom scene") from None

    @classmethod
    def from_json(cls, text: str) -> Scene:
        """Parse JSON text written by :meth:`to_json`."""
        try:
            d = json.loads(text)
        except (json.JSONDecodeError, TypeError) as exc:
            raise FileFormatError(f"scene JSON is not valid JSON: {exc}") from exc
        except RecursionError:
            raise FileFormatError("scene JSON is nested too deeply to be a licrom scene") from None
        return cls.from_dict(d)
