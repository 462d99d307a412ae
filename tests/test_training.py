"""Training data, the Lightning training loop, its files, reproducibility, resume and the CLI."""

import csv
import dataclasses
import warnings

import numpy as np
import pytest
import torch
from licrom import AccuracyWarning, ConfigError, FileFormatError, Trajectory, meshes
from licrom.learn.model import Model, ModelConfig
from licrom.learn.training import TrainConfig, evaluate, output_paths, train
from licrom.learn.training.run import warn_without_impact_frames
from licrom.learn.training_data import (
    TrainingData,
    make_synthetic_trajectories,
    runs_without_impact_frames,
    split_by_trajectory,
)
from licrom.rigid import relative_error
from licrom.subspace.basis import affine_values

# A tiny problem: a coarse box, four short trajectories, cheap epochs.
# extension=0: these runs are too short to reach POD; test_rank.py trains on past it
TINY = dict(epochs=2, batch_frames=4, points_per_frame=128, encoder_points=64, val_points=64, progress=False, extension=0.0)


@pytest.fixture(scope="module")
def trajs(coarse_box):
    return make_synthetic_trajectories(coarse_box, count=4, frames=10, seed=3, modes=3, rotation=True)


@pytest.fixture(scope="module")
def data_dir(trajs, tmp_path_factory):
    d = tmp_path_factory.mktemp("data")
    for k, t in enumerate(trajs):
        t.save(d / f"traj_{k:03d}.npz", precision="float64")
    return d


# --- data --------------------------------------------------------------------------------
def test_split_is_by_whole_trajectory():
    train_idx, val_idx = split_by_trajectory(10, 0.2, seed=1)
    assert len(val_idx) == 2 and sorted(train_idx + val_idx) == list(range(10))
    assert split_by_trajectory(10, 0.2, seed=1) == (train_idx, val_idx)
    assert split_by_trajectory(3, 0.0) == ([0, 1, 2], [])
    assert split_by_trajectory(2, 0.1) == ([0], [1]) or split_by_trajectory(2, 0.1) == ([1], [0])
    assert split_by_trajectory(5, val_indices=[4, 1]) == ([0, 2, 3], [1, 4])
    with pytest.raises(ConfigError):
        split_by_trajectory(3, val_indices=[0, 1, 2])
    with pytest.raises(ConfigError):
        split_by_trajectory(3, val_indices=[7])


def test_training_data_removes_affine_part(data_dir, trajs, coarse_box):
    d = TrainingData(data_dir, val_indices=[1], frame="world")
    assert d.names == [f"traj_{k:03d}" for k in range(4)]
    assert d.train_indices == [0, 2, 3] and d.val_indices == [1]
    assert len(d.train) == 30 and len(d.val) == 10
    assert set(d.train.trajectory.tolist()) == {0, 1, 2} and d.val.names == ["traj_001"]
    # every held-out frame comes from the held-out trajectory only
    np.testing.assert_allclose(d.val.full_displacements(d.rest, slice(None)), trajs[1].displacements, atol=1e-6)
    # residuals are mass-orthogonal to the affine modes
    a = affine_values(d.rest).reshape(-1, 12)
    mw = np.repeat(d.masses, 3)
    proj = d.train.residuals.reshape(len(d.train), -1).astype(np.float64) @ (mw[:, None] * a)
    assert np.abs(proj).max() < 1e-5 * np.sqrt(d.train.norm2_residual.max() * mw.sum())
    # statistics from the training frames
    assert d.x_scale == pytest.approx(0.1)
    assert d.u_scale > 0 and np.isfinite(d.u_scale)
    s = d.summary()
    assert s["validation"] == ["traj_001"] and s["train_frames"] == 30 and s["frame"] == "world"


def _rigid_run(mesh, frames=8, dt=0.01):
    """A trajectory of pure rigid motion: turning about a tilted axis while falling and sliding."""
    from scipy.spatial.transform import Rotation

    x = np.asarray(mesh.vertices)
    c = x.mean(axis=0)
    t = np.arange(frames) * dt
    rots = Rotation.from_rotvec(np.outer(3.0 * t + 0.2, [0.3, -0.5, 0.8])).as_matrix()
    pos = np.einsum("fij,nj->fni", rots, x - c) + c + np.stack([0.4 * t, -0.1 * t, -4.9 * t**2], axis=1)[:, None]
    disp = pos - x
    return Trajectory(x, mesh.tets, disp, np.gradient(disp, dt, axis=0), t, make_synthetic_trajectories(mesh, 1, 2)[0].scene)


