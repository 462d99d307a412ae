"""r checked by the dynamics (licrom.learn.training.dynamics): training runs replayed on POD(r)."""

import warnings

import numpy as np
import pytest
from licrom import ConfigError
from licrom.analysis.compare import compare
from licrom.learn.training import TrainConfig, dynamics
from licrom.learn.training.dynamics import DynamicsCheck, check_dynamics, dynamics_lines
from licrom.learn.training_data import TrainingData
from licrom.reduced.body import BodyFrameSim
from licrom.subspace.basis import MeshBasis, run_balanced_weights
from licrom.subspace.body_basis import BodyFrameBasis
from licrom.subspace.cubature import Cubature


@pytest.fixture(scope="module")
def demo_data(tiny_demo):
    """The tiny demo's full runs (84-tet cheese, 60 steps each), every run a training run."""
    out, _ = tiny_demo
    return TrainingData(out / "data", val_fraction=0.0)


def _choice_rule_holds(check: DynamicsCheck) -> None:
    """r is the cap where some runs meet at the cap and others do not (chaotic motion); else the smallest level at which
    every run meets; the projection's choice where none meets at the cap."""
    reproducible = [run for run in check.runs if run["reproducible"]]
    met = [r for r in check.levels if reproducible and all(any(row["r"] == r and row["meets"] for row in run["rows"]) for run in reproducible)]
    if reproducible and len(reproducible) < len(check.runs):
        assert check.rank == check.max_rank
    else:
        assert check.rank == (met[0] if met else check.projection_rank)
    assert check.raised == (check.rank > check.projection_rank)


