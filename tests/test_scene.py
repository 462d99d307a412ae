import json
import math

import numpy as np
import pytest
from licrom import ConfigError, ContactParams, FileFormatError, InitialState, Material, Plane, Scene, SolverParams


def test_snh_parameters_match_linear_elasticity():
    m = Material(youngs_modulus=1e6, poisson_ratio=0.3)
    mu, lam = m.lame
    assert mu == pytest.approx(1e6 / 2.6)
    smu, slam = m.snh_parameters
    assert smu == pytest.approx(4 / 3 * mu)
    assert slam == pytest.approx(lam + 5 / 6 * mu)


def test_plane_is_normalised_with_offset():
    p = Plane(normal=(0, 0, 2), offset=-1.0, friction=0.3)
    assert p.normal == (0.0, 0.0, 1.0)
    assert p.offset == pytest.approx(-0.5)  # same half-space: 2z - 1 >= 0  <=>  z - 0.5 >= 0
    inc = Plane.incline(30.0, 0.4)
    assert inc.slope_deg == pytest.approx(30.0)
    assert np.linalg.norm(inc.normal) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "normal, offset, expected_normal, expected_offset",
    [
        ((0, 0, 1e200), 0.0, (0, 0, 1), 0.0),
        ((0, 0, 1e200), 3e200, (0, 0, 1), 3.0),
        ((1e-320, 0, 0), -1e-320, (1, 0, 0), -1.0),
        ((3e-300, 4e-300, 0), 1e-300, (0.6, 0.8, 0), 0.2),
        ((1e308, 1e308, 1e308), 0.0, (3**-0.5,) * 3, 0.0),
    ],
)
def test_plane_normalises_huge_and_tiny_normals(normal, offset, expected_normal, expected_offset):
    p = Plane(normal=normal, offset=offset)
    np.testing.assert_allclose(p.normal, expected_normal, rtol=1e-15, atol=1e-15)
    assert p.offset == pytest.approx(expected_offset, rel=1e-15, abs=1e-300)
    back = Scene.from_json(Scene(planes=(p,)).to_json()).planes[0]
    np.testing.assert_allclose(back.normal, p.normal, rtol=1e-15, atol=1e-15)
    assert back.offset == pytest.approx(p.offset, rel=1e-15, abs=1e-300)


@pytest.mark.parametrize("normal, offset", [((0, 0, 1), 1e300), ((0, 0, 1), -2e6), ((0, 0, 1e-300), 1.0), ((0, 0, 1e-320), 1e-300)])
def test_plane_refuses_offsets_beyond_its_range(normal, offset):
    with pytest.raises(ConfigError, match=r"Plane\.offset / \|Plane\.normal\|.*\[-1e\+06, 1e\+06\] m"):
        Plane(normal=normal, offset=offset)
def test_incline_azimuth_turns_the_downhill_direction_and_steep_angles_are_refused():
    for azimuth in (0.0, 45.0, 90.0, -135.0):
        p = Plane.incline(25.0, 0.3, azimuth_deg=azimuth)
        assert p.slope_deg == pytest.approx(25.0) and p.azimuth_deg == pytest.approx(azimuth)
        downhill = np.array([np.cos(np.radians(azimuth)), np.sin(np.radians(azimuth)), 0.0])
        assert np.dot(p.normal, downhill) > 0  # the plane descends that way: its normal leans towards it
    assert Plane.incline(25.0, 0.3) == Plane.incline(25.0, 0.3, azimuth_deg=0.0)
    assert Plane().azimuth_deg == 0.0
    # 95 deg used to give a plane facing down that reads as an 85 deg slope.
    for angle in (95.0, 90.0, -5.0):
        with pytest.raises(ConfigError, match=r"Plane.incline angle must be in \[0, 90\) degrees"):
            Plane.incline(angle, 0.3)


def test_scene_json_round_trip():
    s = Scene(
        material=Material(3e5, 0.25, 1100.0),
        planes=(Plane.incline(20, 0.3), Plane((1, 0, 0), 0.5, 0.1)),
        gravity=(0, 0, -9.8),
        dt=0.005,
        contact=ContactParams(1e7, 10.0, 3e6),
        solver=SolverParams(1e-7, 30, "record", 3e-5),
        initial=InitialState(translation=(0, 0, 0.1), rotation=(0.1, 0.2, 0.3), velocity=(1, 0, 0)),
    )
    back = Scene.from_json(s.to_json())
    assert back == s