def test_body_frame_data_of_a_rigid_run_is_zero(coarse_box):
    run = _rigid_run(coarse_box)
    body = TrainingData([run, run], val_indices=[1], frame="body")
    scale = np.abs(run.displacements).max()
    assert scale > 0.05  # it moved and turned a lot
    assert np.abs(body.train.residuals).max() < 1e-6 * scale
    assert np.abs(body.train.full_displacements(body.rest, slice(None))).max() < 1e-9 * scale
    assert body.train.norm2_full.max() < 1e-20 and body.summary()["frame"] == "body"
    # in the world frame the same run is all displacement (the affine modes hold it)
    world = TrainingData([run, run], val_indices=[1], frame="world")
    np.testing.assert_allclose(world.train.full_displacements(world.rest, slice(None)), run.displacements, atol=1e-9 * scale)


def test_body_frame_data_is_the_deformation_without_rigid_motion(coarse_box, trajs):
    from licrom.rigid import body_frame_displacements

    d = TrainingData(trajs, val_indices=[1], frame="body")
    t = trajs[1]
    expect = body_frame_displacements(d.rest + t.displacements, d.rest, d.masses)
    np.testing.assert_allclose(d.val.full_displacements(d.rest, slice(None)), expect, atol=1e-7 * np.abs(expect).max())
    # a frame turned and moved as a whole gives the same body-frame data
    from scipy.spatial.transform import Rotation

    rot = Rotation.from_rotvec([0.0, 1.2, -0.4]).as_matrix()
    moved = (d.rest + t.displacements) @ rot.T + [1.0, 2.0, 3.0] - d.rest
    turned = Trajectory(d.rest, t.tets, moved, t.velocities, t.times, t.scene)
    d2 = TrainingData([trajs[0], turned], val_indices=[1], frame="body")
    np.testing.assert_allclose(d2.val.residuals, d.val.residuals, atol=1e-6 * np.abs(d.val.residuals).max())


def test_impact_frames_are_training_frames_after_the_regular_ones(trajs):
    t = trajs[0]
    impacts = dataclasses.replace(t, impact_displacements=t.displacements[1:4] * 0.5, impact_times=t.times[1:4] + 1e-3)
    d = TrainingData([impacts, *trajs[1:]], val_indices=[1], frame="body")
    plain = TrainingData(trajs, val_indices=[1], frame="body")
    own = d.train.trajectory == 0
    assert len(d.train) == len(plain.train) + 3 and list(d.train.frame[own][-4:]) == [t.n_frames - 1, -1, -1, -1]
    assert (d.summary()["train_impact_frames"], plain.summary()["train_impact_frames"]) == (3, 0)
    # an impact frame is processed as a regular frame of the same displacement would be
    same = TrainingData([dataclasses.replace(t, displacements=t.displacements[1:4] * 0.5, velocities=t.velocities[1:4],
                                             times=t.times[1:4]), *trajs[1:]], val_indices=[1], frame="body")
    np.testing.assert_allclose(d.train.residuals[own][-3:], same.train.residuals[same.train.trajectory == 0], atol=1e-9)


def test_runs_recorded_every_few_steps_without_impact_frames_are_named_and_warned(trajs):
    t = trajs[0]
    sparse = dataclasses.replace(t, times=t.times * 10)  # a frame every 10th step of the scene's dt
    with_impacts = dataclasses.replace(sparse, impact_displacements=t.displacements[1:3], impact_times=sparse.times[1:3] + 1e-3)
    off_planes = dataclasses.replace(sparse, scene=sparse.scene.replace(planes=()))
    named = [("every_step", t), ("sparse", sparse), ("with_impacts", with_impacts), ("off_planes", off_planes)]
    assert runs_without_impact_frames(named) == ["sparse"]
    data = TrainingData([sparse, *trajs[1:]], val_indices=[1], frame="body")
    assert data.summary()["runs_without_impact_frames"] == [data.names[0]]
    with pytest.warns(AccuracyWarning, match="no impact frames"):
        warn_without_impact_frames(data)
    quiet = TrainingData(trajs, val_indices=[1], frame="body")
    assert quiet.summary()["runs_without_impact_frames"] == []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_without_impact_frames(quiet)


def test_unknown_frame_is_a_config_error_naming_the_frames(trajs):
    with pytest.raises(ConfigError, match="'body', 'world'"):
        TrainingData(trajs, frame="inertial")
    with pytest.raises(ConfigError, match="'body', 'world'"):
        train(trajs, None, TrainConfig(**TINY), ModelConfig(latent_dim=2), frame="Body")
    with pytest.raises(ConfigError, match="frame"):  # prepared data and model must agree
        train(TrainingData(trajs, frame="world"), None, TrainConfig(**TINY), ModelConfig(latent_dim=2), frame="body")


