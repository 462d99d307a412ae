"""Sizes against what the machine can hold (licrom._limits): every size is checked before anything is allocated.

TrainConfig, ModelConfig, the procedural meshes and the command line's size options refuse sizes
whose estimated bytes pass the memory limit with a ConfigError naming the size, the estimate and
the limit (never an allocator traceback, an OOM kill or an OverflowError), and a cheese whose holes
cannot be placed is refused, naming how many fit. The tests fix ``LICROM_MEMORY_LIMIT`` so they do
not depend on this machine's memory, and never allocate the sizes they refuse.
"""

import os
import time
from unittest import mock

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from licrom import ConfigError, meshes
from licrom._limits import ENV_VAR, check_memory, format_bytes, memory_limit
from licrom.cli.commands import main
from licrom.learn.model import ModelConfig
from licrom.learn.model.networks import state_size
from licrom.learn.training import TrainConfig
from licrom.learn.training.config import check_training_memory

PROPERTY = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

# Sizes from tiny to 2**80: zero, negatives, bools and bool-likes, numpy integers, the int64 edges, other types.
SIZES = st.one_of(
    st.integers(-(2**80), 2**80),
    st.integers(-3, 5000),
    st.sampled_from([0, 1, -1, True, False, np.True_, np.int64(2**62), 2**31, 2**63 - 1, 2**63, 2**64, 2**70, 2**80,
                     10**9, 10**6, 2.5, "8", None]),
)
# The command line's spelling of those sizes.
FLAG_VALUES = st.one_of(st.integers(-(2**80), 2**80).map(str), st.integers(-3, 64).map(str), st.integers(-3, 5000).map(str), st.sampled_from(["0", "-1", "true", "True", "1.5", "2**70", "1e9", ""]))


def test_limit_comes_from_the_environment_variable(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "64M")
    assert memory_limit() == (64 * 2**20, f"{ENV_VAR}=64M")
    monkeypatch.setenv(ENV_VAR, "12345")
    assert memory_limit()[0] == 12345
    for bad in ("lots", "-1G", "0"):
        monkeypatch.setenv(ENV_VAR, bad)
        with pytest.raises(ConfigError, match=ENV_VAR):
            memory_limit()
    monkeypatch.delenv(ENV_VAR)
    limit, source = memory_limit()
    physical = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert 0 < limit < physical and "physical memory" in source and ENV_VAR in source


def test_check_memory_names_the_argument_the_estimate_and_the_limit(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "1G")
    check_memory("x", 5, 2**30, "fits exactly")
    with pytest.raises(ConfigError, match=r"^x=1\.181e\+21 needs about 2 GiB \(what\), over the memory limit of 1 GiB "
                                          rf"\({ENV_VAR}=1G\)$"):
        check_memory("x", 2**70, 2**31, "what")
    assert format_bytes(10**400).endswith("e+400 B")  # no float overflow


@pytest.fixture
def limit_16g(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "16G")


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"points_per_frame": 10**9}, "points_per_frame=1000000000"),  # grew to 23 GB and was killed
    ({"points_per_frame": 2**70}, r"points_per_frame=1\.181e\+21"),
    ({"batch_frames": 10**9}, "batch_frames=1000000000"),
    ({"val_points": 10**10}, "val_points=10000000000"),
])
def test_train_config_refuses_sizes_beyond_memory(limit_16g, kwargs, name):
    with pytest.raises(ConfigError, match=rf"^TrainConfig\.{name} needs about .* over the memory limit of 16 GiB"):
        TrainConfig(**kwargs)


@pytest.mark.parametrize(("kwargs", "name"), [
    ({"latent_dim": 10**9}, "latent_dim=1000000000"),  # -r 1000000000: an allocator traceback
    ({"field_width": 10**8}, "field_width=100000000"),  # --width 100000000: an allocator traceback
    ({"field_layers": 2**70}, r"field_layers=1\.181e\+21"),  # OverflowError in state_size
    ({"fourier_features": 2**80}, r"fourier_features=1\.209e\+24"),
    ({"encoder_point_widths": (64, 10**9)}, r"encoder_point_widths=\(64, 1000000000\)"),
])
def test_model_config_refuses_sizes_beyond_memory(limit_16g, kwargs, name):
    with pytest.raises(ConfigError, match=rf"^ModelConfig\.{name} needs about .* network weights .* over the memory limit of 16 GiB"):
        ModelConfig(**kwargs)


def test_points_and_width_are_checked_together(limit_16g):
    train, model = TrainConfig(points_per_frame=10**6), ModelConfig(field_width=4096)  # each fits alone
    with pytest.raises(ConfigError, match=r"^TrainConfig\.points_per_frame=1000000 needs about \d+ GiB .* the network as given\), "
                                          "over the memory limit of 16 GiB"):
        check_training_memory(train, model)
    with pytest.raises(ConfigError, match=r"^ModelConfig\.field_width=100000 needs about"):
        check_training_memory(TrainConfig(), ModelConfig(latent_dim=4, field_width=10**5, field_layers=2))


def test_defaults_fit_in_a_gigabyte(monkeypatch):
    monkeypatch.setenv(ENV_VAR, "1G")
    check_training_memory(TrainConfig(), ModelConfig(latent_dim=120))
    assert meshes.cheese().n_tets > 0 and meshes.sphere().n_tets > 0 and meshes.box().n_tets > 0
    assert meshes.cheese(resolution=42).n_tets > 100_000  # the module docstring's 100k-tet cheese


