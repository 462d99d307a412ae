"""The end-of-training check (licrom.learn.training.held_out): the model run as a user runs it
on the training's held-out runs, against those runs."""

import dataclasses
import warnings

import pytest
from licrom import Model, ReducedSim, Trajectory
from licrom.analysis.compare import compare
from licrom.errors import AccuracyWarning
from licrom.learn.training import held_out


def test_the_training_report_holds_each_held_out_run_replayed_with_the_defaults(tiny_demo):
    out, _ = tiny_demo
    model = Model.load(out / "model.lcm")
    report = model.metadata["held_out"]
    names = model.metadata["data"]["validation"]
    assert names and [r["run"] for r in report["runs"]] == names[: held_out.HELD_OUT_RUNS]
    for row in report["runs"]:
        run = Trajectory.load(out / "data" / f"{row['run']}.npz")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reduced = ReducedSim(model, scene=run.scene).run(len(run.iterations), record_every=len(run.iterations) // (run.n_frames - 1))
        c = compare(run, reduced)
        assert row["nonrigid_error"] == pytest.approx(c.nonrigid_error, rel=1e-9)
        assert row["com_error"] == pytest.approx(c.final_com_error, rel=1e-9)
        assert row["estimate"] == pytest.approx(c.error_estimate, rel=1e-9)
        assert row["estimate_terms"] == pytest.approx(reduced.info["error_estimate_terms"], rel=1e-9)
        assert row["stick_slip_right"] == c.stick_slip_agree
        assert row["flagged"] == (row["estimate"] > report["threshold"])
    assert report["worst_nonrigid_error"] == max(r["nonrigid_error"] for r in report["runs"])
    lines = held_out.held_out_lines(report)
    assert len(lines) == len(report["runs"]) + 2 and "non-rigid error" in lines[0]
    for row, line in zip(report["runs"], lines):  # each run with its verdict, then what the numbers mean
        ok = row["nonrigid_error"] < 0.1 and row["com_error"] < 0.02 and row["stick_slip_right"]
        assert line.endswith("meets every target") == ok and ("misses" in line) == (not ok)
        assert f"the cubature's {100 * row['estimate_terms']['cubature']:.1f} %" in line
    assert lines[-2].startswith("  non-rigid error (target < 10 %): How far")


def test_a_held_out_run_above_the_target_is_named_and_its_estimate_flagged_above_the_threshold(tiny_demo, monkeypatch):
    out, _ = tiny_demo
    model = Model.load(out / "model.lcm")
    name = model.metadata["data"]["validation"][0]
    run = Trajectory.load(out / "data" / f"{name}.npz")
    monkeypatch.setattr(held_out, "NONRIGID_TARGET", 0.0)  # every run misses
    monkeypatch.setattr(held_out, "ERROR_THRESHOLD", 0.0)  # every estimate is flagged
    with pytest.warns(AccuracyWarning, match=rf"misses 1 of its 1 held-out runs .*{name} \(non-rigid error [0-9.]+ % >= 0 %"):
        report = held_out.check_held_out(model, [(name, run)])
    assert report["runs"][0]["nonrigid_error"] > 0.0 and report["runs"][0]["flagged"] and report["threshold"] == 0.0
    with pytest.warns(AccuracyWarning, match=r"chaotic, not the model: `licrom compare MODEL --sensitivity`"):
        held_out.check_held_out(model, [(name, run)])
    with pytest.warns(AccuracyWarning, match=r"; give r \(-r 250\)$"):  # training's advice where the dynamics check did not run
        held_out.check_held_out(model, [(name, run)], remedy="give r (-r 250)")
    monkeypatch.setattr(held_out, "ERROR_THRESHOLD", 1.0)  # the estimate's threshold does not judge the true error
    with pytest.warns(AccuracyWarning, match=rf"misses 1 of its 1 held-out runs .*{name}"):
        assert not held_out.check_held_out(model, [(name, run)])["runs"][0]["flagged"]


def test_runs_whose_frames_are_not_evenly_spaced_steps_are_skipped_with_the_reason(tiny_demo):
    out, _ = tiny_demo
    model = Model.load(out / "model.lcm")
    name = model.metadata["data"]["validation"][0]
    run = Trajectory.load(out / "data" / f"{name}.npz")
    steps = len(run.iterations) - 1  # one step fewer than the frames say
    uneven = dataclasses.replace(run, iterations=run.iterations[:steps], residuals=run.residuals[:steps],
                                 converged=run.converged[:steps], step_seconds=run.step_seconds[:steps])
    report = held_out.check_held_out(model, [(name, uneven)])
    assert "not evenly spaced" in report["runs"][0]["skipped"]


def test_a_held_out_run_that_misses_the_centre_of_mass_target_alone_is_named_too(tiny_demo, monkeypatch):
    out, _ = tiny_demo
    model = Model.load(out / "model.lcm")
    name = model.metadata["data"]["validation"][0]
    run = Trajectory.load(out / "data" / f"{name}.npz")
    monkeypatch.setattr(held_out, "NONRIGID_TARGET", 1.0)  # the non-rigid error never misses
    monkeypatch.setattr(held_out, "COM_TARGET", 0.0)  # the centre of mass always does
    with pytest.warns(AccuracyWarning, match=rf"misses 1 of its 1 held-out runs .*{name} \(final centre of mass [0-9.]+ % of the size >= 0 %"):
        report = held_out.check_held_out(model, [(name, run)])
    row = report["runs"][0]
    assert held_out._missed(row) == [f"final centre of mass {100 * row['com_error']:.2f} % of the size >= 0 %"]
    monkeypatch.setattr(held_out, "COM_TARGET", 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", AccuracyWarning)  # meets every target: no warning
        held_out.check_held_out(model, [(name, run)])


def test_training_above_the_dynamics_checks_tet_limit_advises_r_and_epochs_for_a_missed_run(tiny_demo, monkeypatch):
    from licrom.learn.model import ModelConfig
    from licrom.learn.training import TrainConfig, dynamics, train

    out, _ = tiny_demo
    monkeypatch.setattr(dynamics, "MAX_TETS", 10)  # the 84-tet demo counts as large: the check does not run
    monkeypatch.setattr(held_out, "NONRIGID_TARGET", 0.0)  # every held-out run misses
    cfg = TrainConfig(epochs=1, batch_frames=4, points_per_frame=128, encoder_points=64, val_points=64, progress=False, extension=0.0,
                      dynamics_max_rank=30)  # the cap r goes to: above the projection's choice, within what 1 epoch learns
    with pytest.warns(AccuracyWarning, match=r"does not run above 10 tets: give r \(-r \d+\) and train longer \(--epochs 800\)"):
        model = train(out / "data", None, cfg, ModelConfig(latent_dim="auto"))
    assert model.metadata["rank"]["dynamics"]["too_large"], model.metadata["rank"]
    assert model.n_learned == model.metadata["rank"]["dynamics"]["max_rank"]  # r to the cap where nothing is replayed
    assert model.metadata["cubature"]["candidates"] == dynamics.LARGE_MESH_CANDIDATES
    # two fits, 1000 and 3000 allowed, each replayed on the held-out runs; the kept one nearest the targets
    choice = model.metadata["cubature"]["choice"]
    assert [row["max_count"] for row in choice] == list(dynamics.cubature_counts(model.mesh.n_tets))
    kept = next(row for row in choice if row["max_count"] == model.metadata["cubature"]["max_count"])
    assert kept["count"] == model.cubature.count and kept["target_ratio"] == min(row["target_ratio"] for row in choice)
    # at the large-mesh defaults (r at the cap, their epochs) only the data and the cubature are left to advise
    monkeypatch.setattr(dynamics, "LARGE_MESH_EPOCHS", 1)
    with pytest.warns(AccuracyWarning, match=r"r is at the dynamics check's cap \(\d+\) and training ran 1 epochs or more.*add training runs"):
        model = train(out / "data", None, dataclasses.replace(cfg, epochs="auto"), ModelConfig(latent_dim="auto"))
    assert model.metadata["train_config"]["epochs"] == 1