def test_training_data_refuses_mixed_meshes(trajs):
    other = meshes.box((0.2, 0.1, 0.1), resolution=4)
    t2 = make_synthetic_trajectories(other, count=1, frames=3)[0]
    with pytest.raises(ConfigError, match="one rest mesh"):
        TrainingData([trajs[0], t2])
    moved = Trajectory(trajs[0].rest_positions + 1e-3, trajs[0].tets, trajs[0].displacements, trajs[0].velocities, trajs[0].times, trajs[0].scene)
    with pytest.raises(ConfigError, match="one rest mesh"):
        TrainingData([trajs[0], moved])


def test_training_data_errors(tmp_path, trajs):
    with pytest.raises(FileFormatError):
        TrainingData(tmp_path)  # empty directory
    with pytest.raises(FileFormatError):
        TrainingData(tmp_path / "nope")
    with pytest.raises(ConfigError):
        TrainingData(trajs, frame_stride=0)


def test_relative_error():
    m = np.ones(2)
    u = np.array([[1.0, 0, 0], [0, 0, 0]])
    assert relative_error(u, u, m) == 0.0
    assert relative_error(u, 0 * u, m) == pytest.approx(1.0)
    assert relative_error(0 * u, 0 * u, m) == 0.0
    # frames together: sqrt(sum of squared errors / sum of squared norms), masses weighting vertices
    frames = np.stack([u, 2 * u])
    assert relative_error(frames, np.stack([0 * u, 2 * u]), m) == pytest.approx(np.sqrt(1 / 5))
    assert relative_error(frames, frames + [[0, 0, 0], [3, 0, 0]], np.array([1.0, 0.0])) == 0.0


@pytest.mark.parametrize(
    "kwargs",
    [{"epochs": 0}, {"lr": -1.0}, {"sample": "faces"}, {"device": "tpu"}, {"val_fraction": 1.0}, {"batch_frames": 1.5},
     {"projection_weight": -1.0}, {"devices": 0}, {"nodes": 0}, {"objective": "vae"}, {"pod_weighting": "energy"},
     {"join_timeout_s": 0}, {"join_timeout_s": float("inf")}, {"join_timeout_s": True}],
)
def test_train_config_rejects_bad_values(kwargs):
    with pytest.raises(ConfigError):
        TrainConfig(**kwargs)


def test_train_config_names_the_accepted_pod_weightings(coarse_box):
    from licrom.learn.training.objectives import pod_targets

    with pytest.raises(ConfigError, match="'run', 'frame'"):
        TrainConfig(pod_weighting="energy")
    data = TrainingData(make_synthetic_trajectories(coarse_box, count=2, frames=5, seed=1), val_fraction=0.0)
    with pytest.raises(ConfigError, match="'run', 'frame'"):
        pod_targets(data, 2, "energy")
    # The two weightings give two sets of modes of the same shape.
    assert pod_targets(data, 2, "run")[0].shape == pod_targets(data, 2, "frame")[0].shape == (2, coarse_box.n_vertices, 3)


