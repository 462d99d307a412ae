"""Sizes of the LiCROM networks and the frame of the model (:class:`ModelConfig`)."""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from decimal import Decimal
from typing import Any

import numpy as np

from ..._limits import blame, check_memory
from ...errors import ConfigError
from ...rigid import check_frame

__all__ = ["MIN_FIELD_WIDTH", "ModelConfig", "field_width_for"]

MIN_FIELD_WIDTH = 256
"""Narrowest field of ``field_width="auto"``: width 60 left 1.6x, 128 1.2x and 256 1.01x the held-out projection
error of POD(8) on the demo data (body frame, POD objective, 60 epochs)."""


def field_width_for(r: int) -> int:
    """The field width ``"auto"`` gives r learned modes: every mode is a combination of the last hidden layer's
    functions, so twice r, at least :data:`MIN_FIELD_WIDTH`, rounded up to a multiple of 64. At r = 250 and width 256
    the ball's learned modes stayed 1.30x their POD after 300 epochs, at 512 1.000x after 200 (docs/results.md section 19)."""
    return max(MIN_FIELD_WIDTH, -(-2 * int(r) // 64) * 64)

# Points evaluated per batch of the field (bounds peak memory, not speed).
_CHUNK = 16384
# Bytes per network weight of a built network: the float32 weight and a float64 copy (finalisation, evaluation).
_BYTES_PER_WEIGHT = 12
# The sizes whose memory is estimated, with the values an estimate falls back to when it names the culprit.
_SIZES = {"latent_dim": 1, "field_layers": 5, "field_width": 256, "fourier_features": 32,
          "encoder_point_widths": (64, 128, 256), "encoder_fc_widths": (128,)}


def network_weights(s: Mapping[str, Any]) -> int:
    """Numbers of the networks of sizes ``s`` (the keys of ``_SIZES``; ``latent_dim`` an int), in closed form:
    exact for any size, without building the layer list ``state_size`` builds."""
    f, r, w, layers = s["fourier_features"], s["latent_dim"], s["field_width"], s["field_layers"]
    field = (3 + 2 * f) * w + w + (layers - 2) * (w * w + w) + w * 3 * r + 3 * r + 3 * f
    dims = [6, *s["encoder_point_widths"], *s["encoder_fc_widths"], r]
    return field + sum(a * b + b for a, b in itertools.pairwise(dims)) + 5


def field_floats_per_point(s: Mapping[str, Any]) -> int:
    """Numbers the field's forward pass holds per point: input and Fourier features, every hidden layer
    before and after its ELU, the 3 r output and its Jacobian (9 r)."""
    f, r = s["fourier_features"], s["latent_dim"]
    return 3 + 5 * f + 2 * (s["field_layers"] - 1) * s["field_width"] + 12 * r


def _model_bytes(s: Mapping[str, Any]) -> int:
    # the weights, and the float64 field with its gradients at _CHUNK points at a time (finalisation, Model.values)
    return _BYTES_PER_WEIGHT * network_weights(s) + _CHUNK * 16 * field_floats_per_point(s)


def model_sizes(config: ModelConfig) -> dict[str, Any]:
    """The sizes of ``config`` that memory estimates read (``latent_dim`` "auto" counts as 1 and ``field_width``
    "auto" as :data:`MIN_FIELD_WIDTH`: r is not known yet)."""
    sizes = {name: getattr(config, name) for name in _SIZES}
    if sizes["latent_dim"] == "auto":
        sizes["latent_dim"] = 1
    if sizes["field_width"] == "auto":
        sizes["field_width"] = MIN_FIELD_WIDTH
    return sizes


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of the LiCROM networks.

    Attributes:
        latent_dim: r, the number of learned modes (the latent size), an integer >= 1, or
            ``"auto"`` (the default): :func:`licrom.train` chooses r from its training data
            (:func:`licrom.learn.training.rank.choose_rank`) before it builds the networks, which
            need an integer.
        field_layers: number of linear layers of the neural field W(X) (input 3, then
            ``field_layers - 1`` hidden ELU layers, then the 3 r output), >= 2.
            5 layers of width 60 is LiCROM's network.
        field_width: width of the hidden layers of W(X), an integer >= 1, or ``"auto"`` (the
            default): :func:`field_width_for` r, twice r and at least 256, resolved as soon as r
            is an integer. Every learned mode is a combination of the last hidden layer's
            functions, and with the POD objective (whose output layer is solved exactly) width
            60 left 1.6x and width 128 1.2x the held-out projection error of POD(8) on the demo
            data, width 256 1.01x (body frame, 60 epochs).
        fourier_features: F, random Fourier features of X fed to W(X) beside X itself
            (0: LiCROM's plain input). The default 32 learned the cheese set's subspace
            2-3x more accurately per epoch than 0 (benches/training_report.py sweep).
        fourier_scale: standard deviation of the Fourier frequencies, in cycles per unit
            of normalised coordinate (the object spans about [-1, 1]).
        encoder_point_widths: widths of the shared per-point MLP of the PointNet
            encoder (applied to each sampled (X, u) point, ELU after each layer),
            before max pooling over the points.
        encoder_fc_widths: widths of the fully connected ELU layers after pooling;
            a last linear layer maps to r.
        affine: remove the affine part of every training frame and keep the learned
            modes mass-orthogonal to the 12 affine modes (True), or learn the whole
            displacement (False). In the world frame the 12 affine modes are stacked in
            front of the learned ones.
        frame: ``"body"``: the modes learn the non-rigid deformation in the body frame
            (rigid motion exact, see :mod:`licrom.reduced.body`); ``"world"``: LiCROM's
            world-frame displacement modes.

    Raises:
        ConfigError: a size out of range, or sizes whose networks (their weights and the field at ``_CHUNK``
            points) need more than the memory limit of ``licrom._limits`` (a fraction of the machine's
            physical memory, or ``LICROM_MEMORY_LIMIT``); the message names the size. Training's share
            (gradients, Adam, the step's points) is :func:`licrom.learn.training.config.check_training_memory`'s.
    """

    latent_dim: int | str = "auto"
    field_layers: int = 5
    field_width: int | str = "auto"
    fourier_features: int = 32
    fourier_scale: float = 1.0
    encoder_point_widths: tuple[int, ...] = (64, 128, 256)
    encoder_fc_widths: tuple[int, ...] = (128,)
    affine: bool = True
    frame: str = "body"

    def __post_init__(self) -> None:
        def positive_int(name: str, v: Any, minimum: int = 1) -> int:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
                raise ConfigError(f"ModelConfig.{name} must be an integer >= {minimum}, got {v!r}")
            return int(v)

        if self.latent_dim != "auto":
            object.__setattr__(self, "latent_dim", positive_int("latent_dim", self.latent_dim))
        object.__setattr__(self, "field_layers", positive_int("field_layers", self.field_layers, 2))
        auto_width = self.field_width == "auto"
        if auto_width:
            if self.latent_dim != "auto":
                object.__setattr__(self, "field_width", field_width_for(int(self.latent_dim)))
        elif isinstance(self.field_width, str):
            raise ConfigError(f"ModelConfig.field_width must be an integer >= 1 or 'auto', got {self.field_width!r}")
        else:
            object.__setattr__(self, "field_width", positive_int("field_width", self.field_width))
        object.__setattr__(self, "fourier_features", positive_int("fourier_features", self.fourier_features, 0))
        fs = self.fourier_scale
        if isinstance(fs, bool) or not isinstance(fs, (int, float, np.floating)) or not np.isfinite(fs) or fs <= 0:
            raise ConfigError(f"ModelConfig.fourier_scale must be a positive number, got {fs!r}")
        object.__setattr__(self, "fourier_scale", float(fs))
        for name in ("encoder_point_widths", "encoder_fc_widths"):
            v = getattr(self, name)
            try:
                widths = tuple(v)
            except TypeError:
                raise ConfigError(f"ModelConfig.{name} must be a sequence of integers, got {v!r}") from None
            widths = tuple(positive_int(name, w) for w in widths)
            if name == "encoder_point_widths" and not widths:
                raise ConfigError("ModelConfig.encoder_point_widths needs at least one layer")
            object.__setattr__(self, name, widths)
        if not isinstance(self.affine, (bool, np.bool_)):
            raise ConfigError(f"ModelConfig.affine must be True or False, got {self.affine!r}")
        object.__setattr__(self, "affine", bool(self.affine))
        check_frame(self.frame, "ModelConfig.frame")
        # Before anything is built: a width or rank the machine cannot hold is named, not an allocator traceback.
        sizes = model_sizes(self)
        culprit = blame(_model_bytes, sizes, _SIZES)
        if culprit == "field_width" and auto_width and self.latent_dim != "auto":
            culprit = "latent_dim"  # the width follows r: r is what was asked for
        check_memory(f"ModelConfig.{culprit}", getattr(self, culprit), _model_bytes(sizes),
                     f"{Decimal(network_weights(sizes)):.3g} network weights at {_BYTES_PER_WEIGHT} bytes each and the "
                     f"field at {_CHUNK} points at a time; the other sizes as given")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["encoder_point_widths"] = list(self.encoder_point_widths)
        d["encoder_fc_widths"] = list(self.encoder_fc_widths)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        try:
            return cls(**d)
        except TypeError as exc:
            raise ConfigError(f"unknown or missing ModelConfig fields: {exc}") from exc
