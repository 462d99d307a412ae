"""r chosen from the data (licrom.learn.training.rank) and its use by train and the CLI."""

import pytest
from licrom import ConfigError
from licrom.learn.model import ModelConfig
from licrom.learn.training import RankChoice, TrainConfig, choose_rank, output_paths, train
from licrom.learn.training_data import TrainingData, make_synthetic_trajectories

TINY = dict(epochs=2, batch_frames=4, points_per_frame=128, encoder_points=64, val_points=64, progress=False, device="cpu")
SMALL_NET = dict(field_width=32, encoder_point_widths=(16, 32), encoder_fc_widths=(16,))


@pytest.fixture(scope="module")
def rank4(coarse_box):
    """World-frame residuals that lie exactly in a 4-dimensional space (4 fields, no rotation)."""
    return make_synthetic_trajectories(coarse_box, count=6, frames=24, seed=5, modes=4, rotation=False)


def test_curve_drops_to_zero_at_the_known_rank(rank4):
    # world frame: the errors are relative to the whole displacement, the fall included, so they are small
    choice = choose_rank(TrainingData(rank4, val_fraction=0.0, frame="world"), tolerance=1e-6, candidates=range(1, 9))
    assert choice.rank == 4 and not choice.capped and choice.method == "5 folds of runs"
    errors = dict(zip(choice.candidates, choice.errors))
    assert errors[3] > 1e-3 and errors[4] < 1e-7 and errors[8] < 1e-7
    assert all(w >= e for w, e in zip(choice.worst_errors, choice.errors))
    assert RankChoice.from_dict(choice.to_dict()) == choice
    assert "r =    4" in choice.describe() and "<- chosen" in choice.describe()


def test_tolerance_and_cap(coarse_box, rank4):
    rotating = TrainingData(make_synthetic_trajectories(coarse_box, count=3, frames=20, seed=1, modes=8), val_fraction=0.0)
    capped = choose_rank(rotating, tolerance=1e-9, max_rank=6, candidates=(2, 4, 8))
    assert capped.capped and capped.rank == 6 and capped.candidates == (2, 4, 6) and capped.max_rank == 6
    assert capped.method == "leave one run out"
    assert choose_rank(rotating, tolerance=0.99, candidates=(2, 4)).rank == 2
    # the cap also follows the frames: 3 runs of 2 frames
    few = TrainingData(make_synthetic_trajectories(coarse_box, count=3, frames=2, seed=1), val_fraction=0.0)
    assert choose_rank(few, tolerance=1e-9).max_rank == 6


def test_where_no_r_meets_the_tolerance_r_stops_where_the_held_out_error_stops_falling(coarse_box):
    # a run of 2 fields and one of 6: held out, the second is never spanned by the first's 2 dimensions
    runs = [make_synthetic_trajectories(coarse_box, count=1, frames=24, seed=s, modes=m, rotation=False)[0] for s, m in ((11, 2), (12, 6))]
    choice = choose_rank(TrainingData(runs, val_fraction=0.0, frame="world"), tolerance=1e-6, candidates=range(1, 11))
    assert choice.capped and choice.max_rank == 48 and choice.rank <= 6  # not the cap: beyond 6 fields nothing is left to span
    errors = dict(zip(choice.candidates, choice.errors))
    assert errors[choice.rank] <= 1.01 * min(choice.errors) and errors[10] > 1e-3
    assert "stops falling" in choice.describe()


def test_single_run_and_no_deformation(coarse_box, rank4):
    single = choose_rank(TrainingData(rank4[:1], val_fraction=0.0, frame="world"), tolerance=1e-6, candidates=range(1, 7))
    assert single.method == "the single run's own frames (nothing to hold out)" and single.rank == 4
    rigid = TrainingData(make_synthetic_trajectories(coarse_box, count=2, frames=5, amplitude=0.0), val_fraction=0.0)
    still = choose_rank(rigid, candidates=(3, 5))
    assert still.method == "no deformation" and still.rank == 3 and still.errors == (0.0, 0.0, 0.0)  # the cap, 10 frames, is tried too


@pytest.mark.parametrize("kwargs", [{"tolerance": 0.0}, {"tolerance": 1.0}, {"tolerance": "5%"}, {"max_rank": 0},
                                    {"max_rank": 2.5}, {"candidates": []}, {"candidates": [0, 4]}, {"candidates": 7}])
def test_bad_inputs_are_config_errors(rank4, kwargs):
    with pytest.raises(ConfigError):
        choose_rank(TrainingData(rank4[:2], val_fraction=0.0), **kwargs)


def test_bad_data_and_configs_are_config_errors(rank4):
    with pytest.raises(ConfigError, match="TrainingData"):
        choose_rank(rank4)
    with pytest.raises(ConfigError, match="rank_tolerance"):
        TrainConfig(rank_tolerance=0.0)
    with pytest.raises(ConfigError, match="max_rank"):
        TrainConfig(max_rank=0)
    with pytest.raises(ConfigError, match="latent_dim"):
        ModelConfig(latent_dim="some")


def test_train_chooses_r_records_it_and_extends_once(rank4, tmp_path):
    out = tmp_path / "m.lcm"
    model = train(rank4, out, TrainConfig(**TINY, val_indices=(5,), rank_tolerance=1e-6, max_rank=8, extension=0.5), ModelConfig(**SMALL_NET), frame="world")
    rank, sub = model.metadata["rank"], model.metadata["subspace"]
    # 4 fields: the smallest default candidate that holds them
    assert model.n_learned == rank["rank"] == 5 and rank["tolerance"] == 1e-6 and rank["max_rank"] == 8
    # world frame: the dynamics check does not replay, and says so
    assert rank["dynamics"]["projection_rank"] == 5 and rank["dynamics"]["method"] == "not run (world-frame models)"
    assert RankChoice.from_dict(rank).rank == 5
    assert sub["split"] == "validation" and sub["r"] == 5 and sub["pod"] < 1e-6 < sub["model"]
    # two epochs leave the field far from POD: one extension of half the epochs, no more
    assert sub["extended_epochs"] == 1 and model.metadata["epochs_trained"] == 3 and sub["ratio_before_extension"] > 1.05
    assert not (output_paths(out)["checkpoints"] / "before_extension.ckpt").exists()
    assert output_paths(out)["png"].exists()
    fixed = train(rank4, None, TrainConfig(**TINY, extension=0.0), ModelConfig(latent_dim=2, **SMALL_NET))
    assert fixed.n_learned == 2 and fixed.metadata["rank"]["method"].startswith("given")
    assert "extended_epochs" not in fixed.metadata["subspace"]


def test_cli_modes_auto_or_integer(rank4, tmp_path, capsys):
    from licrom.cli.commands import main

    data = tmp_path / "data"
    data.mkdir()
    for k, t in enumerate(rank4[:3]):
        t.save(data / f"t{k}.npz", precision="float64")
    assert main(["train", str(data), "-o", str(tmp_path / "m.lcm"), "-r", "x"]) == 2
    args = ["train", str(data), "-o", str(tmp_path / "m.lcm"), "--frame", "world", "--epochs", "1", "--device", "cpu", "-q",
            "--width", "32", "--max-rank", "6", "--val-fraction", "0"]
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "r chosen from the data (leave one run out" in text and "<- chosen" in text and "learned subspace" in text
    assert "dynamics check: not run (world-frame models)" in text
