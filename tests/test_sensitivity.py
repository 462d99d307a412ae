import math

import numpy as np
import pytest
from licrom import Material, Plane, Scene, meshes
from licrom.analysis.sensitivity import CHAOTIC_SPREAD, HALF_STEP, Perturbations, perturbed_scenes, sensitivity
from licrom.errors import ConfigError
from licrom.scene.placement import drop_state


def _angle(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return math.degrees(math.acos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


def test_each_input_moves_alone_by_its_amount():
    plane = Plane.incline(25.0, friction=0.4)
    scene = Scene(material=Material(youngs_modulus=3e4), planes=(plane, Plane((0, 1, 0), 1.0, 0.2)), gravity=(0.0, -3.0, -9.0), dt=0.004)
    p = Perturbations(drop=2e-3, tilt_deg=0.7, friction=0.03, stiffness=0.05)
    scenes = perturbed_scenes(scene, p)
    assert list(scenes)[-1] == HALF_STEP and len(scenes) == 6
    g = np.asarray(scene.gravity)
    up = -g / np.linalg.norm(g)
    higher = scenes["2 mm higher"]
    np.testing.assert_allclose(np.subtract(higher.initial.translation, scene.initial.translation), 2e-3 * up, atol=1e-15)
    turned = [np.asarray(scenes[f"gravity turned 0.7 deg ({k})"].gravity) for k in (1, 2)]
    for t in turned:
        assert np.linalg.norm(t) == pytest.approx(np.linalg.norm(g), rel=1e-12)
        assert _angle(t, g) == pytest.approx(0.7, rel=1e-6)
    # turned about two horizontal axes at right angles: the two changes are perpendicular
    assert _angle(turned[0] - g, turned[1] - g) == pytest.approx(90.0, abs=0.5)
    assert [pl.friction for pl in scenes["mu +0.03"].planes] == pytest.approx([0.43, 0.23])
    assert scenes["E +5 %"].material.youngs_modulus == pytest.approx(3.15e4)
    assert scenes[HALF_STEP].dt == pytest.approx(0.002)
    for label, moved in scenes.items():  # everything else as it was
        same = {"2 mm higher": "initial", "mu +0.03": "planes", "E +5 %": "material", HALF_STEP: "dt"}.get(label, "gravity")
        for name in ("initial", "planes", "material", "dt", "gravity"):
            if name != same:
                assert getattr(moved, name) == getattr(scene, name), (label, name)


def test_scenes_without_planes_or_gravity():
    assert not any(label.startswith("mu") for label in perturbed_scenes(Scene(planes=())))
    assert HALF_STEP not in perturbed_scenes(Scene(), Perturbations(half_step=False))
    with pytest.raises(ConfigError, match="gravity"):
        perturbed_scenes(Scene(gravity=(0.0, 0.0, 0.0)))


@pytest.mark.parametrize("field, value", [("drop", 0.0), ("tilt_deg", 20.0), ("friction", -0.1), ("stiffness", 0.6), ("drop", float("nan")), ("drop", float("inf")), ("tilt_deg", True)])
def test_perturbations_reject_bad_amounts(field, value):
    with pytest.raises(ConfigError, match=field.split("_")[0]):
        Perturbations(**{field: value})


def test_free_fall_moves_as_backward_euler_says():
    # No planes: the body falls without deforming, so each moved run is off by a translation known in closed form.
    # Backward Euler under constant g from rest: x_n = x_0 + g h^2 n (n + 1) / 2.
    mesh = meshes.box(0.1, 2)
    h, n = 0.01, 12
    scene = Scene(planes=(), dt=h)
    s = sensitivity(mesh, scene, n, record_every=3, perturbations=Perturbations(drop=2e-3, tilt_deg=1.0))
    g = np.linalg.norm(scene.gravity)
    rows = s.rows
    assert rows["2 mm higher"]["com_error"] == pytest.approx(2e-3 / mesh.size, rel=1e-6)
    fall = g * h * h * n * (n + 1) / 2
    for k in (1, 2):
        assert rows[f"gravity turned 1 deg ({k})"]["com_error"] == pytest.approx(2 * math.sin(math.radians(0.5)) * fall / mesh.size, rel=1e-4)
    # at h / 2 over 2n steps: g (h/2)^2 (2n)(2n + 1) / 2, a distance g h^2 n / 4 shorter
    assert rows[HALF_STEP]["com_error"] == pytest.approx(g * h * h * n / 4 / mesh.size, rel=1e-4)
    assert s.com_spread == pytest.approx(max(r["com_error"] for label, r in rows.items() if label != HALF_STEP))
    assert s.time_step_error is rows[HALF_STEP]


def test_a_box_landing_on_flat_ground_is_not_chaotic():
    mesh = meshes.box(0.1, 2)
    scene = Scene(material=Material(youngs_modulus=2e4), planes=(Plane((0, 0, 1), 0.0, 0.5),), dt=0.01)
    scene = scene.replace(initial=drop_state(mesh, scene.material.density, 0.03))
    seen = []
    s = sensitivity(mesh, scene, 40, record_every=5, on_run=lambda label, row: seen.append(label))
    assert seen == list(s.rows)
    assert all(r["stick_slip_agree"] for r in s.rows.values())
    assert s.nonrigid_spread < CHAOTIC_SPREAD and not s.chaotic
    # it lands and rests: 2 % stiffer deforms about 2 % less
    assert 0.005 < s.rows["E +2 %"]["nonrigid_error"] < 0.04
    # backward Euler at 10 ms is far from converged: half the step moves it more than any input does
    assert s.time_step_error["nonrigid_error"] > 3 * s.nonrigid_spread
    assert s.summary()["chaotic"] is False and s.summary()["rows"] is s.rows


def test_bad_steps_and_reference():
    mesh = meshes.box(0.1, 2)
    with pytest.raises(ConfigError, match="steps"):
        sensitivity(mesh, Scene(planes=()), 0)
    with pytest.raises(ConfigError, match="record_every"):
        sensitivity(mesh, Scene(planes=()), 4, record_every=0)
    from licrom import FullSim

    ref = FullSim(mesh, Scene(planes=())).run(4)
    with pytest.raises(ConfigError, match="frames"):
        sensitivity(mesh, Scene(planes=()), 6, reference=ref)
