import numpy as np
import pytest
from licrom import ConfigError, meshes


def test_box_is_exact():
    m = meshes.box((0.2, 0.1, 0.1), resolution=4)
    assert m.volume == pytest.approx(0.002)
    assert m.n_tets == 4 * 2 * 2 * 6
    lo, hi = m.bounds
    np.testing.assert_allclose(hi - lo, [0.2, 0.1, 0.1])


def test_sphere_volume_converges():
    exact = 4 / 3 * np.pi * 0.05**3
    errors = [abs(meshes.sphere(0.05, r).volume - exact) / exact for r in (6, 12, 24)]
    assert errors[2] < errors[0]
    assert errors[2] < 0.01
    q = meshes.sphere(0.05, 12).quality()
    assert q.min_volume > 0 and q.min_dihedral_deg > 3.0


def test_cheese_is_deterministic_and_has_holes():
    a = meshes.cheese(resolution=10)
    b = meshes.cheese(resolution=10)
    assert a.same_as(b)
    other = meshes.cheese(resolution=10, holes=meshes.CheeseHoles(seed=3))
    assert not a.same_as(other)
    block = 0.2 * 0.12 * 0.1
    assert 0.5 * block < a.volume < 0.97 * block
    # holes make extra boundary: more surface than the bare block
    assert a.surface_area > 2 * (0.2 * 0.12 + 0.2 * 0.1 + 0.12 * 0.1)


def test_resolution_controls_tet_count():
    counts = [meshes.cheese(resolution=r).n_tets for r in (6, 12)]
    assert 6 < counts[1] / counts[0] < 10


@pytest.mark.parametrize("bad", [0, -3, 2.5, "8"])
def test_bad_resolution(bad):
    with pytest.raises(ConfigError, match="resolution"):
        meshes.cheese(resolution=bad)


def test_bad_size():
    with pytest.raises(ConfigError, match="size"):
        meshes.box((0.1, -0.1, 0.1))
