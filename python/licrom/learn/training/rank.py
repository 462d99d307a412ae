"""r chosen from the data: the smallest POD size whose held-out projection error meets a tolerance.

:func:`choose_rank` holds training runs out in turn (leave runs out), fits the run-balanced POD
of the other runs' residuals as the ``"pod"`` objective does (:func:`licrom.learn.training.objectives.pod_targets`),
and measures the relative mass-weighted projection error of each held-out run, in the model's
frame, for every r at once. That error is a lower bound of a reduced run's non-rigid error on a
scene like the held-out one, so r is the smallest candidate whose held-out runs meet the tolerance
(root mean square over the runs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from scipy.linalg import eigh

from ...errors import ConfigError
from ...subspace.basis import RUN_BALANCE, run_balanced_weights
from ..training_data import TrainingData

__all__ = ["DEFAULT_CANDIDATES", "DEFAULT_MAX_RANK", "DEFAULT_TOLERANCE", "RankChoice", "choose_rank"]

DEFAULT_TOLERANCE = 0.04
"""Default tolerance of the held-out runs' RMS relative projection error.

Measured on the body-frame experiments' training runs (experiments/body_frame_experiments.py): the
cheese's curve stays above it up to the cap (7.3 % at r = 120: r = 120, capped), the box's three
runs never predict each other below 19 % (r where the curve stops falling, 100), and the ball's
falls to 4.2 % at the cap (4.7 % at r = 100). At 5 % the ball took r = 100, and its rolling
held-out run ended 3.2 % of its size away in centre of mass (target 2 %; non-rigid 6.6 %): a
rolling body's contact patch travels over it, and the last modes carry it (POD of the training
runs, every tet: 3.7 % at r = 100, 1.2 % at 120). At 4 % no r meets it and the ball takes the
curve's lowest, r = 120: 2.0 % (non-rigid 6.5 %) at 1.25x the step time (docs/results.md
section 11)."""

DEFAULT_MAX_RANK = 120
"""Default cap of r: docs/results.md section 10 needed r = 120 for every held-out body-frame run to
meet its targets, and the reduced step's dense Newton system grows as (6 + r)^2 (its factorisation as r^3)."""

DEFAULT_CANDIDATES = (5, 10, 15, 20, 25, 30, 40, 50, 60, 70, 80, 100, 120)
"""r values tried by default (the cap is added when it is not among them)."""

PLATEAU = 0.01
"""Where no r meets the tolerance, r is the smallest whose held-out error is within this share of the curve's lowest."""

MAX_FOLDS = 5
"""More training runs than this are held out in this many folds (a fifth each, as the default validation split)."""

MAX_FRAMES = 1000
"""Frames used at most (every k-th frame of each run): one (F x F) eigenproblem per fold, about a second."""

QUIET_RUN = 1e-2
"""A run whose mean frame energy is below this share of the largest run's is left out of the
aggregate: its relative error measures round-off, not a subspace (a free fall, a body at rest)."""


