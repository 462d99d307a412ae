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
def tiny_demo(tmp_path_factory):
    """The README's main job on an 84-tet cheese: ``(output folder, summary)``.

    Held-out scenes at 20 deg (tan = 0.36): mu 0.1 slides, mu 0.9 sticks.
    """
    from licrom.demo import DemoConfig, run_demo

    out = tmp_path_factory.mktemp("demo") / "demo"
    config = DemoConfig(out_dir=str(out), resolution=4, train_slopes=(10.0, 30.0), train_frictions=(0.3, 0.6),
                        test_cases=((20.0, 0.1), (20.0, 0.9)), steps=60, modes=4, epochs=3, cubature_points=40)
    return out, run_demo(config, progress=False)