# --- training ----------------------------------------------------------------------------
def test_train_writes_model_curves_plot_and_checkpoints(data_dir, tmp_path, coarse_box):
    out = tmp_path / "m.lcm"
    cfg = TrainConfig(**TINY, val_indices=(3,), seed=5)
    model = train(data_dir, out, cfg, ModelConfig(latent_dim=3), frame="world")
    paths = output_paths(out)
    for key in ("model", "csv", "png"):
        assert paths[key].is_file(), key
    assert (paths["checkpoints"] / "last.ckpt").is_file()
    assert paths["png"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(paths["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    for r in rows:
        for k in ("train_loss", "val_loss", "val_proj_residual", "val_enc_residual", "val_proj_full", "train_seconds"):
            assert np.isfinite(float(r[k])), k
        assert float(r["val_proj_full"]) <= float(r["val_proj_residual"])
    # learning rate decays
    assert float(rows[1]["lr"]) < float(rows[0]["lr"])
    assert model.n_modes == 15 and model.mesh.same_as(coarse_box) and model.frame == "world"
    meta = model.metadata
    assert meta["data"]["validation"] == ["traj_003"] and meta["epochs_trained"] == 2
    assert meta["train_config"]["seed"] == 5 and len(meta["history"]) == 2
    assert model.default_scene == model.scenes[0]
    back = Model.load(out)
    x = coarse_box.vertices[:9]
    np.testing.assert_array_equal(back.values(x), model.values(x))
    np.testing.assert_array_equal(back.jacobians(x), model.jacobians(x))
    assert back.metadata["data"] == meta["data"]
    # the model is mass-orthonormal in its learned block on the rest mesh
    b = model.values(coarse_box.vertices).reshape(-1, model.n_modes)
    mw = np.repeat(coarse_box.vertex_masses(1.0), 3)
    g = b.T @ (mw[:, None] * b)
    np.testing.assert_allclose(g[12:, 12:], mw.sum() / 3 * np.eye(3), rtol=1e-6, atol=1e-9)


def test_same_seed_same_result_on_cpu(trajs, tmp_path):
    cfg = TrainConfig(**TINY, seed=11, device="cpu")
    a = train(trajs, None, cfg, ModelConfig(latent_dim=2))
    b = train(trajs, None, cfg, ModelConfig(latent_dim=2))
    ha, hb = a.metadata["history"], b.metadata["history"]
    assert [r["train_loss"] for r in ha] == [r["train_loss"] for r in hb]
    assert ha[-1]["val_proj_residual"] == hb[-1]["val_proj_residual"]
    for (ka, va), (kb, vb) in zip(a.net.state_dict().items(), b.net.state_dict().items()):
        assert ka == kb and torch.equal(va, vb), ka
    c = train(trajs, None, TrainConfig(**TINY, seed=12, device="cpu"), ModelConfig(latent_dim=2))
    assert c.metadata["history"][-1]["train_loss"] != ha[-1]["train_loss"]


def test_resume_continues_where_it_stopped(trajs, tmp_path, monkeypatch):
    import licrom.learn.training.run as tr

    cfg = TrainConfig(**{**TINY, "epochs": 3}, seed=2)
    full = train(trajs, None, cfg, ModelConfig(latent_dim=2))

    # an interrupted run: stop gracefully after epoch 2 (its checkpoint is written)
    real = tr._lightning_classes

    def stopping():
        classes = real()
        base = classes["History"]

        class StopAfterTwo(base):
            def on_train_epoch_end(self, trainer, pl_module):
                super().on_train_epoch_end(trainer, pl_module)
                if trainer.current_epoch + 1 == 2:
                    trainer.should_stop = True

        return {**classes, "History": StopAfterTwo}

    out = tmp_path / "run.lcm"
    monkeypatch.setattr(tr, "_lightning_classes", stopping)
    part = train(trajs, out, cfg, ModelConfig(latent_dim=2))
    monkeypatch.setattr(tr, "_lightning_classes", real)
    assert part.metadata["epochs_trained"] == 2
    assert (output_paths(out)["checkpoints"] / "last.ckpt").is_file()

    resumed = train(trajs, out, TrainConfig(**{**TINY, "epochs": 3}, seed=2, resume=True), ModelConfig(latent_dim=2))
    hist = resumed.metadata["history"]
    assert [r["epoch"] for r in hist] == [1, 2, 3]
    # the same losses as the uninterrupted run: weights, optimiser, schedule, order and points restored
    assert [r["train_loss"] for r in hist] == [r["train_loss"] for r in full.metadata["history"]]
    for (ka, va), (_kb, vb) in zip(full.net.state_dict().items(), resumed.net.state_dict().items()):
        assert torch.equal(va, vb), ka
    with open(output_paths(out)["csv"]) as fh:
        assert len(list(csv.DictReader(fh))) == 3


def test_encoder_against_exact_projection(tmp_path, capsys):
    # residual exactly in a 3-dimensional space (no rotation): train a little, then compare
    mesh = meshes.box((0.2, 0.1, 0.1), resolution=3)
    trajs = make_synthetic_trajectories(mesh, count=3, frames=12, seed=0, modes=3, rotation=False)
    cfg = TrainConfig(epochs=12, batch_frames=6, points_per_frame=256, encoder_points=128, val_points=128,
                      lr=3e-3, val_fraction=0.0, progress=False, seed=0)
    model = train(trajs, None, cfg, ModelConfig(latent_dim=3, encoder_point_widths=(32, 64), encoder_fc_widths=(32,), frame="world"))
    data = TrainingData(trajs, val_fraction=0.0, affine=True, frame="world")
    masses = data.masses
    err_proj, err_enc, norm = 0.0, 0.0, 0.0
    for t in trajs:
        for f in range(1, t.n_frames, 3):
            u = t.displacements[f]
            q = model.project(u)
            u_proj = model.reconstruct(q)
            q_enc = model.encode_q(mesh.vertices, u)
            np.testing.assert_allclose(q_enc[:12], q[:12], rtol=1e-8, atol=1e-12)  # same affine part
            u_enc = model.reconstruct(q_enc)
            res = u - model.reconstruct(np.concatenate([q[:12], np.zeros(3)]))
            err_proj += np.einsum("ni,ni,n->", u - u_proj, u - u_proj, masses)
            err_enc += np.einsum("ni,ni,n->", u - u_enc, u - u_enc, masses)
            norm += np.einsum("ni,ni,n->", res, res, masses)
    rel_proj, rel_enc = np.sqrt(err_proj / norm), np.sqrt(err_enc / norm)
    with capsys.disabled():
        print(f"\n  residual error on training frames: projection {100 * rel_proj:.2f} %, encoder {100 * rel_enc:.2f} %")
    assert rel_proj <= rel_enc + 1e-9  # the exact projection is optimal in the mass norm
    assert rel_proj < 0.9 and rel_enc < 1.0  # learned something in a few epochs
    ev = evaluate(model, data, "train", points=128)
    assert ev["frames"] == len(data.train) and ev["proj_residual"] <= ev["enc_residual"] + 1e-9


def test_cli_train(data_dir, tmp_path):
    from click.testing import CliRunner
    from licrom.cli.commands import cli

    out = tmp_path / "cli.lcm"
    res = CliRunner().invoke(cli, ["train", str(data_dir), "-o", str(out), "--modes", "2", "--epochs", "1", "--points", "128",
                                   "--batch-frames", "4", "--device", "cpu", "--quiet"])
    assert res.exit_code == 0, res.output
    assert out.is_file() and "held-out projection error" in res.output and "body frame" in res.output
    back = Model.load(out)
    assert back.n_learned == 2 and back.frame == "body"  # body frame by default
    assert back.metadata["train_config"]["pod_weighting"] == "run"  # every training run counts the same by default
    assert back.metadata["train_config"]["cuda_graph"] is True  # on by default (used only on one GPU)
    world = tmp_path / "world.lcm"
    res = CliRunner().invoke(cli, ["train", str(data_dir), "-o", str(world), "--modes", "2", "--epochs", "1", "--points", "128",
                                   "--batch-frames", "4", "--device", "cpu", "--quiet", "--frame", "world", "--objective", "autoencoder",
                                   "--pod-weighting", "frame", "--no-cuda-graph"])
    assert res.exit_code == 0, res.output
    back = Model.load(world)
    assert back.frame == "world" and back.n_modes == 14 and back.metadata["train_config"]["cuda_graph"] is False
    assert back.metadata["train_config"]["objective"] == "autoencoder" and back.metadata["train_config"]["pod_weighting"] == "frame"
    res = CliRunner().invoke(cli, ["train", str(data_dir), "-o", str(tmp_path / "x.lcm"), "--frame", "lab"])
    assert res.exit_code != 0 and "body" in res.output and "world" in res.output


def test_gpus_asked_for_where_there_are_none_are_refused_before_the_data_is_read(tmp_path, monkeypatch, capsys):
    from licrom.cli.commands import main

    missing = tmp_path / "no-such-data"  # refused before it is looked at
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)
    with pytest.raises(ConfigError, match=r"TrainConfig.devices \(--gpus\) is 2 but no CUDA device is available here.*accepted here: devices 'auto' or 1"):
        train(missing, None, TrainConfig(**TINY, devices=2))
    with pytest.raises(ConfigError, match=r"devices \(--gpus\) is 2 but TrainConfig.device is 'cpu'"):
        train(missing, None, TrainConfig(**TINY, devices=2, device="cpu"))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(ConfigError, match=r"is 3 but this machine has 1 CUDA device\(s\); accepted here: 'auto' or 1..1"):
        train(missing, None, TrainConfig(**TINY, devices=3))
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "m.lcm"), "-r", "2", "--gpus", "2", "-q"]) == 2
    assert "--gpus) is 2 but no CUDA device is available here" in capsys.readouterr().err
    assert main(["train", str(tmp_path), "-o", str(tmp_path / "m.lcm"), "-r", "2", "--nodes", "2", "--join-timeout", "0", "-q"]) == 2
    assert "TrainConfig.join_timeout_s must be a finite number of seconds > 0, got 0.0" in capsys.readouterr().err


