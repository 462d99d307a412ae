"""r checked by the dynamics: training runs replayed on POD(r) of the training runs.

The leave-runs-out projection curve (:mod:`.rank`) says how well r modes hold a run's shapes; it does
not say whether a reduced run on them *moves* as the full run did. A rolling ball is the case that
showed it (docs/results.md section 16): at a converged truth its curve met the 4 % tolerance at
r = 100, yet its held-out roll ended 5.3 % of its size away in centre of mass. Its contact patch
travels round the whole surface, the rolling resistance comes from the deformation there, and with
100 modes the reduced ball rolled 0.3-0.8 % too fast; POD(200) of the same runs brought it to 1.1 %.

:func:`check_dynamics` replays a few training runs (:data:`DYNAMICS_RUNS`, spread over their motions)
with the body-frame reduced model on POD(r) of *all* the training runs (the run included: what is
tested is whether r modes carry the dynamics of motion the data covers; whether the data covers a
new scene is the projection curve's question), every tet as cubature, and compares each with its
full run (:func:`licrom.analysis.compare.compare`). r is raised from the projection's choice through
:data:`DYNAMICS_CANDIDATES` to the smallest at which every reproducible replay meets the targets
with :data:`MARGIN` and :data:`COM_MARGIN`. A run that misses at the cap too is not reproducible by any r allowed (a
chaotic tumble, where a nudge of the start moves the run as much). Beside runs that the cap does reproduce, it is chaotic
motion in the data, and it takes r to the cap: such a run's outcome amplifies every difference of the reduced dynamics.
On the box (docs/results.md section 33) the tip-overs' replays met at r = 120 and the training tumble's at no r, and its
drawn held-out tumbles came within 3x their noise floors at POD(120) / POD(200) / POD(250) in 2 / 3 / 4 of 4. Where no
run meets at the cap, the replays say nothing about r and it stays.

Above :data:`MAX_TETS` tets nothing is replayed (no quadrature there holds the replays without the full elastic pass),
and r goes to the cap: the one mesh measured at that size, the 104k-tet ball, needed it (docs/results.md section 35),
and a model that is too rich costs speed where one that is too poor costs the run. Training then also runs
:data:`LARGE_MESH_EPOCHS` epochs by default (:func:`default_epochs`), fits its cubature from
:data:`LARGE_MESH_CANDIDATES` candidate tets (:func:`fit_pool`) with at most 1000 and 3000 tets, and keeps the fit
whose held-out runs land nearer their targets (:func:`cubature_counts`).
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ...analysis.compare import COM_TARGET, NONRIGID_TARGET, compare
from ...errors import ConfigError, LicromError, LicromWarning
from ...geometry.points import farthest_points
from ...records.trajectory import Trajectory
from ...reduced.body import BodyFrameSim
from ...rigid import rigid_fit
from ...subspace.basis import MeshBasis, run_balanced_weights
from ...subspace.body_basis import BodyFrameBasis
from ...subspace.cubature import Cubature
from ..training_data import TrainingData
from .held_out import run_cadence

__all__ = ["COM_MARGIN", "DEFAULT_DYNAMICS_MAX_RANK", "DEFAULT_EPOCHS", "DYNAMICS_CANDIDATES", "DYNAMICS_RUNS", "LARGE_MESH_CANDIDATES", "LARGE_MESH_EPOCHS", "MARGIN", "MAX_TETS", "DynamicsCheck",
           "check_dynamics", "cubature_counts", "default_epochs", "fit_pool", "large_mesh_remedy", "replay_run", "replayed_runs",
           "spread_runs", "too_large", "training_pod"]

DEFAULT_DYNAMICS_MAX_RANK = 250
"""Default cap of r raised by the dynamics: the ball's held-out roll needed about 200 (POD(r) of its
training runs, every tet: 5.8 / 5.0 / 2.7 / 1.1 / 0.9 % of its size in centre of mass at r = 100 /
120 / 150 / 200 / 250; its step 0.96 ms at 120, 4.2 ms at 250 on 2 cores)."""

DYNAMICS_CANDIDATES = (100, 120, 150, 200, 250)
"""r values above the projection's choice that the dynamics may take (those above the cap dropped, the cap added)."""

