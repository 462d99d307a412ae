import numpy as np
import pytest


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


@pytest.fixture
def unit_tet():
    from licrom import Mesh

    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    return Mesh(v, np.array([[0, 1, 2, 3]]))


@pytest.fixture(scope="session")
def coarse_box():
    """The coarse box (0.2 x 0.1 x 0.1 m, resolution 3) that the training and rank tests make synthetic runs on."""
    from licrom import meshes

    return meshes.box((0.2, 0.1, 0.1), resolution=3)


@pytest.fixture(scope="session")
def tiny_demo(tmp_path_factory):
    """The README's main job on an 84-tet cheese: ``(output folder, summary)``.

    Held-out scenes at 20 deg (tan = 0.36): mu 0.1 slides, mu 0.9 sticks.
    """
    from licrom.cli.demo import DemoConfig, run_demo

    root = tmp_path_factory.mktemp("demo")
    out = root / "demo"
    (root / "tiny.toml").write_text(TINY_DEMO_SCENE)
    config = DemoConfig(out_dir=str(out), scene=str(root / "tiny.toml"), resolution=4, steps=60, modes=4, epochs=3, cubature_points=40)
    return out, run_demo(config, progress=False)


@pytest.fixture
def tiny_demo_scene():
    """The text of the tiny demo's scene file."""
    return TINY_DEMO_SCENE


# The built-in demo scene with a smaller sweep and held-out scenes that slide and stick.
TINY_DEMO_SCENE = """
version = 1
[object]
mesh = "cheese"
[material]
youngs_modulus = 1.0e5
[[planes]]
friction = 0.5
[sweep]
frictions = [0.3, 0.6]
slopes = [10.0, 30.0]
[[initial]]
drop_height = 0.01
[[held_out]]
slope = 20.0
friction = 0.1
[[held_out]]
slope = 20.0
friction = 0.9
"""