def test_nodes_whose_peers_never_join_time_out_naming_what_they_wait_for(trajs, monkeypatch):
    import socket
    import time

    with socket.socket() as s:  # a free port for this run's rendezvous
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # The launcher's variables, as on node 0 of 2 whose node 1 never starts; restored after the test.
    for name, value in (("MASTER_ADDR", "127.0.0.1"), ("MASTER_PORT", str(port)), ("NODE_RANK", "0")):
        monkeypatch.setenv(name, value)
    for name in ("WORLD_SIZE", "LOCAL_RANK", "GLOBAL_RANK", "PL_GLOBAL_SEED"):
        monkeypatch.delenv(name, raising=False)
    start = time.perf_counter()
    with pytest.raises(ConfigError, match=rf"the 2 processes of this run \(2 node\(s\) x 1 process\(es\); this one: node rank 0, global rank 0\) "
                                          rf"did not all join at MASTER_ADDR:MASTER_PORT = 127.0.0.1:{port} within 1 s \(TrainConfig.join_timeout_s, "
                                          rf"--join-timeout\): .*1/2 clients joined; start the same command on every node"):
        train(trajs, None, TrainConfig(**TINY, device="cpu", nodes=2, join_timeout_s=1.0), ModelConfig(latent_dim=2))
    assert time.perf_counter() - start < 60  # Lightning alone waits 30 minutes
    assert not torch.distributed.is_initialized()