DYNAMICS_RUNS = 4
"""Training runs replayed at most (spread over what the runs did: :func:`spread_runs`): each costs a reduced run per r tried."""

MARGIN = 2.0 / 3.0
"""A replay meets the non-rigid target when its non-rigid error is below ``MARGIN x`` the 10 % target: a held-out
scene lands further off than a run the modes were fitted to (the ball at r = 120: 4.3 % held out against 4.0 % for
the worst replay, 1.1x)."""

COM_MARGIN = 0.35
"""A replay meets the centre-of-mass target when its final centre of mass is below ``COM_MARGIN x`` the 2 % target.
A held-out scene lands further off than a run the modes were fitted to. Measured at a converged truth with impact frames
(docs/results.md section 28), POD(r) of the training runs, every tet: the worst replay of the cheese lands 0.58 % at
r = 120, where its held-out scenes land 0.1-1.5 %; the ball's worst replays land 0.77 / 0.79 / 0.33 % at r = 150 / 200 /
250, where its held-out roll lands 2.4 / 0.3 % at r = 150 / 250 (learned model at 150: 3.0 %). 0.35 x 2 % = 0.7 % lies between
the two families: the cheese stays at 120, the ball goes to 250. On the converged cheese family's runs as `licrom train FOLDER` splits them it
does not: its worst replay at r = 120 is a 30 deg, mu 0.2 slide ending 1.27 % of the size off, and the cheese goes to 250
too (a 2.7-2.9x slower step; section 51), which there buys every held-out scene 2-5x closer and another mesh of the
object 7 % non-rigid against 15-19 % (section 53). Replaying each run on POD(r) of the *other* runs
(leave one out) instead was measured and does not separate them either: with 3-16 training runs on a grid of slopes
and frictions, a run left out is a corner of the grid, which the modes must extrapolate to (the cheese's steepest,
grippiest run: 16 % non-rigid at r = 120 left out, 5 % kept in; every ball run misses at r = 250 left out)."""

MAX_TETS = 5000
"""Meshes of more tets are not checked: every tet as cubature makes each replay cost the full step's
elastic pass, and a cubature fitted per r does not hold the replays there. Tried on the 120k-tet cheese
(docs/results.md section 28; POD(250) of its 16 training runs, 256 training poses, the fit's candidates cut to
2048 tets by its memory bound, 622 tets chosen): every replayed run missed at r = 250 (14-145 % non-rigid), where
the learned model at r = 120 with its own fit lands its held-out scenes at 4.7-7.9 %; on the 1.6k-tet cheese the
same per-r fit moves the replays by up to 1.5x against every tet (it would choose 200 for the ball, 150 for the cheese).
A quadrature that needs no fit (well-spread tets weighted with the volumes of their Voronoi cells) did not hold them
either: on the 1074-tet ball at r = 250 one of half its tets moved a replay from 0.4 % to 15 % non-rigid (section 35).
What skipping cost before r went to the cap there: the 104k-tet ball kept the projection's r = 60 and missed its
held-out roll (13.7 % non-rigid, 12.4 % of its size in centre of mass, section 34)."""


LARGE_MESH_EPOCHS = 800
"""Training epochs by default on a mesh above :data:`MAX_TETS` tets (``TrainConfig.epochs="auto"``): on the 104k-tet
ball at r = 250, 300 epochs (the small meshes' 200 and its extension) left the learned subspace at 1.42x POD(250) and
the held-out roll at 8.8 % non-rigid / 9.4 % of the size in centre of mass; 800 (1200 with the extension) at 1.26x and
4.8 % / 1.3 %, within the targets (docs/results.md section 35). That 300-epoch model's centre of mass was mostly its
fit from 2048 candidates: with 8192, nine 300-epoch trainings put the held-out rolls at 4.4-10.2 % non-rigid (median
7.1 % and 6.8 % on two rolls) and 0.8-3.9 % of the size, 7 of 18 rolls within both targets, against 3.5-8.8 % (median
4.8 % and 4.1 %) and 1.1-3.5 %, 4 of 6, for three trainings at 1200 (section 43). A training step samples the same 2048
points a frame on any mesh, one point per ten vertices there; 8192 or 32768 do not shorten the training (the subspace
at 300 epochs 1.34x POD(250) with either, 1.35x with 2048; section 43)."""