@dataclass(frozen=True)
class RankChoice:
    """The chosen r and the measurement behind it.

    Attributes:
        rank: the chosen r.
        candidates: the r values tried, ascending.
        errors: held-out relative projection error at each candidate, the root mean square over
            the runs of each run's ``sqrt(sum_f |u_f - P u_f|_M^2 / sum_f |u_f|_M^2)`` (u the
            displacement in the model's frame, the affine part exact): what the choice uses.
        worst_errors: the worst run's, for the report.
        tolerance: the tolerance the choice met (or missed, when ``capped``).
        max_rank: the cap actually applied (``max_rank`` limited by frames and 3 n).
        capped: no candidate met the tolerance: r is the smallest within :data:`PLATEAU` of the
            lowest error of the curve (the cap where it still falls there).
        method: how runs were held out (``"leave one run out"``, ``"5 folds of runs"``, ``"the single
            run's own frames (nothing to hold out)"``, or ``"no deformation"``).
        runs: names of the runs in the aggregate.
        frame_stride: every this many frames of each run were used.
    """

    rank: int
    candidates: tuple[int, ...]
    errors: tuple[float, ...]
    worst_errors: tuple[float, ...]
    tolerance: float
    max_rank: int
    capped: bool
    method: str
    runs: tuple[str, ...]
    frame_stride: int

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (model metadata)."""
        d = asdict(self)
        for key in ("candidates", "errors", "worst_errors", "runs"):
            d[key] = list(d[key])
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RankChoice:
        """The choice recorded by :meth:`to_dict` (a model's ``metadata["rank"]``, where ``"rank"`` is the model's r
        and ``"dynamics"`` the check that may have raised this choice, ``"projection_rank"``)."""
        names = {f.name for f in fields(cls)}
        kept = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items() if k in names}
        return cls(**{**kept, "rank": d.get("dynamics", {}).get("projection_rank", d["rank"])})

    def describe(self) -> str:
        """One line per candidate and the choice, for the printed training report."""
        lines = [f"r chosen from the data ({self.method}, every {self.frame_stride} frame(s)): held-out projection error, RMS over runs / worst run"]
        for r, e, w in zip(self.candidates, self.errors, self.worst_errors):
            mark = "  <- chosen" if r == self.rank else ""
            lines.append(f"  r = {r:4d}  {100 * e:6.2f} % / {100 * w:6.2f} %{mark}")
        verdict = (f"no r up to the cap {self.max_rank} meets {100 * self.tolerance:g} %: r = {self.rank}, where the held-out error "
                   f"stops falling (within {100 * PLATEAU:g} % of its lowest; capped)" if self.capped
                   else f"r = {self.rank}: the smallest tried with error <= {100 * self.tolerance:g} % (cap {self.max_rank})")
        return "\n".join([*lines, verdict])


def _check(tolerance: Any, max_rank: Any, candidates: Any) -> tuple[float, int, tuple[int, ...] | None]:
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float, np.floating)) or not 0 < tolerance < 1:
        raise ConfigError(f"rank tolerance must be a relative error in (0, 1), got {tolerance!r}")
    if isinstance(max_rank, bool) or not isinstance(max_rank, (int, np.integer)) or max_rank < 1:
        raise ConfigError(f"max_rank must be an integer >= 1, got {max_rank!r}")
    if candidates is None:
        return float(tolerance), int(max_rank), None
    try:
        cands = tuple(candidates)
    except TypeError:
        raise ConfigError(f"rank candidates must be a sequence of integers >= 1, got {candidates!r}") from None
    if not cands or any(isinstance(r, bool) or not isinstance(r, (int, np.integer)) or r < 1 for r in cands):
        raise ConfigError(f"rank candidates must be a non-empty sequence of integers >= 1, got {candidates!r}")
    return float(tolerance), int(max_rank), tuple(sorted({int(r) for r in cands}))


def _gram(residuals: np.ndarray, masses: np.ndarray, chunk: int = 4096) -> np.ndarray:
    """Mass-weighted Gram matrix ``G_fg = sum_v m_v u_f(v) . u_g(v)`` of frames (F, n, 3), float64, by vertex chunks."""
    gram = np.zeros((len(residuals), len(residuals)))
    for v0 in range(0, residuals.shape[1], chunk):
        y = residuals[:, v0 : v0 + chunk].astype(np.float64) * np.sqrt(masses[v0 : v0 + chunk])[None, :, None]
        y = y.reshape(len(y), -1)
        gram += y @ y.T
    return gram


def _fold_errors(gram: np.ndarray, train: np.ndarray, test: np.ndarray, weights: np.ndarray, ranks: int) -> np.ndarray:
    """Squared projection errors (ranks, len(test)) of the test frames onto POD(1..ranks) of the weighted train frames.

    With ``Z = Y_train D`` (D = diag sqrt(w)) and ``D G_tt D = E L E^T``, the POD modes are
    ``Z E L^-1/2`` and a test frame's coordinates are ``L^-1/2 E^T D G_t,test``: one eigenproblem
    of the train frames gives every r, and no mode is ever formed on the mesh.
    """
    d = np.sqrt(weights)
    k = min(ranks, len(train))
    # The whole spectrum by divide and conquer, then the top k: on 500-1000 frames faster than the subset driver,
    # which took 2 s a fold on 120k-tet runs.
    lam, vec = eigh(d[:, None] * gram[np.ix_(train, train)] * d[None, :], driver="evd")
    lam, vec = lam[::-1][:k], vec[:, ::-1][:, :k]
    keep = lam > max(float(lam[0]), 1e-300) * 1e-10  # beyond the data's rank (or round-off of the Gram matrix) nothing is captured
    coef = (vec[:, keep] / np.sqrt(lam[keep])).T @ (d[:, None] * gram[np.ix_(train, test)])  # (k', test)
    captured = np.cumsum(coef**2, axis=0)
    captured = np.concatenate([captured, np.repeat(captured[-1:], ranks - len(captured), axis=0)]) if len(captured) else np.zeros((ranks, len(test)))
    return np.maximum(np.diag(gram)[test][None, :] - captured, 0.0)


def choose_rank(
    data: TrainingData,
    tolerance: float = DEFAULT_TOLERANCE,
    max_rank: int = DEFAULT_MAX_RANK,
    candidates: Sequence[int] | None = None,
) -> RankChoice:
    """The smallest r whose held-out (leave runs out) projection error is below ``tolerance``.

    For each fold of the training runs of ``data`` (each run alone when there are at most
    :data:`MAX_FOLDS`, else :data:`MAX_FOLDS` folds of runs drawn by a fixed permutation), the
    run-balanced POD (:func:`licrom.subspace.basis.run_balanced_weights`, power
    :data:`licrom.subspace.basis.RUN_BALANCE`, as the default ``"pod"`` objective) of the other runs'
    affine-free residuals is the subspace, and each held-out run's relative mass-weighted
    projection error is measured in the model's frame (the affine part exact), as
    :func:`licrom.learn.training.subspace_report` does. The runs are aggregated by the root mean square
    of their errors, each run counted the same whatever its size (quiet runs, :data:`QUIET_RUN`,
    left out): on the body-frame experiments it stayed within 1.3-1.6x of the worst *held-out*
    run's error at the chosen r, where the worst training run, a run unlike every other (the cheese
    tumbling end over end), overstated it up to 3.6x (the worst run is reported too). A single
    training run has nothing to hold out: its own frames' projection error is the curve (two halves
    in time holding each other out gave a flat curve, 36 % at every r, on the README's one run). Frames are subsampled
    to at most :data:`MAX_FRAMES`. With few runs, a run that no other run resembles is held out
    with nothing like it left, and the curve overstates (the box's 3 training runs of its 4, one
    of them the only tumbling one: 19 % at r = 120, its held-out run 1 %). In the world frame the
    errors are relative to the whole displacement, rigid motion included, so a tolerance measured
    in the body frame is looser there.

    Args:
        data: training data (its training runs only are used; its validation runs stay unseen).
        tolerance: relative projection error to meet, in (0, 1).
        max_rank: largest r, also capped by the training frames and 3 n.
        candidates: r values to try (default :data:`DEFAULT_CANDIDATES`); those above the cap are
            dropped and the cap is added.

    Returns:
        The :class:`RankChoice`.

    Raises:
        ConfigError: a tolerance outside (0, 1), a cap or candidate that is not an integer >= 1,
            or ``data`` that is not a :class:`~licrom.learn.training_data.TrainingData`.
    """
    tolerance, max_rank, cands = _check(tolerance, max_rank, candidates)
    if not isinstance(data, TrainingData):
        raise ConfigError(f"choose_rank needs a TrainingData, got {type(data).__name__}")
    frames = data.train
    cap = min(max_rank, len(frames), 3 * data.mesh.n_vertices)
    cands = tuple(r for r in (cands or DEFAULT_CANDIDATES) if r <= cap)
    cands = cands if cap in cands else (*cands, cap)
    runs = frames.trajectory
    names = [frames.names[k] for k in np.unique(runs)]
    stride = max(1, math.ceil(len(frames) / MAX_FRAMES))
    keep = np.concatenate([np.flatnonzero(runs == k)[::stride] for k in np.unique(runs)])
    groups = runs[keep]
    single = len(names) == 1
    if single:  # nothing to hold out: the run's own frames (its two halves in time told nothing: a flat curve)
        method = "the single run's own frames (nothing to hold out)"
    else:
        method = "leave one run out" if len(names) <= MAX_FOLDS else f"{MAX_FOLDS} folds of runs"
    n_groups = len(names)
    norm2 = frames.norm2_full[keep]
    mass_total = float(data.masses.sum())
    if len(keep) < 2 or np.sqrt(norm2.mean() / mass_total) <= 1e-6 * data.mesh.size:
        zeros = tuple(0.0 for _ in cands)
        return RankChoice(cands[0], cands, zeros, zeros, tolerance, cap, False, "no deformation", tuple(names), stride)
    fold_of = np.arange(n_groups) if n_groups <= MAX_FOLDS else np.random.default_rng(0).permutation(n_groups) % MAX_FOLDS
    group_ids = np.searchsorted(np.unique(groups), groups)  # 0..n_groups-1 per kept frame
    gram = _gram(frames.residuals[keep], data.masses)
    err2 = np.zeros((cap, len(keep)))
    for fold in np.unique(fold_of):
        test = np.flatnonzero(fold_of[group_ids] == fold)
        train = test if single else np.flatnonzero(fold_of[group_ids] != fold)
        weights = run_balanced_weights(group_ids[train], frames.norm2_residual[keep][train], power=RUN_BALANCE)
        err2[:, test] = _fold_errors(gram, train, test, weights, cap)
    energy = np.array([norm2[group_ids == g].sum() for g in range(n_groups)])
    per_run = np.sqrt(np.stack([err2[:, group_ids == g].sum(axis=1) for g in range(n_groups)], axis=1) / np.maximum(energy, 1e-300))
    mean_energy = energy / np.bincount(group_ids, minlength=n_groups)
    counted = mean_energy >= QUIET_RUN * mean_energy.max()
    rms = np.sqrt(np.mean(per_run[:, counted] ** 2, axis=1))
    worst = per_run[:, counted].max(axis=1)
    errors = tuple(float(rms[r - 1]) for r in cands)
    met = [r for r, e in zip(cands, errors) if e <= tolerance]
    # None meets it: the smallest r within PLATEAU of the best held-out error, where more modes stop helping the
    # runs held out (a single run of 101 frames: its halves of 50 frames flatten the curve from r = 50 on).
    rank = met[0] if met else next(r for r, e in zip(cands, errors) if e <= (1.0 + PLATEAU) * min(errors))
    return RankChoice(rank, cands, errors, tuple(float(worst[r - 1]) for r in cands), tolerance, cap, not met, method,
                      tuple(n for n, c in zip(names, counted) if c), stride)