def test_a_process_age_counts_from_its_start():
    import subprocess
    import sys
    import time

    from licrom.learn.training.run import process_age_s

    before = process_age_s()
    time.sleep(0.3)
    assert 0.25 <= process_age_s() - before <= 5.0  # /proc counts in clock ticks (10 ms)
    # A process that slept 1 s before asking is at least that old, and not older than its whole run.
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", "import time; time.sleep(1.0); from licrom.learn.training.run import process_age_s; "
                          "print(process_age_s())"], capture_output=True, text=True, check=True)
    assert 1.0 <= float(out.stdout) <= time.perf_counter() - start + 0.05


def test_one_machine_waits_for_its_processes_to_start_from_the_beginning():
    from licrom.learn.training.run import JOIN_CATCH_UP, join_timeout_s

    # Lightning starts a machine's other processes at the fit, and they load the runs again: the wait grows with that work.
    assert join_timeout_s(TrainConfig(join_timeout_s=120.0), 300.0) == 120.0 + JOIN_CATCH_UP * 300.0
    # A launcher starts every node's processes at once: the timeout stands as given.
    assert join_timeout_s(TrainConfig(join_timeout_s=120.0, nodes=2), 300.0) == 120.0


# --- the POD bound -------------------------------------------------------------------------
def test_subspace_report_meets_the_pod_bound_on_synthetic_data(coarse_box):
    from licrom.learn.training import subspace_report
    from licrom.rigid import body_frame_displacements
    from licrom.subspace.basis import AffineBasis, MeshBasis, StackedBasis, SubspaceProjector

    # six deformation fields, three learned modes: POD(3) leaves a real error to compare against
    trajs = make_synthetic_trajectories(coarse_box, count=5, frames=20, seed=3, modes=6, rotation=True)
    data = TrainingData(trajs, val_indices=[4])
    cfg = TrainConfig(epochs=10, batch_frames=8, points_per_frame=256, encoder_points=64, val_points=64, progress=False, device="cpu")
    model = train(data, None, cfg, ModelConfig(latent_dim=3, field_width=32, encoder_point_widths=(16, 32), encoder_fc_widths=(16,)))
    rep = subspace_report(model, data)
    assert rep["frame"] == "body" and rep["r"] == 3
    assert (rep["train"]["frames"], rep["val"]["frames"]) == (80, 20)
    for split in ("train", "val"):
        assert 0.01 < rep[split]["pod"] < 1.0 and 0.0 < rep[split]["model"] < 1.0
    # POD(r) is the best r-dimensional subspace for its own training frames
    assert rep["train"]["model"] >= rep["train"]["pod"] * (1 - 1e-9)
    # the bound: held out, at most 1.2x the projection error of POD(r)
    assert rep["val"]["model"] <= 1.2 * rep["val"]["pod"] and rep["ratio"] == rep["val"]["model"] / rep["val"]["pod"]

    # the POD number, computed independently: affine + POD(3) of the body-frame residuals, held-out run projected
    pod, _ = MeshBasis.pod(coarse_box, data.train.residuals, 3)
    values = StackedBasis(AffineBasis(), pod).values(coarse_box.vertices)
    held_out = body_frame_displacements(data.rest + trajs[4].displacements, data.rest, data.masses)
    q = SubspaceProjector(values, data.masses).project(held_out)
    approx = np.einsum("nic,fc->fni", values, q)
    assert relative_error(held_out, approx, data.masses) == pytest.approx(rep["val"]["pod"], rel=1e-4)

    with pytest.raises(ConfigError, match="frame"):
        subspace_report(model, TrainingData(trajs, val_indices=[4], frame="world"))