LARGE_MESH_CANDIDATES = 8192
"""Candidate tets of the cubature fitted at the end of training on a mesh above :data:`MAX_TETS` tets, where
``TrainConfig.cubature_candidates`` is None (below, as many as ``licrom.subspace.cubature.FIT_MEMORY`` holds). At
r = 250 that memory (1 GiB) holds about 2000 candidates, and the pool limits the fit: the 104k-tet ball's 1200-epoch
model, fitted from them, stops at 665 tets with a 26 % force residual and lands its held-out roll at 6.5 % non-rigid
and 3.6 % of its size in centre of mass; from 8192 candidates (4.3 GB at r = 250 with 256 poses) 735 tets at 12 % land
it at 4.8 % and 1.3 %, and a drawn roll at 4.1 % and 1.9 % (7.4 % and 1.3 % from 2048; docs/results.md section 36)."""

LARGE_MESH_CUBATURE_POINTS = 3000
"""Most tets of the second cubature training fits on a mesh above :data:`MAX_TETS` tets by default
(``TrainConfig.cubature_points="auto"``), beside :data:`DEFAULT_CUBATURE_POINTS`; training keeps the one whose
held-out runs land nearer their targets (:func:`licrom.learn.training.held_out.target_ratio`). At r = 250 the count
limits the fit, not its residual: the 120k-tet cheese's model, fitted from 8192 candidates with at most 1000 tets,
kept 587 at a 15 % force residual and put its held-out slide and stick 10.9 % and 15.1 % non-rigid from the same model
run with every tet (which lands 1.6 % and 3.6 % from their full runs); with at most 3000 it kept 1343 at 12 %, 3.1 %
and 4.8 % from every tet, for a 1.6x reduced step (docs/results.md section 47). But the 104k-tet ball's learned modes,
integrated with every tet, land further from the truth than its fits of about 740 tets (section 39), and 3000 allowed
(1801 kept) brings its rolls within 1.5 % of every tet: which fit is better is the model's, so the data choose."""

DEFAULT_CUBATURE_POINTS = 1000
"""Most tets of the cubature fitted at the end of training by default: the small meshes' fits meet their tolerance
with 370-800 tets (docs/results.md section 32)."""

DEFAULT_EPOCHS = 200
"""Training epochs by default on a mesh of at most :data:`MAX_TETS` tets (``TrainConfig.epochs="auto"``): the 1k-tet
meshes' learned subspaces end within 1.000-1.002x of their POD with them (docs/results.md section 35)."""


def default_epochs(n_tets: int) -> int:
    """``TrainConfig.epochs="auto"`` on a mesh of ``n_tets`` tets: :data:`DEFAULT_EPOCHS`, or :data:`LARGE_MESH_EPOCHS`
    above :data:`MAX_TETS`."""
    return LARGE_MESH_EPOCHS if too_large(n_tets) else DEFAULT_EPOCHS


def cubature_counts(n_tets: int) -> tuple[int, ...]:
    """The most tets of each cubature training fits with ``TrainConfig.cubature_points="auto"`` on a mesh of ``n_tets``
    tets: :data:`DEFAULT_CUBATURE_POINTS`, and :data:`LARGE_MESH_CUBATURE_POINTS` beside it above :data:`MAX_TETS`."""
    return (DEFAULT_CUBATURE_POINTS, LARGE_MESH_CUBATURE_POINTS) if too_large(n_tets) else (DEFAULT_CUBATURE_POINTS,)


def fit_pool(n_tets: int, candidates: int | None) -> int | None:
    """The candidate tets the end-of-training cubature fit draws: ``candidates`` where given (``TrainConfig.cubature_candidates``),
    else :data:`LARGE_MESH_CANDIDATES` on a mesh above :data:`MAX_TETS` and None (the fit's memory bound) below."""
    if candidates is not None:
        return candidates
    return LARGE_MESH_CANDIDATES if too_large(n_tets) else None


def too_large(n_tets: int) -> bool:
    """A mesh of ``n_tets`` tets is above :data:`MAX_TETS`: not replayed, r to the cap, :data:`LARGE_MESH_EPOCHS`."""
    return n_tets > MAX_TETS


