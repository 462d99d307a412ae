"""The trained model: a basis (W and dW/dX at any rest point), an encoder, and its file."""

from __future__ import annotations

import copy
import os
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from ..._io import load_npz, save_npz
from ...errors import ConfigError, FileFormatError, LicromError, ShapeError
from ...geometry.mesh import Mesh, check_points
from ...scene.scene import Scene
from ...subspace.affine import AFFINE_JACOBIAN, N_AFFINE, affine_values, apply_affine, fit_affine
from ...subspace.basis import SubspaceProjector
from .config import _CHUNK, ModelConfig
from .finalize import _Finalization
from .networks import LicromNet, state_size

if TYPE_CHECKING:
    from ...subspace.cubature import Cubature

__all__ = ["MODEL_FORMAT_VERSION", "OUTSIDE_TOLERANCE", "Model"]

# Version 3 adds the fitted cubature, version 2 the frame; version 1 files are world-frame models.
MODEL_FORMAT_VERSION = 3
_READABLE_VERSIONS = (1, 2, 3)

OUTSIDE_TOLERANCE = 1e-9
"""Distance from the model's mesh, over its size, beyond which a point's learned fields are evaluated at the
nearest point of its surface (:meth:`Model.field_points`); nearer, round-off of points on the surface."""


def _real_array(name: str, a: Any) -> np.ndarray:
    """``a`` as a float64 array; ShapeError naming ``name`` for strings, complex values or objects."""
    try:
        raw = np.asarray(a)
        if raw.dtype.kind not in "biufO":
            raise TypeError(f"dtype {raw.dtype}")
        return raw.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be an array of real numbers, got {type(a).__name__} ({exc})") from None


def _check_weights(path: Any, config: ModelConfig, arrays: dict[str, np.ndarray]) -> None:
    """Refuse a header whose network sizes do not match the stored weights, before the network is built.

    The networks the header describes must hold exactly as many numbers as the file stores, so
    an absurd header (r = 10^6) is refused without allocating anything.
    """
    stored = sum(a.size for k, a in arrays.items() if k.startswith("net/"))
    needed = state_size(config)
    if needed != stored:
        raise FileFormatError(
            f"model '{path}' header does not match its weights: its model_config (latent_dim={config.latent_dim}, "
            f"field_width={config.field_width}, field_layers={config.field_layers}, fourier_features={config.fourier_features}) "
            f"needs {needed} weights, the file holds {stored}"
        )


def _check_members(path: Any, config: ModelConfig, arrays: dict[str, np.ndarray]) -> None:
    """Refuse weights and post-processing arrays that would make every value NaN or wrong, naming the member.

    Every stored number must be real and finite, the coordinate and displacement scales > 0,
    and the post-processing arrays of the shapes the header's ``latent_dim`` r gives.
    """
    r = config.latent_dim
    shapes = {"affine_correction": (12, r), "mode_transform": (r, r), "mode_transform_inv": (r, r), "mode_variance": (r,),
              "net/x_center": (3,), "net/x_scale": (), "net/u_scale": ()}
    for key in sorted(arrays):
        if not (key.startswith("net/") or key in shapes or (key.startswith("cubature/") and key != "cubature/tets")):
            continue
        a = arrays[key]
        if a.dtype.kind not in "iuf":
            raise FileFormatError(f"model '{path}' member {key} must hold real numbers, it holds dtype {a.dtype}")
        if key in shapes and a.shape != shapes[key]:
            raise FileFormatError(f"model '{path}' member {key} has shape {a.shape}; latent_dim={r} needs {shapes[key]}")
        if a.size and not np.all(np.isfinite(a)):
            raise FileFormatError(f"model '{path}' member {key} must be finite, it holds NaN or inf")
    for key in ("net/x_scale", "net/u_scale"):
        if key in arrays and not float(arrays[key]) > 0:
            raise FileFormatError(f"model '{path}' member {key} is {float(arrays[key])!r}; it must be > 0 (a length in m)")
    if "mode_variance" in arrays and np.any(arrays["mode_variance"] < 0):
        raise FileFormatError(f"model '{path}' member mode_variance holds negative values; variances must be >= 0")
    weights = arrays.get("cubature/weights")
    if weights is not None and (weights.ndim != 1 or np.any(weights < 0)):
        raise FileFormatError(f"model '{path}' member cubature/weights must be finite and >= 0 (a 1-D array of weights in m^3)")