# --- a body-frame model end to end -------------------------------------------------------
def test_body_frame_model_trains_saves_loads_runs_and_transfers(data_dir, tmp_path, coarse_box):
    from licrom import BodyFrameSim, ReducedSim
    from licrom.reduced.world import WorldFrameSim

    out = tmp_path / "body.lcm"
    model = train(data_dir, out, TrainConfig(**TINY, val_indices=(3,), seed=1), ModelConfig(latent_dim=3, field_width=32))
    assert model.frame == "body" and model.n_modes == 3 and model.metadata["data"]["frame"] == "body"
    # the reported held-out projection error is the final model's (after the output-layer fit)
    from licrom.learn.training import subspace_report

    rep = subspace_report(model, TrainingData(data_dir, val_indices=[3]))
    assert model.metadata["final"]["val_proj_full"] == pytest.approx(rep["val"]["model"], rel=1e-4)
    back = Model.load(out)
    assert back.frame == "body" and back.n_modes == 3
    np.testing.assert_array_equal(back.values(coarse_box.vertices), model.values(coarse_box.vertices))
    sim = ReducedSim(back)
    assert isinstance(sim, BodyFrameSim) and isinstance(sim, ReducedSim) and sim.n_modes == 6 + 3
    traj = sim.run(5)
    assert traj.n_frames == 6 and traj.converged.all() and np.isfinite(traj.displacements).all()
    assert np.abs(traj.displacements[-1]).max() > 0.0
    # the same state on another mesh of the object
    fine = meshes.box((0.2, 0.1, 0.1), resolution=4)
    other = sim.transfer(fine)
    assert isinstance(other, BodyFrameSim) and other.mesh is fine and other.n_modes == 9
    np.testing.assert_allclose(other.center, sim.center, atol=1e-12)
    np.testing.assert_allclose(other.rotation, sim.rotation, atol=1e-12)
    assert other.run(2).converged.all()
    # the world-frame model of the same data gives a world-frame simulation, on either mesh
    world = train(data_dir, None, TrainConfig(**TINY, val_indices=(3,), seed=1), ModelConfig(latent_dim=3, field_width=32), frame="world")
    wsim = ReducedSim(world)
    assert type(wsim) is WorldFrameSim and isinstance(wsim, ReducedSim) and wsim.n_modes == 15
    assert type(wsim.transfer(fine)) is WorldFrameSim
    with pytest.raises(ConfigError, match="newton"):
        ReducedSim(back, solver="prefactored")


# --- checkpoints: weights only, the same run, atomic -------------------------------------
def test_resume_never_runs_code_from_a_checkpoint(trajs, tmp_path):
    out = tmp_path / "m.lcm"
    marker = tmp_path / "code-ran"

    class Planted:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    folder = output_paths(out)["checkpoints"]
    folder.mkdir()
    torch.save({"state_dict": {}, "epoch": 0, "planted": Planted()}, folder / "last.ckpt")
    with pytest.raises(FileFormatError, match=r"not a licrom training checkpoint .*UnpicklingError.*without --resume"):
        train(trajs, out, TrainConfig(**TINY, resume=True), ModelConfig(latent_dim=2))
    assert not marker.exists()