def large_mesh_remedy(cap: int, rank: int, epochs: int) -> str:
    """What to do where a model of a mesh above :data:`MAX_TETS` tets, trained at r = ``rank`` for ``epochs`` epochs,
    misses its held-out runs (training's held-out warning says it): the check that would raise r did not run. Where r
    is already at the check's ``cap`` and training ran :data:`LARGE_MESH_EPOCHS` or more, the data or the cubature are
    what is left: a larger fit lowered the 104k-tet ball's non-rigid error, but its centre of mass landed either side
    of the target with the fit's own error, from one training to the next (docs/results.md sections 38-39)."""
    if rank >= cap and epochs >= LARGE_MESH_EPOCHS:
        return (f"r is at the dynamics check's cap ({cap}) and training ran {LARGE_MESH_EPOCHS} epochs or more, the large-mesh "
                f"defaults where the check does not run (above {MAX_TETS} tets): add training runs nearer the missed scene; a larger "
                "cubature (--cubature-points) moves the model towards its exact integration, while a rolling body's "
                "centre of mass at this size lands either side of its target with the fit's own error (docs/results.md sections 39 "
                "and 47): check the scenes you rely on against a full run (licrom compare)")
    return (f"the dynamics check, which raises r where the motion needs more modes, does not run above {MAX_TETS} tets: give r "
            f"(-r {cap}) and train longer (--epochs {LARGE_MESH_EPOCHS}), the large-mesh defaults, which brought the 104k-tet "
            "ball's held-out roll within its targets (docs/results.md section 35)")


def _chaotic(meets_at_cap: list[bool]) -> bool:
    """Some replays meet at the cap and others do not: chaotic motion beside reproducible runs, which takes r to the
    cap (module docstring)."""
    return any(meets_at_cap) and not all(meets_at_cap)


@dataclass(frozen=True)
class DynamicsCheck:
    """What the replays found and the r they ask for.

    Attributes:
        rank: r after the check (the projection's choice, or raised).
        projection_rank: the projection's choice the check started from.
        max_rank: the cap applied (``max_rank`` limited by frames and 3 n).
        levels: the r values replayed, ascending.
        runs: per replayed run, ``{"run", "reproducible", "rows": [{"r", "nonrigid_error", "com_error",
            "stick_slip_right", "meets", "step_ms"}]}`` (``step_ms``: the replay's wall time a step, None where it failed).
        raised: r was raised above the projection's choice.
        method: ``"replayed"``, or why nothing was replayed.
        seconds: wall time of the check.
        too_large: not run because the mesh has more than :data:`MAX_TETS` tets (:func:`large_mesh_remedy`).
    """

    rank: int
    projection_rank: int
    max_rank: int
    levels: tuple[int, ...]
    runs: tuple[dict[str, Any], ...]
    raised: bool
    method: str
    seconds: float
    too_large: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def lines(self) -> list[str]:
        """The check as lines of text for the training report."""
        if self.method != "replayed":
            return [f"dynamics check: {self.method}"]
        nr, com = _limits()
        lines = [f"dynamics check: training runs replayed on POD(r) of the training runs, every tet as cubature "
                 f"(meets: non-rigid < {100 * nr:.1f} %, centre of mass < {100 * com:.2f} % of the size, stick/slip right)"]
        for run in self.runs:
            cells = ", ".join(f"r = {row['r']}: {100 * row['nonrigid_error']:.1f} % / {100 * row['com_error']:.2f} %"
                              + ("" if row["meets"] else " (misses)") for row in run["rows"])
            lines.append(f"  {run['run']}: {cells}" + ("" if run["reproducible"] else "; misses at the cap too: chaotic?"))
        chaotic = _chaotic([r["reproducible"] for r in self.runs])
        verdict = (f"r raised from {self.projection_rank} to the cap {self.rank}: a run no r reproduces beside runs the cap does "
                   "(chaotic motion needs the most modes allowed)" if chaotic and self.raised
                   else f"r raised from {self.projection_rank} to {self.rank}" if self.raised
                   else f"r = {self.rank} kept" if any(r["reproducible"] for r in self.runs)
                   else f"r = {self.rank} kept: no replay meets the targets at the cap {self.max_rank}")
        if self.raised:
            cost = _step_cost(self.runs, self.projection_rank, self.rank)
            keep = f"licrom train --dynamics-max-rank 0 keeps r = {self.projection_rank}"
            verdict += (f"; its replays stepped {cost:.1f}x slower at r = {self.rank} than at r = {self.projection_rank}; {keep}"
                        if cost is not None else f"; {keep}, at a cheaper step")
        return [*lines, f"  {verdict} ({self.seconds:.0f} s)"]