def test_each_replay_is_the_body_frame_run_on_pod_of_the_training_runs(demo_data):
    check = check_dynamics(demo_data, 4, max_rank=12, runs=2)
    assert check.method == "replayed" and check.levels == (4, 12) and len(check.runs) == 2
    _choice_rule_holds(check)
    # one replay redone by hand: POD(r) of the training residuals, run-balanced, every tet, the run's own steps
    frames = demo_data.train
    pod, _ = MeshBasis.pod(demo_data.mesh, frames.residuals, 4, weights=run_balanced_weights(frames.trajectory, frames.norm2_residual))
    run = next(t for n, t in demo_data.training_runs if n == check.runs[0]["run"])
    basis = BodyFrameBasis(demo_data.mesh, pod, density=run.scene.material.density)
    steps = len(run.iterations)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reduced = BodyFrameSim(basis, demo_data.mesh, run.scene, cubature=Cubature.full(demo_data.mesh)).run(steps, record_every=steps // (run.n_frames - 1))
    c = compare(run, reduced)
    row = next(row for row in check.runs[0]["rows"] if row["r"] == 4)
    assert row["nonrigid_error"] == pytest.approx(c.nonrigid_error, rel=1e-6)
    assert row["com_error"] == pytest.approx(c.final_com_error, rel=1e-6, abs=1e-12)
    # more modes of the same runs hold each replay at least as well
    for run_report in check.runs:
        errors = {row["r"]: row["nonrigid_error"] for row in run_report["rows"]}
        if 4 in errors:
            assert errors[12] <= errors[4] * 1.05


def test_r_is_raised_to_the_first_level_where_every_reproducible_replay_meets(demo_data, monkeypatch):
    loose = check_dynamics(demo_data, 2, max_rank=12, runs=2)
    errors = {(run["run"], row["r"]): row["nonrigid_error"] for run in loose.runs for row in run["rows"]}
    at_cap = max(errors[(run["run"], 12)] for run in loose.runs)
    at_two = min(errors.get((run["run"], 2), np.inf) for run in loose.runs)
    assert at_cap < at_two, "the demo's runs need more than 2 modes"
    # a non-rigid limit between the two: every replay meets at the cap, none at r = 2
    monkeypatch.setattr(dynamics, "_limits", lambda: ((at_cap + at_two) / 2, np.inf))
    raised = check_dynamics(demo_data, 2, max_rank=12, runs=2)
    assert raised.raised and raised.rank > 2 and all(run["reproducible"] for run in raised.runs)
    _choice_rule_holds(raised)
    # the report tells what the raised r costs: the median over the runs of their replays' step times at the two r
    assert all(row["step_ms"] > 0 for run in raised.runs for row in run["rows"])
    ratios = [next(row["step_ms"] for row in run["rows"] if row["r"] == raised.rank) / next(row["step_ms"] for row in run["rows"] if row["r"] == 2)
              for run in raised.runs]
    assert f"stepped {np.median(ratios):.1f}x slower at r = {raised.rank} than at r = 2" in raised.lines()[-1]
    assert "--dynamics-max-rank 0 keeps r = 2" in raised.lines()[-1]
    # nothing meets even at the cap: r stays and the report says so
    monkeypatch.setattr(dynamics, "_limits", lambda: (0.0, 0.0))
    none = check_dynamics(demo_data, 2, max_rank=12, runs=2)
    assert none.rank == 2 and not none.raised and not any(run["reproducible"] for run in none.runs)
    assert "misses at the cap too" in "\n".join(none.lines()) and "no replay meets" in none.lines()[-1]


def test_a_run_no_r_reproduces_beside_one_the_cap_does_takes_r_to_the_cap(demo_data, monkeypatch):
    loose = check_dynamics(demo_data, 2, max_rank=12, runs=2)
    at_cap = sorted(next(row["nonrigid_error"] for row in run["rows"] if row["r"] == 12) for run in loose.runs)
    assert at_cap[0] < at_cap[1], "the two replays land apart at the cap"
    # a non-rigid limit between the two replays at the cap: one is reproducible, the other is not (a stand-in for a tumble)
    monkeypatch.setattr(dynamics, "_limits", lambda: (sum(at_cap) / 2, np.inf))
    mixed = check_dynamics(demo_data, 2, max_rank=12, runs=2)
    assert [run["reproducible"] for run in mixed.runs].count(True) == 1
    assert mixed.rank == 12 and mixed.raised
    _choice_rule_holds(mixed)
    assert "chaotic" in mixed.lines()[-1] and "to the cap 12" in mixed.lines()[-1]
    # replayed at the cap alone: no step time at r = 2 to compare with, and the report does not make one up
    assert "slower" not in mixed.lines()[-1] and "--dynamics-max-rank 0 keeps r = 2, at a cheaper step" in mixed.lines()[-1]


def test_nothing_is_replayed_where_the_check_cannot_raise_r_or_does_not_apply(demo_data, tiny_demo, monkeypatch):
    assert check_dynamics(demo_data, 12, max_rank=12).method.startswith("not run (cap")
    assert check_dynamics(demo_data, 4, max_rank=0).rank == 4
    out, _ = tiny_demo
    world = TrainingData(out / "data", val_fraction=0.0, frame="world")
    assert check_dynamics(world, 4, max_rank=12).method == "not run (world-frame models)"
    monkeypatch.setattr(dynamics, "MAX_TETS", 10)
    big = check_dynamics(demo_data, 4, max_rank=12)
    assert big.method.startswith("not run (84 tets") and big.runs == () and dynamics_lines(big.to_dict())[0].startswith("dynamics check: not run")
    assert big.too_large and not check_dynamics(world, 4, max_rank=12).too_large
    # nothing replayed, r to the cap: what the 104k-tet ball needed
    assert big.rank == big.max_rank == 12 and big.raised and big.projection_rank == 4 and "to the cap 12" in big.method
    given = dynamics.large_mesh_remedy(big.max_rank, 4, dynamics.LARGE_MESH_EPOCHS)
    assert f"-r {big.max_rank}" in given and "above 10 tets" in given and f"--epochs {dynamics.LARGE_MESH_EPOCHS}" in given
    assert dynamics.large_mesh_remedy(big.max_rank, 12, 300) == given
    spent = dynamics.large_mesh_remedy(big.max_rank, 12, dynamics.LARGE_MESH_EPOCHS)
    assert "-r " not in spent and "training runs" in spent and "--cubature-points" in spent and "against a full run" in spent


def test_epochs_the_fits_and_their_candidates_by_default_grow_above_the_checks_tet_limit(monkeypatch):
    for name in ("epochs", "cubature_points"):
        assert getattr(TrainConfig(), name) == "auto" and getattr(TrainConfig(**{name: 7}), name) == 7
        for bad in (0, -3, 2.5, True, "many"):
            with pytest.raises(ConfigError, match=f"{name} must be an integer >= 1 or 'auto'"):
                TrainConfig(**{name: bad})
    assert dynamics.default_epochs(dynamics.MAX_TETS) == dynamics.DEFAULT_EPOCHS
    assert dynamics.default_epochs(dynamics.MAX_TETS + 1) == dynamics.LARGE_MESH_EPOCHS > dynamics.DEFAULT_EPOCHS
    assert dynamics.cubature_counts(dynamics.MAX_TETS) == (dynamics.DEFAULT_CUBATURE_POINTS,)
    assert dynamics.cubature_counts(dynamics.MAX_TETS + 1) == (dynamics.DEFAULT_CUBATURE_POINTS, dynamics.LARGE_MESH_CUBATURE_POINTS)
    assert dynamics.LARGE_MESH_CUBATURE_POINTS > dynamics.DEFAULT_CUBATURE_POINTS
    assert dynamics.fit_pool(84, None) is None and dynamics.fit_pool(84, 300) == 300
    monkeypatch.setattr(dynamics, "MAX_TETS", 10)
    assert dynamics.default_epochs(84) == dynamics.LARGE_MESH_EPOCHS
    assert len(dynamics.cubature_counts(84)) == 2
    assert dynamics.fit_pool(84, None) == dynamics.LARGE_MESH_CANDIDATES and dynamics.fit_pool(84, 300) == 300


def test_the_report_round_trips_through_its_dict(demo_data):
    check = check_dynamics(demo_data, 4, max_rank=8, runs=1)
    assert dynamics_lines(check.to_dict()) == check.lines()
    assert dynamics_lines(None) == []
    assert f"r = {check.rank}" in check.lines()[-1] or f"to {check.rank}" in check.lines()[-1]


@pytest.mark.parametrize("kwargs", [dict(rank=0), dict(rank=2.5), dict(max_rank=-1), dict(runs=0), dict(rank=True)])
def test_bad_arguments_are_config_errors(demo_data, kwargs):
    args = dict(rank=4, max_rank=12, runs=2) | kwargs
    with pytest.raises(ConfigError, match="check_dynamics"):
        check_dynamics(demo_data, **args)


def test_bad_data_and_config_are_config_errors():
    with pytest.raises(ConfigError, match="needs a TrainingData"):
        check_dynamics([], 4)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="dynamics_max_rank"):
        TrainConfig(dynamics_max_rank=-1)
    assert TrainConfig(dynamics_max_rank=0).dynamics_max_rank == 0


def test_replayed_runs_are_spread_over_what_the_runs_did(demo_data):
    runs = [run for _, run in demo_data.training_runs]
    spread = lambda rs, k: dynamics.spread_runs(rs, demo_data.masses, demo_data.mesh.size, k)  # noqa: E731
    every = spread(runs, 99)
    assert sorted(every) == list(range(len(runs)))
    assert spread(runs, 2) == every[:2]  # greedy: a longer choice extends a shorter one
    # a copy of a run is taken only once every run that did something else is
    doubled = spread([*runs, runs[every[0]]], len(runs))
    assert {every[0] if i == len(runs) else i for i in doubled} == set(range(len(runs)))