def test_initial_state_is_rigid():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((20, 3))
    m = rng.uniform(1, 2, 20)
    st = InitialState(translation=(1, 2, 3), rotation=(0.3, -0.2, 0.5), angular_velocity=(0, 0, 2.0))
    pos, vel = st.apply(x, m)
    d0 = np.linalg.norm(x[:, None] - x[None], axis=2)
    d1 = np.linalg.norm(pos[:, None] - pos[None], axis=2)
    np.testing.assert_allclose(d1, d0, atol=1e-12)
    com0 = (m[:, None] * x).sum(0) / m.sum()
    com1 = (m[:, None] * pos).sum(0) / m.sum()
    np.testing.assert_allclose(com1 - com0, [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose((m[:, None] * vel).sum(0), 0.0, atol=1e-12)  # pure spin
    r = st.rotation_matrix()
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Material(youngs_modulus=-1.0), r"youngs_modulus .* must be > 0"),
        (lambda: Material(poisson_ratio=0.5), r"poisson_ratio must be in \(-1, 0.5\)"),
        (lambda: Material(density=float("nan")), "must be finite"),
        (lambda: Material(viscosity=-1.0), r"viscosity \(Pa s\) must be >= 0"),
        (lambda: Plane(normal=(0, 0, 0)), "non-zero vector"),
        (lambda: Plane(friction=-0.1), "friction must be >= 0"),
        (lambda: ContactParams(normal_stiffness=0), "normal_stiffness .* must be > 0"),
        (lambda: SolverParams(on_failure="ignore"), "'raise' or 'record'"),
        (lambda: SolverParams(reduced_tolerance=0.0), r"reduced_tolerance \(m/s\) must be > 0"),
        (lambda: Scene(dt=0.0), r"dt \(s\) must be > 0"),
        (lambda: Scene(gravity=(0, 0)), "3 real numbers"),
    ],
)
def test_bad_parameters(make, match):
    with pytest.raises(ConfigError, match=match):
        make()


def test_a_scene_saved_before_the_reduced_tolerance_loads_with_its_default():
    d = Scene(solver=SolverParams(tolerance=1e-7)).to_dict()
    del d["solver"]["reduced_tolerance"]
    back = Scene.from_json(json.dumps(d))
    assert back.solver.tolerance == 1e-7 and back.solver.reduced_tolerance == SolverParams().reduced_tolerance


def test_a_scene_saved_before_the_viscosity_loads_undamped():
    d = Scene(material=Material(viscosity=400.0)).to_dict()
    assert Scene.from_json(json.dumps(d)).material.viscosity == 400.0
    del d["material"]["viscosity"]
    assert Scene.from_json(json.dumps(d)).material.viscosity == 0.0


def test_unknown_scene_version():
    d = Scene().to_dict()
    d["version"] = 99
    with pytest.raises(FileFormatError, match="version 99; this licrom reads version 1"):
        Scene.from_json(json.dumps(d))
    d["version"] = True  # JSON true is not version 1
    with pytest.raises(FileFormatError, match="version True; this licrom reads version 1"):
        Scene.from_json(json.dumps(d))
    with pytest.raises(FileFormatError, match="not a licrom scene"):
        Scene.from_json('{"planes": []}')
    with pytest.raises(FileFormatError, match="not valid JSON"):
        Scene.from_json('{"format": "licrom.scene", ')
    assert math.isclose(Scene().dt, 0.01)


def test_a_bool_is_not_a_count_and_deep_json_is_a_file_format_error():
    with pytest.raises(ConfigError, match=r"SolverParams\.max_iterations must be an integer >= 1, got True"):
        SolverParams(max_iterations=True)
    deep = '{"format": "licrom.scene", "version": 1, "material": ' + "[" * 100_000 + "]" * 100_000 + "}"
    with pytest.raises(FileFormatError, match="nested too deeply"):
        Scene.from_json(deep)


def test_a_huge_rotation_vector_is_refused_with_the_accepted_length():
    for rotation in ((1e300, 0, 0), (0, 2e6, 0), (1e154, 1e154, 1e154)):
        with pytest.raises(ConfigError, match=r"InitialState.rotation must be a rotation vector of length <= 1e\+06 rad"):
            InitialState(rotation=rotation)
    turns = InitialState(rotation=(0, 0, 1000 * 2 * np.pi))  # many whole turns: still the identity
    np.testing.assert_allclose(turns.rotation_matrix(), np.eye(3), atol=1e-9)


def test_scene_file_names_over_the_file_system_limit_are_named(tmp_path):
    from licrom.data.scene_file import load_scene

    with pytest.raises(FileFormatError, match="its name is 305 bytes long, over the file system's limit of 255 bytes"):
        load_scene(tmp_path / ("s" * 300 + ".toml"))


@pytest.mark.parametrize("planes", [Plane(), 3, "ground"])
def test_planes_that_are_not_a_sequence_are_named(planes):
    with pytest.raises(ConfigError, match=r"Scene.planes must be a sequence of Plane objects \(planes=\(Plane\(...\),\) for one"):
        Scene(planes=planes)
    assert Scene(planes=[Plane()]).planes == (Plane(),) and Scene(planes=()).planes == ()
