import json

import numpy as np
import pytest
from licrom.cli.demo import DemoConfig
from licrom.errors import ConfigError


def test_demo_writes_every_output(tiny_demo):
    out, summary = tiny_demo
    for name in ("cheese.vtu", "model.lcm", "model.losses.csv", "model.losses.png", "errors.png", "summary.md", "report.html",
                 "filmstrip_slope20_mu0.1.png", "filmstrip_slope20_mu0.9.png", "animation_slope20_mu0.1.gif",
                 "animation_slope20_mu0.9.gif", "runs/full_slope20_mu0.1.npz", "runs/reduced_slope20_mu0.9.npz",
                 "vtu_slope20_mu0.1/full/full.pvd", "vtu_slope20_mu0.9/reduced/reduced.pvd"):
        assert (out / name).is_file(), name
    assert len(list((out / "data").glob("*.npz"))) == 4
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert "| slope 20 deg, mu 0.1 |" in (out / "summary.md").read_text()


def test_demo_reduced_runs_follow_the_full_ones(tiny_demo):
    slides, sticks = tiny_demo[1]["cases"]
    assert slides["slid_full"] and not sticks["slid_full"]  # tan 20 deg = 0.36 against mu 0.1 and 0.9
    for case in (slides, sticks):
        assert case["stick_slip_agree"]
        assert 0.0 <= case["mean_error"] < 0.05
        assert case["reduced_step_ms"] < case["full_step_ms"]


def test_demo_without_pyvista_draws_with_matplotlib_and_says_so(tmp_path, monkeypatch, capsys, tiny_demo_scene):
    from licrom import render
    from licrom.cli.demo import run_demo

    monkeypatch.setattr(render, "pyvista_unavailable", lambda: "PyVista is not installed (pip install 'licrom[render]')")
    scene = tmp_path / "one.toml"
    one_run = tiny_demo_scene.replace("frictions = [0.3, 0.6]", "frictions = [0.3]").replace("slopes = [10.0, 30.0]", "slopes = [10.0]")
    scene.write_text("[[held_out]]".join(one_run.split("[[held_out]]")[:2]))  # held out: 20 deg, mu 0.1
    config = DemoConfig(out_dir=str(tmp_path / "out"), scene=str(scene), resolution=4, steps=10, modes=2, epochs=1, cubature_points=20)
    run_demo(config, progress=False)
    said = capsys.readouterr().out
    assert said.count("pictures: PyVista is not installed (pip install 'licrom[render]'); drawing them with matplotlib") == 1
    for name in ("filmstrip_slope20_mu0.1.png", "animation_slope20_mu0.1.gif", "report.html"):
        assert (tmp_path / "out" / name).is_file(), name


def test_demo_saves_the_runs_it_pictures(tiny_demo):
    from licrom import Trajectory

    full = Trajectory.load(tiny_demo[0] / "runs" / "full_slope20_mu0.1.npz")
    reduced = Trajectory.load(tiny_demo[0] / "runs" / "reduced_slope20_mu0.1.npz")
    assert full.n_frames == reduced.n_frames == 61 and full.info["source"] == "full"
    assert np.abs(reduced.displacements[-1] - full.displacements[-1]).max() < 0.1 * full.mesh.size


def test_demo_trains_on_the_cpu_by_default(tiny_demo):
    # its budget was measured there; on a GPU another draw of the points lands elsewhere (results section 44)
    from licrom import Model

    assert Model.load(tiny_demo[0] / "model.lcm").metadata["train_config"]["device"] == "cpu"


def test_demo_refuses_a_held_out_scene_from_the_training_set(tmp_path, tiny_demo_scene):
    from licrom.cli.demo import run_demo

    scene = tmp_path / "s.toml"
    scene.write_text(tiny_demo_scene.replace("friction = 0.9", "friction = 0.6").replace("slope = 20.0\nfriction = 0.6", "slope = 30.0\nfriction = 0.6"))
    with pytest.raises(ConfigError, match="held-out"):
        run_demo(DemoConfig(out_dir=str(tmp_path / "out"), scene=str(scene)), progress=False)
    assert not (tmp_path / "out").exists()  # refused before anything ran
    scene.write_text(tiny_demo_scene.split("[[held_out]]")[0])
    with pytest.raises(ConfigError, match=r"needs held-out scenes"):
        run_demo(DemoConfig(out_dir=str(tmp_path / "out"), scene=str(scene)), progress=False)


@pytest.mark.parametrize("field, value", [("epochs", 0), ("modes", -1), ("steps", 0), ("cubature_points", 0),
                                          ("resolution", 2), ("frame", "space"), ("train_device", "gpu")])
def test_demo_refuses_bad_settings_before_simulating(field, value):
    with pytest.raises(ConfigError, match=f"DemoConfig.{field}"):
        DemoConfig(**{field: value})