class Model:
    """A trained LiCROM subspace; also a basis for the reduced simulation.

    Build one with :func:`licrom.train` or :meth:`Model.load`. Evaluation runs in
    float64 on the CPU by default (:meth:`to` moves it to a GPU).

    Attributes:
        config: the network sizes.
        mesh: the rest mesh trained on.
        scenes: the scenes of the training trajectories.
        default_scene: the scene a reduced simulation of this model uses by default.
        metadata: JSON-ready training information (data, split, losses, timings, ...).
        cubature: the cubature fitted at the end of training on the model's mesh
            (:meth:`licrom.Cubature.fitted`), which a reduced simulation uses by default;
            None for models saved before it was stored (format versions 1 and 2).
    """

    def __init__(
        self,
        net: LicromNet,
        mesh: Mesh,
        scenes: Sequence[Scene] = (),
        *,
        finalization: _Finalization | None = None,
        default_scene_index: int = 0,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        if not isinstance(net, LicromNet):
            raise ConfigError(f"Model needs a LicromNet, got {type(net).__name__}")
        if not isinstance(mesh, Mesh):
            raise ConfigError(f"Model needs a Mesh, got {type(mesh).__name__}")
        self.config: ModelConfig = net.config
        r = self.config.latent_dim
        self.mesh = mesh
        self.scenes: list[Scene] = list(scenes)
        if self.scenes and not 0 <= default_scene_index < len(self.scenes):
            raise ConfigError(f"default_scene_index {default_scene_index} out of range for {len(self.scenes)} scenes")
        self._default_index = int(default_scene_index)
        self.metadata: dict[str, Any] = dict(metadata or {})
        if finalization is None:
            finalization = _Finalization(np.zeros((N_AFFINE, r)), np.eye(r), np.eye(r), np.zeros(r))
        if finalization.affine_correction.shape != (N_AFFINE, r) or finalization.transform.shape != (r, r):
            raise ShapeError("model finalization arrays do not match the latent size")
        self._fin = finalization
        self._device = torch.device("cpu")
        self._net32 = net  # as trained (float32), kept for saving
        self._build_eval_net()
        self._vertex_cache: dict[str, Any] = {}
        self._own_values: np.ndarray | None = None
        self.cubature: Cubature | None = None
        self._cubature_samples: np.ndarray | None = None
        self._cubature_cache: dict[int, tuple[Mesh, Cubature]] = {}

    # --- construction helpers -------------------------------------------------------
    def _build_eval_net(self) -> None:
        net = copy.deepcopy(self._net32).to(device=self._device, dtype=torch.float64)
        net.eval()
        for p in net.parameters():
            p.requires_grad_(False)
        self._net = net
        dev = self._device
        self._C = torch.as_tensor(self._fin.affine_correction, dtype=torch.float64, device=dev)
        self._T = torch.as_tensor(self._fin.transform, dtype=torch.float64, device=dev)
        self._Tinv = torch.as_tensor(self._fin.transform_inv, dtype=torch.float64, device=dev)
        self._dA = torch.tensor(AFFINE_JACOBIAN, dtype=torch.float64, device=dev)

    def to(self, device: str | torch.device) -> Model:
        """Evaluate on ``device`` ("cpu", "cuda", ...) from now on; returns self.

        Raises:
            ConfigError: ``device`` is not a device name torch knows ("cpu", "cuda", "cuda:N", ...)
                or a ``torch.device``, or names a CUDA device that is not there.
        """
        accepted = "'cpu', 'cuda', 'cuda:N' (N = 0, 1, ...) or a torch.device"
        try:
            dev = torch.device(device)
        except (RuntimeError, TypeError, ValueError):
            raise ConfigError(f"device must be {accepted}, got {device!r}") from None
        if dev.type == "cuda":
            count = torch.cuda.device_count() if torch.cuda.is_available() else 0
            if count == 0:
                raise ConfigError(f"device {device!r} requested but no CUDA device is available here; accepted here: 'cpu'")
            if dev.index is not None and dev.index >= count:
                raise ConfigError(f"device {device!r} does not exist: {count} CUDA device(s) available (cuda:0..cuda:{count - 1})")
        previous = self._device
        self._device = dev
        try:
            self._build_eval_net()
        except BaseException:
            self._device = previous
            self._build_eval_net()
            raise
        return self

    # --- basic properties -----------------------------------------------------------
    @property
    def affine(self) -> bool:
        """Whether the learned modes are mass-orthogonal to the 12 affine modes (affine part removed in training)."""
        return self.config.affine

    @property
    def frame(self) -> str:
        """``"world"`` or ``"body"``: the frame the modes live in (see the module docstring)."""
        return self.config.frame

    @property
    def n_learned(self) -> int:
        """r, the number of learned modes."""
        return self.config.latent_dim

    @property
    def n_affine(self) -> int:
        """Affine modes stacked in front of the learned ones: 12 for an affine world-frame model, else 0."""
        return N_AFFINE if self.affine and self.frame == "world" else 0

    @property
    def n_modes(self) -> int:
        """Total number of modes: 12 + r (affine world-frame model) or r."""
        return self.n_affine + self.n_learned

    @property
    def default_scene(self) -> Scene:
        """The scene a reduced simulation uses unless told otherwise (the first training scene)."""
        if not self.scenes:
            return Scene()
        return self.scenes[self._default_index]

    @property
    def normalization(self) -> dict[str, Any]:
        """Input centre (m), input scale (m) and output scale (m) used by the networks."""
        return {
            "x_center": self._net32.x_center.detach().cpu().numpy().astype(np.float64).tolist(),
            "x_scale": float(self._net32.x_scale),
            "u_scale": float(self._net32.u_scale),
        }

    @property
    def mode_variance(self) -> np.ndarray:
        """(r,) mean squared latent coordinate of each learned mode over the training frames, m^2."""
        return self._fin.mode_variance.copy()

    @property
    def net(self) -> LicromNet:
        """The trained float32 networks (encoder and field)."""
        return self._net32

    def __repr__(self) -> str:
        return f"Model(frame={self.frame!r}, n_learned={self.n_learned}, affine={self.affine}, n_modes={self.n_modes}, mesh={self.mesh!r})"

    # --- the learned field ------------------------------------------------------------
    def _learned_values_t(self, x: torch.Tensor) -> torch.Tensor:
        w = self._net.raw_field(x)
        if self.affine:
            w = w - torch.einsum("pic,cr->pir", affine_values(x), self._C)
        return w @ self._T

    def _learned_jacobians_t(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Values (p, 3, r) and Jacobians (p, 3, 3, r) of the learned modes at raw points x."""
        from torch.func import jacfwd, vmap

        net = self._net

        def f(xh: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            out = net.field(xh)  # (3, r)
            return out, out

        xh = net.normalize(x)
        with warnings.catch_warnings():
            # torch builds its forward-mode decompositions with the deprecated torch.jit.script
            # on first use; that warning is about torch's internals, not about this call.
            warnings.filterwarnings("ignore", message=".*torch.jit.script.*", category=FutureWarning)
            jac, val = vmap(jacfwd(f, has_aux=True))(xh)  # jac (p, 3, r, 3): d out_ic / d xh_j
        val = net.u_scale * val
        jac = (net.u_scale / net.x_scale) * jac.permute(0, 1, 3, 2)  # (p, 3, 3, r): [i, j, c]
        if self.affine:
            val = val - torch.einsum("pic,cr->pir", affine_values(x), self._C)
            jac = jac - torch.einsum("ijc,cr->ijr", self._dA, self._C)[None]
        return val @ self._T, jac @ self._T

    def values(self, points: Any) -> np.ndarray:
        """(p, 3, n_modes) float64 basis values ``B(X)`` at points (p, 3); affine modes first (world frame).

        For a body-frame model these are the r learned body-frame displacement fields. The learned
        fields are evaluated at points outside the model's mesh as at the nearest point of its
        surface (:meth:`field_points`).
        """
        x = check_points(points)
        if x.shape == self.mesh.vertices.shape and np.array_equal(x, self.mesh.vertices):
            # The model's own vertices: every reduced simulation of it asks for them, and a network pass at all of
            # them takes 1 s at 120k tets and r = 250. Kept once, shared with the projector's cache.
            return self._own_vertex_values().copy()
        return self._values_at(x)

    def _own_vertex_values(self) -> np.ndarray:
        if self._own_values is None:
            self._own_values = self._values_at(self.mesh.vertices)
        return self._own_values

    def field_points(self, points: Any) -> np.ndarray:
        """The points at which the learned fields are evaluated for ``points`` (p, 3): each point of the
        model's mesh itself, each point farther outside it than :data:`OUTSIDE_TOLERANCE` of its size
        moved to the nearest point of its surface (:meth:`licrom.Mesh.nearest_surface_points`).

        The network is trained at the mesh's own points and extrapolates without bound beyond it:
        on a coarser mesh of the same cheese, whose surface lies up to 3 mm outside the 120k-tet
        training mesh, a model's modes reached 6000 at those vertices against at most 32 on its own
        (docs/results.md section 63), and every reduced run on that mesh failed. Held constant
        along the move, the fields stay continuous across the mesh's surface.
        """
        x = check_points(points)
        if x is self.mesh.vertices:
            return x
        tets, bary = self.mesh.locate(x)
        clamped = np.einsum("pa,pai->pi", bary, self.mesh.vertices[self.mesh.tets[tets]])
        outside = np.linalg.norm(clamped - x, axis=1) > OUTSIDE_TOLERANCE * self.mesh.size
        if not outside.any():
            return x
        moved = x.copy()
        moved[outside] = self.mesh.nearest_surface_points(x[outside])
        return moved

    def _values_at(self, x: np.ndarray) -> np.ndarray:
        out = np.empty((len(x), 3, self.n_modes))
        if self.n_affine:
            out[:, :, :N_AFFINE] = affine_values(x)
        x = self.field_points(x)
        with torch.no_grad():
            for s in range(0, len(x), _CHUNK):
                xt = torch.tensor(x[s : s + _CHUNK], device=self._device)
                out[s : s + _CHUNK, :, self.n_affine :] = self._learned_values_t(xt).cpu().numpy()
        return out

    def jacobians(self, points: Any) -> np.ndarray:
        """(p, 3, 3, n_modes) float64 ``J[p, i, j, c] = d B_ic / d X_j`` at points (p, 3).

        ``F = I + sum_c J[:, :, :, c] q_c`` is the deformation gradient of ``u = B q``. Outside the
        model's mesh the learned fields' Jacobians are those at the point :meth:`field_points` gives.
        """
        return self.values_and_jacobians(points)[1]

    def values_and_jacobians(self, points: Any) -> tuple[np.ndarray, np.ndarray]:
        """Both :meth:`values` and :meth:`jacobians` in one pass."""
        x = check_points(points)
        vals = np.empty((len(x), 3, self.n_modes))
        jacs = np.empty((len(x), 3, 3, self.n_modes))
        if self.n_affine:
            vals[:, :, :N_AFFINE] = affine_values(x)
            jacs[:, :, :, :N_AFFINE] = AFFINE_JACOBIAN
        x = self.field_points(x)
        with torch.no_grad():
            for s in range(0, len(x), _CHUNK):
                xt = torch.tensor(x[s : s + _CHUNK], device=self._device)
                v, j = self._learned_jacobians_t(xt)
                vals[s : s + _CHUNK, :, self.n_affine :] = v.cpu().numpy()
                jacs[s : s + _CHUNK, :, :, self.n_affine :] = j.cpu().numpy()
        return vals, jacs

    # --- projection onto the subspace ---------------------------------------------------
    def _vertex_system(self, mesh: Mesh | None) -> tuple[Mesh, np.ndarray, SubspaceProjector]:
        """Basis at the vertices of ``mesh`` (default: the model mesh) and its mass-weighted projector."""
        m = self.mesh if mesh is None else mesh
        key = "model" if mesh is None else str(id(mesh))
        hit = self._vertex_cache.get(key)
        if hit is not None and hit[0] is m:
            return hit
        basis = self._own_vertex_values() if mesh is None else self._values_at(m.vertices)  # (n, 3, k)
        entry = (m, basis, SubspaceProjector(basis, m.vertex_masses(1.0)))  # relative weights: a homogeneous density cancels
        if mesh is None or len(self._vertex_cache) < 4:
            self._vertex_cache[key] = entry
        return entry

    def project(self, displacements: Any, mesh: Mesh | None = None) -> np.ndarray:
        """Exact mass-weighted projection ``q = M_r^-1 B^T M u`` onto the subspace.

        Args:
            displacements: (n, 3) or (f, n, 3) vertex displacements of ``mesh`` in m
                (body-frame displacements for a body-frame model).
            mesh: the mesh they live on; default the model's rest mesh. Any mesh of the
                same object works (the basis is continuous).

        Returns:
            (n_modes,) or (f, n_modes) reduced coordinates.
        """
        m, _basis, projector = self._vertex_system(mesh)
        u = _real_array("displacements", displacements)
        single = u.ndim == 2
        if single:
            u = u[None]
        if u.ndim != 3 or u.shape[1:] != (m.n_vertices, 3):
            raise ShapeError(f"displacements must have shape (n, 3) or (f, n, 3) with n = {m.n_vertices}, got {np.shape(displacements)}")
        if not np.isfinite(u).all():
            raise ShapeError("displacements hold NaN or inf; project needs finite values")
        q = projector.project(u)
        return q[0] if single else q

    def reconstruct(self, q: Any, mesh: Mesh | None = None) -> np.ndarray:
        """Vertex displacements ``B q`` (n, 3) or (f, n, 3) of the model mesh (or ``mesh``)."""
        _m, basis, _ = self._vertex_system(mesh)
        qa = _real_array("q", q)
        if qa.ndim not in (1, 2) or qa.shape[-1] != self.n_modes:
            raise ShapeError(f"q must have shape ({self.n_modes},) or (f, {self.n_modes}), got {qa.shape}")
        if not np.isfinite(qa).all():
            raise ShapeError("q holds NaN or inf; reconstruct needs finite reduced coordinates")
        return (qa @ basis.reshape(-1, self.n_modes).T).reshape(*qa.shape[:-1], *basis.shape[:2])

    # --- encoder ------------------------------------------------------------------------
    def _split_affine(self, x: np.ndarray, u: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(affine coefficients in q, residual)`` of a world-frame field, as in training."""
        if not self.affine and self.frame == "world":
            return np.zeros(0), u
        w = np.ones(len(x)) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (len(x),) or np.any(w < 0) or not np.isfinite(w).all() or w.sum() <= 0:
            raise ShapeError(f"weights must be ({len(x)},) non-negative and not all zero")
        if self.frame == "body":
            from ...rigid import body_frame_displacements

            u = body_frame_displacements(x + u, x, w)
        if not self.affine:
            return np.zeros(0), u
        # Fewer than 4 weighted points, or all in one plane, leave the affine fit's normal equations singular.
        used = x[w > 0]
        spans = int(np.linalg.matrix_rank(used - used.mean(axis=0))) if len(used) > 1 else 0
        if spans < 3:
            raise ShapeError(f"points must span 3-D space for the affine fit that encode removes first: at least 4 points with "
                             f"weight > 0, not all in one plane; got {len(x)} point(s), {len(used)} of weight > 0, spanning "
                             f"{('a point', 'a line', 'a plane')[spans]}")
        a = fit_affine(x, u, w)
        return a[: self.n_affine], u - apply_affine(x, a)

    def encode(self, points: Any, displacements: Any, weights: Any = None) -> np.ndarray:
        """Latent z (r,) of the learned modes from a displacement field sampled at points.

        The affine part is first removed by a weighted least-squares fit (``weights``:
        (p,) lumped masses of the points, default uniform; for the model mesh's own
        vertices the masses are used automatically), then the PointNet encoder maps
        the cloud of (X, residual) to z. A body-frame model first removes the best
        rigid fit (the same weights), as in training. Use :meth:`encode_q` for the full ``q``.

        Args:
            points: (p, 3) rest positions X in m (any sampling of the object).
            displacements: (p, 3) world-frame displacements u at those points in m.
            weights: optional (p,) weights of the affine fit.

        Raises:
            ShapeError: misshapen or non-finite points, displacements or weights, no points, or (a model with
                affine modes, or in the body frame) points that do not span 3-D space: fewer than 4 of weight
                > 0, or all in one plane, leave the affine fit undetermined.
        """
        return self.encode_q(points, displacements, weights)[self.n_affine :]

    def encode_q(self, points: Any, displacements: Any, weights: Any = None) -> np.ndarray:
        """Reduced coordinates (n_modes,): ``[a; z]`` (world frame: the affine fit, then :meth:`encode`) or ``z`` (body frame)."""
        x = check_points(points)
        u = check_points(displacements, "displacements")
        if u.shape != x.shape:
            raise ShapeError(f"points and displacements must have the same shape, got {x.shape} and {u.shape}")
        if len(x) == 0:
            raise ShapeError("points must hold at least one point (p >= 1), got none")
        if weights is None and x.shape == self.mesh.vertices.shape and np.array_equal(x, self.mesh.vertices):
            weights = self.mesh.vertex_masses(1.0)
        a, res = self._split_affine(x, u, weights)
        with torch.no_grad():
            xt = torch.tensor(x, device=self._device)[None]
            ut = torch.tensor(res, device=self._device)[None]
            z_raw = self._net.encode_normalized(xt, ut)[0]
            z = (self._Tinv @ z_raw).cpu().numpy()
        return np.concatenate([a, z])

    # --- cubature -------------------------------------------------------------------------
    def set_cubature(self, cubature: Cubature, samples: np.ndarray) -> None:
        """Store the cubature a reduced simulation of this model uses by default, with the reduced
        coordinates ``samples`` (S, n) it was fitted to (they refit it on other meshes, :meth:`cubature_for`).

        Raises:
            ShapeError: tets not of the model's mesh, or samples of the wrong shape or not finite.
        """
        from ...subspace.cubature import Cubature

        if not isinstance(cubature, Cubature):
            raise ShapeError(f"cubature must be a licrom.Cubature, got {type(cubature).__name__}")
        tets = np.asarray(cubature.tets)
        if tets.ndim != 1 or not np.issubdtype(tets.dtype, np.integer) or (len(tets) and (tets.min() < 0 or tets.max() >= self.mesh.n_tets)):
            raise ShapeError(f"cubature tets must be integer indices in [0, {self.mesh.n_tets}) of the model's mesh")
        n = self.n_modes + (6 if self.frame == "body" else 0)
        q = np.asarray(samples, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != n or not np.all(np.isfinite(q)):
            raise ShapeError(f"cubature samples must be finite with shape (S, {n}), got {q.shape}")
        self.cubature = cubature
        self._cubature_samples = q
        self._cubature_cache = {}

    @property
    def cubature_samples(self) -> np.ndarray | None:
        """(S, n) reduced coordinates of the training poses :attr:`cubature` was fitted to (None without one):
        refit it with other settings by :meth:`licrom.Cubature.fitted`."""
        return None if self._cubature_samples is None else self._cubature_samples.copy()

    def cubature_for(self, mesh: Mesh | None = None) -> Cubature | None:
        """The fitted cubature on ``mesh`` (default: the model's mesh); None when the model has none.

        On the model's own mesh this is :attr:`cubature`. On another mesh of the object it is
        refitted (:meth:`licrom.Cubature.fitted`) to the same training poses, whose reduced
        coordinates carry over unchanged, with the tolerance, size and candidate count of the stored fit; the
        result is kept for the next call with the same mesh object.
        """
        if self.cubature is None or self._cubature_samples is None:
            return None
        if mesh is None or mesh is self.mesh or (mesh.vertices.shape == self.mesh.vertices.shape and mesh.tets.shape == self.mesh.tets.shape
                                                  and np.array_equal(mesh.vertices, self.mesh.vertices) and np.array_equal(mesh.tets, self.mesh.tets)):
            return self.cubature
        hit = self._cubature_cache.get(id(mesh))
        if hit is not None and hit[0] is mesh:
            return hit[1]
        from ...subspace.cubature import FIT_TOLERANCE, Cubature

        info = self.metadata.get("cubature", {})
        given = info.get("candidates")
        refit = Cubature.fitted(self, self._cubature_samples, mesh, count=int(info.get("max_count", 1000)),
                                tolerance=float(info.get("tolerance", FIT_TOLERANCE)), candidates=None if given is None else int(given))
        self._cubature_cache = {id(mesh): (mesh, refit)}
        return refit

    # --- file ---------------------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the model to one file atomically (``.npz`` container, JSON header, no pickle).

        Any file name works; ``.lcm`` is the conventional extension.
        """
        p = Path(path)
        state = self._net32.state_dict()
        arrays: dict[str, np.ndarray] = {f"net/{k}": v.detach().cpu().numpy() for k, v in state.items()}
        arrays.update(
            rest_vertices=np.asarray(self.mesh.vertices),
            tets=np.asarray(self.mesh.tets),
            affine_correction=self._fin.affine_correction,
            mode_transform=self._fin.transform,
            mode_transform_inv=self._fin.transform_inv,
            mode_variance=self._fin.mode_variance,
        )
        if self.cubature is not None and self._cubature_samples is not None:
            arrays.update({"cubature/tets": np.asarray(self.cubature.tets, dtype=np.int64),
                           "cubature/weights": np.asarray(self.cubature.weights, dtype=np.float64),
                           "cubature/samples": self._cubature_samples})
        header = {
            "kind": "model",
            "version": MODEL_FORMAT_VERSION,
            "model_config": self.config.to_dict(),
            "n_learned": self.n_learned,
            "affine": self.affine,
            "frame": self.frame,
            "normalization": self.normalization,
            "scenes": [s.to_dict() for s in self.scenes],
            "default_scene": self._default_index,
            "state_keys": sorted(state.keys()),
            "metadata": self.metadata,
            "cubature": None if self.cubature is None else {"scheme": self.cubature.scheme, "fit_error": self.cubature.fit_error},
            "saved_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "torch_version": torch.__version__,
        }
        save_npz(p, arrays, header)
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> Model:
        """Read a model written by :meth:`save` (no training data needed).

        Version 1 files (before the frame was recorded) load as world-frame models; files
        before version 3 have no fitted cubature (:attr:`cubature` is None).

        Raises:
            FileFormatError: missing, truncated or foreign file, unknown format version,
                or incomplete/inconsistent contents.
        """
        header, arrays = load_npz(path, "model")
        version = header.get("version")
        if isinstance(version, bool) or version not in _READABLE_VERSIONS:
            raise FileFormatError(
                f"model '{path}' has format version {version!r}; this licrom reads versions {', '.join(map(str, _READABLE_VERSIONS))}"
            )
        try:
            config_dict = dict(header["model_config"])
            if version == 1:
                config_dict["frame"] = "world"
            config = ModelConfig.from_dict(config_dict)
            if (int(header["n_learned"]) != config.latent_dim or bool(header["affine"]) != config.affine
                    or header.get("frame", "world") != config.frame):
                raise FileFormatError(f"model '{path}' header is inconsistent (n_learned/affine/frame vs model_config)")
            keys = header["state_keys"]
            _check_weights(path, config, arrays)
            _check_members(path, config, arrays)
            net = LicromNet(config)
            state = {}
            for k in keys:
                state[k] = torch.from_numpy(np.ascontiguousarray(arrays[f"net/{k}"]))
            net.load_state_dict(state, strict=True)
            mesh = Mesh(arrays["rest_vertices"], arrays["tets"], fix_orientation=False)
            scenes = [Scene.from_dict(s) for s in header["scenes"]]
            fin = _Finalization(
                np.asarray(arrays["affine_correction"], dtype=np.float64),
                np.asarray(arrays["mode_transform"], dtype=np.float64),
                np.asarray(arrays["mode_transform_inv"], dtype=np.float64),
                np.asarray(arrays.get("mode_variance", np.zeros(config.latent_dim)), dtype=np.float64),
            )
            net.eval()
            model = cls(net, mesh, scenes, finalization=fin, default_scene_index=int(header.get("default_scene", 0)), metadata=header.get("metadata", {}))
            cub = header.get("cubature")
            if version >= 3 and cub is not None:
                from ...subspace.cubature import Cubature

                tets = np.asarray(arrays["cubature/tets"])
                if tets.ndim != 1 or not np.issubdtype(tets.dtype, np.integer) or (len(tets) and (tets.min() < 0 or tets.max() >= mesh.n_tets)):
                    raise FileFormatError(f"model '{path}' member cubature/tets is not a list of tet indices of its mesh")
                fit_error = cub.get("fit_error")
                model.set_cubature(Cubature(tets, np.asarray(arrays["cubature/weights"], dtype=np.float64), mesh.centroids[tets], str(cub["scheme"]),
                                            None if fit_error is None else float(fit_error)), arrays["cubature/samples"])
            return model
        except FileFormatError:
            raise
        except (KeyError, TypeError, ValueError, RuntimeError, AttributeError, IndexError, OverflowError, LicromError) as exc:
            raise FileFormatError(f"model '{path}' is incomplete or inconsistent: {type(exc).__name__}: {exc}") from exc