def _step_cost(runs: Sequence[dict[str, Any]], fast: int, slow: int) -> float | None:
    """Median over the replayed runs of their step time at r = ``slow`` over that at r = ``fast``; None where no run was
    timed at both (a chaotic check replays at the cap alone)."""
    ratios = []
    for run in runs:
        ms = {row["r"]: row.get("step_ms") for row in run["rows"]}
        if ms.get(fast) and ms.get(slow):
            ratios.append(ms[slow] / ms[fast])
    return float(np.median(ratios)) if ratios else None


def _limits() -> tuple[float, float]:
    return MARGIN * NONRIGID_TARGET, COM_MARGIN * COM_TARGET


def check_dynamics(data: TrainingData, rank: int, max_rank: int = DEFAULT_DYNAMICS_MAX_RANK, runs: int = DYNAMICS_RUNS) -> DynamicsCheck:
    """The smallest r at or above ``rank`` at which replays of the training runs meet the targets.

    Args:
        data: training data of body-frame models (its training runs are replayed).
        rank: the projection's choice (:func:`licrom.learn.training.rank.choose_rank`).
        max_rank: largest r the check may raise to; at or below ``rank`` nothing is replayed.
        runs: training runs replayed at most.

    Returns:
        The :class:`DynamicsCheck`; its ``rank`` is never below ``rank``.

    Raises:
        ConfigError: ``rank``, ``max_rank`` or ``runs`` not an integer >= 1 (``max_rank`` may be 0: no check),
            or ``data`` that is not a :class:`~licrom.learn.training_data.TrainingData`.
    """
    if not isinstance(data, TrainingData):
        raise ConfigError(f"check_dynamics needs a TrainingData, got {type(data).__name__}")
    for name, value, least in (("rank", rank, 1), ("max_rank", max_rank, 0), ("runs", runs, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
            raise ConfigError(f"check_dynamics: {name} must be an integer >= {least}, got {value!r}")
    start = time.perf_counter()
    cap = min(int(max_rank), len(data.train), 3 * data.mesh.n_vertices)

    def unchecked(why: str) -> DynamicsCheck:
        return DynamicsCheck(rank, rank, cap, (), (), False, why, time.perf_counter() - start)

    if cap <= rank:
        return unchecked(f"not run (cap {cap} at or below r = {rank})")
    if data.frame != "body":
        return unchecked("not run (world-frame models)")
    if too_large(data.mesh.n_tets):
        return DynamicsCheck(cap, rank, cap, (), (), True,
                             f"not run ({data.mesh.n_tets} tets, above {MAX_TETS}: every tet as cubature would cost the full elastic "
                             f"pass); r raised from {rank} to the cap {cap}, which the 104k-tet ball's held-out roll needed",
                             time.perf_counter() - start, True)
    chosen = replayed_runs(data, runs)
    if not chosen:
        return unchecked("not run (no training run of evenly spaced frames)")
    pod = training_pod(data, cap)
    levels = (rank, *(r for r in DYNAMICS_CANDIDATES if rank < r < cap), cap)

    # At the cap first: a run no r allowed reproduces says nothing about r.
    rows = {name: {cap: replay_run(data, pod, run, cap)} for name, run in chosen}
    reproducible = [(name, run) for name, run in chosen if rows[name][cap]["meets"]]
    choice = rank
    if _chaotic([rows[name][cap]["meets"] for name, _ in chosen]):
        choice = cap
    elif reproducible:
        for r in levels:
            for name, run in reproducible:
                if r not in rows[name]:
                    rows[name][r] = replay_run(data, pod, run, r)
            if all(rows[name][r]["meets"] for name, _ in reproducible):
                choice = r
                break
    report = tuple({"run": name, "reproducible": rows[name][cap]["meets"], "rows": [rows[name][r] for r in sorted(rows[name])]}
                   for name, _ in chosen)
    return DynamicsCheck(choice, rank, cap, levels, report, choice > rank, "replayed", time.perf_counter() - start)


def replayed_runs(data: TrainingData, count: int) -> list[tuple[str, Trajectory]]:
    """Up to ``count`` named training runs of evenly spaced frames, spread over what they did (:func:`spread_runs`),
    in the order chosen: the runs the check replays."""
    candidates = [(name, run) for name, run in data.training_runs if run_cadence(run) is not None]
    if not candidates:
        return []
    return [candidates[i] for i in spread_runs([run for _, run in candidates], data.masses, data.mesh.size, count)]


def training_pod(data: TrainingData, r: int) -> MeshBasis:
    """POD(r) of the training frames' body-frame residuals, each run weighted alike: the modes the replays step on."""
    frames = data.train
    pod, _ = MeshBasis.pod(data.mesh, frames.residuals, r, weights=run_balanced_weights(frames.trajectory, frames.norm2_residual))
    return pod


def replay_run(data: TrainingData, pod: MeshBasis, run: Trajectory, r: int) -> dict[str, Any]:
    """One training run replayed on the first ``r`` modes of ``pod`` with the body-frame reduced model, every tet as
    cubature, against its full run: ``{"r", "nonrigid_error", "com_error", "stick_slip_right", "meets", "step_ms"}``
    (``meets``: within the check's margins; a replay that fails to step misses, with infinite errors and no step time)."""
    basis = BodyFrameBasis(data.mesh, MeshBasis(data.mesh, pod.modes[:, :, :r]), density=data.scenes[0].material.density)
    steps, every = run_cadence(run)  # type: ignore[misc]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LicromWarning)
            sim = BodyFrameSim(basis, data.mesh, run.scene, cubature=Cubature.full(data.mesh))
            began = time.perf_counter()
            reduced = sim.run(steps, record_every=every)
            step_ms = 1e3 * (time.perf_counter() - began) / steps  # what the raised r costs, told in the report
            c = compare(run, reduced)
    except LicromError:
        return {"r": r, "nonrigid_error": float("inf"), "com_error": float("inf"), "stick_slip_right": False, "meets": False,
                "step_ms": None}
    nr_limit, com_limit = _limits()
    meets = bool(c.nonrigid_error < nr_limit and c.final_com_error < com_limit and c.stick_slip_agree)
    return {"r": r, "nonrigid_error": float(c.nonrigid_error), "com_error": float(c.final_com_error),
            "stick_slip_right": bool(c.stick_slip_agree), "meets": meets, "step_ms": step_ms}


def spread_runs(runs: Sequence[Trajectory], masses: np.ndarray, size: float, count: int) -> list[int]:
    """Indices of up to ``count`` of ``runs`` spread over what they did, in the order chosen.

    Each run is the point (centre-of-mass travel from its first frame to its last / ``size``, rotation
    vector of its turn in rad), the rigid fits of those frames; farthest-point sampling from the run
    nearest their centroid (a typical run, then the most different ones). Spreading by list order put
    the cheese's 4 replays on 2 of its 5 downhill directions.
    """
    motion = np.empty((len(runs), 6))
    for i, run in enumerate(runs):
        (c0, r0), (c1, r1) = (rigid_fit(run.positions(f), run.rest_positions, masses) for f in (0, -1))
        motion[i, :3] = (c1 - c0) / size
        motion[i, 3:] = Rotation.from_matrix(r1 @ r0.T).as_rotvec()
    return [int(i) for i in farthest_points(motion, min(count, len(runs)))]


def dynamics_lines(report: dict[str, Any] | None) -> Sequence[str]:
    """:meth:`DynamicsCheck.lines` of a check stored as a dict (``model.metadata["rank"]["dynamics"]``)."""
    if not report:
        return []
    return DynamicsCheck(**{**report, "levels": tuple(report["levels"]), "runs": tuple(report["runs"])}).lines()