def test_resume_takes_the_same_run_and_names_what_differs(trajs, data_dir, tmp_path, capsys):
    from licrom.cli.commands import main
    from licrom.learn.training.checkpoints import RUN_KEY, read_checkpoint

    out = tmp_path / "m.lcm"
    folder = output_paths(out)["checkpoints"]
    first = train(trajs, out, TrainConfig(**TINY, seed=1), ModelConfig(latent_dim=2))
    first_ckpt = (folder / "last.ckpt").read_bytes()
    # a second run without --resume writes its own last.ckpt (no last-v1.ckpt beside the first run's)
    train(trajs, out, TrainConfig(**TINY, seed=1), ModelConfig(latent_dim=3))
    assert [p.name for p in folder.iterdir()] == ["last.ckpt"]
    assert read_checkpoint(folder / "last.ckpt")[RUN_KEY]["r"] == 3
    with pytest.raises(ConfigError, match=r"another training run: r differs: 3 in the checkpoint, 2 now \(-r/--modes\)"):
        train(trajs, out, TrainConfig(**{**TINY, "epochs": 3}, seed=1, resume=True), ModelConfig(latent_dim=2))
    with pytest.raises(ConfigError, match=r"the network differs: field_width 256 in the checkpoint, 64 now \(--width\)"):
        train(trajs, out, TrainConfig(**TINY, resume=True), ModelConfig(latent_dim=3, field_width=64))
    with pytest.raises(ConfigError, match="the training data differ"):
        train(trajs[:3], out, TrainConfig(**TINY, resume=True), ModelConfig(latent_dim=3))
    # the CLI says the same in one line
    assert main(["train", str(data_dir), "-o", str(out), "-r", "5", "--resume", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("licrom: error: cannot resume from") and "r differs: 3 in the checkpoint, 5 now (-r/--modes)" in err
    assert err.count("\n") == 1
    # with the first run's checkpoint beside the second's (as older versions left them), each run resumes its own
    (folder / "last-v1.ckpt").write_bytes(first_ckpt)
    resumed = train(trajs, out, TrainConfig(**{**TINY, "epochs": 3}, seed=1, resume=True), ModelConfig(latent_dim=2))
    hist = resumed.metadata["history"]
    assert [r["epoch"] for r in hist] == [1, 2, 3] and resumed.n_learned == 2
    assert [r["train_loss"] for r in hist[:2]] == [r["train_loss"] for r in first.metadata["history"]]


def test_checkpoint_writes_are_atomic_and_a_damaged_one_says_start_afresh(trajs, tmp_path, monkeypatch):
    import errno
    import os

    from licrom import OutputError

    out = tmp_path / "m.lcm"
    cfg = TrainConfig(**TINY, seed=4)
    train(trajs, out, cfg, ModelConfig(latent_dim=2))
    folder = output_paths(out)["checkpoints"]
    good = (folder / "last.ckpt").read_bytes()

    def full_disk(obj, f, *args, **kwargs):
        with open(f, "wb") as fh:
            fh.write(good[:100])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(torch, "save", full_disk)
    with pytest.raises(OutputError, match=r"last\.ckpt': no space left on the device"):
        train(trajs, out, cfg, ModelConfig(latent_dim=2))
    monkeypatch.undo()
    assert [p.name for p in folder.iterdir()] == ["last.ckpt"] and (folder / "last.ckpt").read_bytes() == good
    (folder / "last.ckpt").write_bytes(good[: len(good) // 2])  # cut short, as by a crash of an older version
    with pytest.raises(FileFormatError, match=r"last\.ckpt' is truncated, corrupt .*start afresh: run again without --resume"):
        train(trajs, out, TrainConfig(**TINY, seed=4, resume=True), ModelConfig(latent_dim=2))


def test_runs_without_deformation_are_refused_naming_the_runs(coarse_box, tmp_path):
    rigid = make_synthetic_trajectories(coarse_box, count=2, frames=4, seed=1, amplitude=0.0)  # rigid motion only
    still = [Trajectory(coarse_box.vertices, coarse_box.tets, np.zeros((3, coarse_box.n_vertices, 3)), np.zeros((3, coarse_box.n_vertices, 3)),
                        [0.0, 0.01, 0.02], rigid[0].scene) for _ in range(2)]
    for k, t in enumerate(rigid):
        t.save(tmp_path / f"rigid_{k}.npz", precision="float64")
    for runs, frame in ((tmp_path, "body"), (still, "world")):
        with pytest.raises(ConfigError, match=r"no training run holds any .*below 1e-09 of the object's size .*round-off only: "
                                              r"(rigid_0 .*m\), rigid_1|.*, .*)"):
            train(runs, None, TrainConfig(**TINY, val_fraction=0.0), ModelConfig(latent_dim=2), frame=frame)
    # a run that deforms is enough: the data check passes
    data = TrainingData([*still, make_synthetic_trajectories(coarse_box, count=1, frames=4, seed=2)[0]], val_fraction=0.0, frame="world")
    data.check_deformation()
    assert min(data.residual_rms().values()) == 0.0 and max(data.residual_rms().values()) > 1e-6 * coarse_box.size


def test_progress_bar_counts_epochs_from_one(trajs, capsys):
    """Two epochs show as 'Epoch 1/2' and 'Epoch 2/2' (Lightning's own bar ends at 'Epoch 1', or 'Epoch 1/1')."""
    train(trajs, None, TrainConfig(**{**TINY, "progress": True, "cubature_points": 10}), ModelConfig(latent_dim=2, frame="world"))
    shown = "".join(capsys.readouterr())  # Lightning's bars write to stdout
    epochs = [part for part in shown.replace("\n", "\r").split("\r") if part.startswith("Epoch")]
    assert any(p.startswith("Epoch 1/2: 100%") for p in epochs) and epochs[-1].startswith("Epoch 2/2: 100%")


def test_the_training_report_says_how_many_frames_are_impact_frames():
    from licrom.cli.commands import _frames_of

    assert _frames_of({"train_frames": 10, "train_impact_frames": 3}, "train") == "10 frames, 3 of them impact frames"
    assert _frames_of({"validation_frames": 4, "validation_impact_frames": 0}, "validation") == "4 frames"