@pytest.mark.parametrize("resolution", [100000, 2**70, 10**400])
@pytest.mark.parametrize("shape", ["box", "sphere", "cheese"])
def test_mesh_resolution_beyond_memory_is_refused_before_meshing(limit_16g, shape, resolution):
    start = time.perf_counter()
    with pytest.raises(ConfigError, match=r"^resolution=\S+ needs about .* tets from a .* grid.* over the memory limit of 16 GiB"):
        meshes.PROCEDURAL[shape](resolution=resolution)
    assert time.perf_counter() - start < 0.5


def test_hole_count_that_cannot_fit_fails_fast():
    start = time.perf_counter()
    for count in (100000, 2**70):  # 100000 tried for over 120 s
        with pytest.raises(ConfigError, match=r"^CheeseHoles\.count must be at most 205 for a 0\.2 x 0\.12 x 0\.1 m block"):
            meshes.cheese(holes=meshes.CheeseHoles(count=count))
    assert time.perf_counter() - start < 0.5


def test_fewer_holes_placed_than_asked_is_an_error_naming_how_many():
    with pytest.raises(ConfigError, match=r"^CheeseHoles\.count=100: only 37 holes could be placed in the 0\.2 x 0\.12 x 0\.1 m block"):
        meshes.cheese(holes=meshes.CheeseHoles(count=100))  # placed 37 without a word
    with pytest.raises(ConfigError, match=r"CheeseHoles\.count must be an integer >= 0"):
        meshes.CheeseHoles(count=True)


def test_cli_size_options_beyond_memory_are_one_line_errors_naming_the_flag(limit_16g, tmp_path, capsys):
    out = str(tmp_path / "m.lcm")
    for flags, text in [(["--points", "1000000000"], "--points: TrainConfig.points_per_frame=1000000000 needs about"),
                        (["-r", "1000000000"], "--modes / -r: ModelConfig.latent_dim=1000000000 needs about"),
                        (["--width", "100000000"], "--width: ModelConfig.field_width=100000000 needs about"),
                        (["--points", "1000000", "--width", "4096"], "--points: TrainConfig.points_per_frame=1000000 needs about")]:
        assert main(["train", str(tmp_path), "-o", out] + flags) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"licrom: error: {text}") and "over the memory limit of 16 GiB" in err and err.count("\n") == 1, err
    for args in (["mesh", "cheese", "--resolution", "100000"], ["mesh", "cheese", "--resolution", str(2**70)],
                 ["generate", str(tmp_path / "g"), "-r", "100000"], ["demo", "-r", "1000000000", "--out", str(tmp_path / "d")]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "needs about" in err and "over the memory limit of 16 GiB" in err and err.count("\n") == 1, err
    assert main(["mesh", "cheese", "--holes", "100000"]) == 2
    assert "CheeseHoles.count must be at most 205" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# --- properties: any size gives a valid config or a ConfigError, quickly, and a valid one fits --------------------------
@PROPERTY
@given(name=st.sampled_from(["points_per_frame", "batch_frames", "encoder_points", "val_points", "val_encoder_frames"]), value=SIZES)
def test_train_config_sizes_give_a_config_that_fits_or_a_config_error(name, value):
    with mock.patch.dict(os.environ, {ENV_VAR: "1G"}):
        try:
            cfg = TrainConfig(**{name: value})
        except ConfigError:
            return
    # the step's displacements alone (batch_frames x points_per_frame x 3 float32) fit
    assert cfg.batch_frames * cfg.points_per_frame * 12 <= 2**30


@PROPERTY
@given(name=st.sampled_from(["latent_dim", "field_width", "field_layers", "fourier_features"]), value=SIZES)
def test_model_config_sizes_give_a_config_that_fits_or_a_config_error(name, value):
    with mock.patch.dict(os.environ, {ENV_VAR: "1G"}):
        try:
            cfg = ModelConfig(**{name: value, "latent_dim": 8} if name != "latent_dim" else {name: value})
        except ConfigError:
            return
    if cfg.latent_dim != "auto":
        assert 4 * state_size(cfg) <= 2**30  # the float32 weights alone fit


class _Reached(Exception):
    """The train command got past its checks to licrom.train."""


@PROPERTY
@given(flag=st.sampled_from(["--points", "--batch-frames", "-r", "--width", "--layers", "--fourier", "--max-rank"]), value=FLAG_VALUES)
def test_train_command_size_options_give_a_one_line_error_or_configs_that_fit(tmp_path, flag, value):
    def stub(data, output, train_config, model_config):
        raise _Reached(train_config, model_config)

    with mock.patch.dict(os.environ, {ENV_VAR: "1G"}), mock.patch("licrom.learn.training.train", stub):
        try:
            rc = main(["train", str(tmp_path), "-o", str(tmp_path / "m.lcm"), flag, value])
        except _Reached as reached:
            train_config, model_config = reached.args
            sizes = model_config if model_config.latent_dim != "auto" else ModelConfig(**{**model_config.to_dict(), "latent_dim": 1})
            assert 4 * state_size(sizes) + 12 * train_config.batch_frames * train_config.points_per_frame <= 2**30
            return
    assert rc == 2  # a LicromError or click's usage error, one line each


@PROPERTY
@given(option=st.sampled_from(["--resolution", "--holes"]), shape=st.sampled_from(["box", "sphere", "cheese"]), value=FLAG_VALUES)
def test_mesh_command_size_options_give_a_mesh_or_a_one_line_error(option, shape, value):
    if option == "--holes":
        shape = "cheese"
    # A limit of 32 MiB: the meshes that fit are small, the property never meshes for long.
    with mock.patch.dict(os.environ, {ENV_VAR: "32M"}):
        start = time.perf_counter()
        assert main(["mesh", shape, option, value]) in (0, 2)
        assert time.perf_counter() - start < 5
