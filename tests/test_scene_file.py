import math

import numpy as np
import pytest
from licrom import ConfigError, FileFormatError, Plane, meshes
from licrom.cli.commands import main
from licrom.data.dataset import IMPACT_WINDOW
from licrom.data.scene_file import DropSpec, builtin_scenes, load_scene
from licrom.scene.placement import drop_state, initial_state_on_plane
from licrom.scene.scene import InitialState

MINIMAL = """
version = 1
[object]
mesh = "box"
resolution = 2
"""


def _write(tmp_path, text, name="s.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_builtin_scenes_load_and_describe_themselves():
    assert set(builtin_scenes()) >= {"cheese", "sphere", "demo"}
    for name in builtin_scenes():
        s = load_scene(name)
        assert s.name == name and s.source == f"built-in {name}"
        assert f"= {s.n_runs} runs" in s.summary()
    assert load_scene("cheese").n_runs == 15 and len(load_scene("demo").held_out) == 2


def test_defaults_of_a_minimal_file(tmp_path):
    s = load_scene(_write(tmp_path, MINIMAL))
    assert s.name == "s" and s.steps == 200 and s.scene.dt == 0.01
    assert s.scene.planes == (Plane(),)  # one horizontal ground, mu 0.5
    assert s.initial == (DropSpec(),) and s.n_runs == 1  # resting on it
    spec = s.dataset_spec()
    assert spec.mesh.n_tets == meshes.box(resolution=2).n_tets and spec.initial_frame == "plane"
    (scene,) = spec.scenes()
    assert spec.mesh.vertices[:, 2].min() + scene.initial.translation[2] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("text, message", [
    ("[object]\nmesh = 'box'", r"version is required \(version = 1\)"),
    ("version = 2\n[object]\nmesh = 'box'", "version 2 is not supported; this licrom reads version 1"),
    ("version = true\n[object]\nmesh = 'box'", "version True is not supported; this licrom reads version 1"),
    ("version = 1", "object is required"),
    (MINIMAL + "colour = 'red'", "unknown key object.colour; accepted keys in object: mesh, resolution, size, radius"),
    ("version = 1\ncolour = 1\n[object]\nmesh = 'box'", "unknown key colour"),
    (MINIMAL + "[[planes]]\nfriction = 0.2\n[[planes]]\nfrction = 0.2", r"unknown key planes\[1\].frction"),
    (MINIMAL + "[[planes]]\nfriction = 0.2\n[[planes]]\nfriction = -0.1", r"planes\[1\].friction must be a number >= 0, got -0.1"),
    (MINIMAL + "[[planes]]\nslope = 95.0", r"planes\[0\].slope must be a number in \[0, 90\) \(deg\), got 95.0"),
    (MINIMAL + "[[planes]]\nslope = 10.0\nnormal = [0, 0, 1]", r"planes\[0\] takes either normal or slope/azimuth"),
    (MINIMAL + "[[planes]]\nnormal = [0, 0, 0]", r"planes\[0\].normal must be a non-zero vector"),
    (MINIMAL + "[material]\npoisson_ratio = 0.5", r"material.poisson_ratio must be a number in \(-1, 0.5\), got 0.5"),
    (MINIMAL + "[material]\ndensity = true", "material.density must be a number > 0"),
    (MINIMAL + "[material]\nyoungs_modulus = 'soft'", "material.youngs_modulus must be a number > 0 \\(Pa\\)"),
    (MINIMAL + "[material]\nviscosity = -400.0", r"material.viscosity must be a number >= 0 \(Pa s\)"),
    (MINIMAL + "[contact]\nnormal_damping = -1.0", "contact.normal_damping must be a number >= 0"),
    (MINIMAL + "[solver]\non_failure = 'ignore'", "solver.on_failure must be one of 'raise', 'record'"),
    (MINIMAL + "[solver]\nreduced_tolerance = -1e-4", "solver.reduced_tolerance"),
    (MINIMAL + "[time]\nsteps = 0", "time.steps must be an integer >= 1, got 0"),
    (MINIMAL + "[time]\ndt = 0.0", r"time.dt must be a number > 0 \(s\)"),
    (MINIMAL + "[time]\nimpact_window = -0.1", r"time.impact_window must be a number >= 0 \(s\)"),
    (MINIMAL + "[sweep]\nfrictions = []", "sweep.frictions must be a non-empty list of numbers >= 0"),
    (MINIMAL + "[sweep]\nslopes = [10.0, 95.0]", r"sweep.slopes\[1\] must be a number in \[0, 90\)"),
    ("version = 1\nplanes = []\n[object]\nmesh = 'box'\n[sweep]\nslopes = [10.0]", "sweep.slopes tilts the first plane, but planes is empty"),
    (MINIMAL + "[[initial]]\ndrop_height = 0.1\n[[initial]]\ntranslation = [0, 0, 1]", r"initial\[1\]: give every initial state a drop_height"),
    (MINIMAL + "[[initial]]\ndrop_height = -0.1", r"initial\[0\].drop_height must be a number >= 0"),
    (MINIMAL + "[[initial]]\nvelocity = [1, 2]", r"initial\[0\].velocity must be 3 numbers \(m/s\)"),
    (MINIMAL + "[[held_out]]\nfrction = 0.3", r"unknown key held_out\[0\].frction"),
    (MINIMAL + "[[held_out]]", r"held_out\[0\] needs a slope, a friction or both"),
    ("version = 1\ngravity = [0, 0]\n[object]\nmesh = 'box'", r"gravity must be 3 numbers \(m/s\^2\), got \[0, 0\]"),
    ("version = 1\n[object]\nmesh = 'sphere'\nresolution = 2", "object.resolution must be an integer >= 4"),
    ("version = 1\n[object]\nmesh = 'sphere'\nsize = [1, 1, 1]", "a sphere takes object.radius"),
    ("version = 1\n[object]\nmesh = 'part.msh'\nresolution = 8", "object.resolution applies to procedural shapes"),
    ("version = 1\nplanes = 3\n[object]\nmesh = 'box'", r"planes must be an array of tables \(\[\[planes\]\]\)"),
])
def test_loader_names_the_key_and_the_accepted_range(tmp_path, text, message):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError, match=message) as info:
        load_scene(path)
    assert str(info.value).startswith(f"scene file '{path}': ")


def test_unreadable_files(tmp_path):
    with pytest.raises(FileFormatError, match="scene file not found"):
        load_scene(tmp_path / "missing.toml")
    with pytest.raises(FileFormatError, match="not valid TOML"):
        load_scene(_write(tmp_path, "version = = 1"))
    with pytest.raises(ConfigError, match="no scene file 'teapot' and no built-in scene of that name; built-in: cheese, demo, sphere"):
        load_scene("teapot")


def test_mesh_file_relative_to_the_scene_file(tmp_path):
    box = meshes.box(0.1, resolution=2)
    (tmp_path / "parts").mkdir()
    box.save(tmp_path / "parts" / "part.msh")
    s = load_scene(_write(tmp_path, "version = 1\n[object]\nmesh = 'parts/part.msh'"))
    assert s.dataset_spec().mesh.same_as(box)
    surface = load_scene(_write(tmp_path, "version = 1\n[object]\nmesh = 'part.obj'"))
    with pytest.raises(ConfigError, match="is a surface; fill it with tets first: licrom mesh"):
        surface.dataset_spec()


def test_planes_by_slope_and_azimuth_and_the_sweep_keeps_them(tmp_path):
    text = MINIMAL + """
[[planes]]
slope = 30.0
azimuth = 90.0
offset = 0.01
friction = 0.2
[[planes]]
normal = [0, 0, 2]
offset = 1.0
[sweep]
slopes = [10.0, 20.0]
frictions = [0.7]
"""
    s = load_scene(_write(tmp_path, text))
    first, second = s.scene.planes
    np.testing.assert_allclose(first.normal, [0.0, 0.5, math.sqrt(3) / 2], atol=1e-15)  # downhill towards +y
    assert first.azimuth_deg == pytest.approx(90.0) and first.offset == 0.01
    assert second.normal == (0.0, 0.0, 1.0) and second.offset == 0.5  # normalised with its offset
    scenes = s.dataset_spec().scenes()
    assert [round(sc.planes[0].slope_deg, 9) for sc in scenes] == [10.0, 20.0]
    for sc in scenes:
        assert sc.planes[0].azimuth_deg == pytest.approx(90.0) and sc.planes[0].offset == pytest.approx(0.01)
        assert [p.friction for p in sc.planes] == [0.7, 0.7]
        assert sc.planes[1] == Plane((0, 0, 1), 0.5, 0.7)


def test_world_frame_initial_states(tmp_path):
    s = load_scene(_write(tmp_path, MINIMAL + "[[initial]]\ntranslation = [0, 0, 0.2]\nvelocity = [1, 0, 0]\n[[initial]]\n"))
    spec = s.dataset_spec()
    assert spec.initial_frame == "world"
    assert spec.initial_states == (InitialState(translation=(0, 0, 0.2), velocity=(1, 0, 0)), InitialState())


def test_demo_scene_file_is_the_old_demo_config():
    """The demo's old settings: cheese at 8, slopes (10, 30) x mu (0.1, 0.4, 0.7), drop 1 cm, 150 steps, held out (20, 0.25), (20, 0.55)."""
    from licrom.data.presets import report_dataset_spec

    s = load_scene("demo")
    mesh = meshes.cheese(resolution=8)
    base = report_dataset_spec("cheese", resolution=4).base_scene
    rest = drop_state(mesh, base.material.density, height=0.01)
    spec = s.dataset_spec()
    assert spec.mesh.same_as(mesh) and spec.steps == 150 and spec.base_scene == base
    assert spec.frictions == (0.1, 0.4, 0.7) and spec.initial_states == (rest,) and spec.initial_frame == "plane"
    assert [sc.planes[0] for sc in spec.scenes()] == [Plane.incline(a, mu) for mu in (0.1, 0.4, 0.7) for a in (10.0, 30.0)]
    old_cases = []
    for slope, mu in ((20.0, 0.25), (20.0, 0.55)):
        plane = Plane.incline(slope, mu)
        old_cases.append((f"slope {slope:g} deg, mu {mu:g}", base.replace(planes=(plane,), initial=initial_state_on_plane(rest, plane, mesh, 1000.0))))
    assert s.cases(mesh) == old_cases


def test_overrides_replace_and_check_values():
    s = load_scene("cheese").overridden(mesh="box:3", youngs_modulus=2e5, poisson_ratio=0.4, density=500.0, viscosity=400.0,
                                        frictions=(0.2,), slopes=(15.0,), dt=0.005, steps=7, record_every=7)
    assert s.object.mesh == "box" and s.object.resolution == 3
    m = s.scene.material
    assert (m.youngs_modulus, m.poisson_ratio, m.density, m.viscosity, s.scene.dt, s.steps, s.record_every) == (2e5, 0.4, 500.0, 400.0, 0.005, 7, 7)
    assert "viscosity 400 Pa s" in s.summary()
    assert s.n_runs == 1 and s.dataset_spec().scenes()[0].planes[0] == Plane.incline(15.0, 0.2)
    assert s.impact_window == IMPACT_WINDOW and s.overridden(impact_window=0.05).dataset_spec().impact_window == 0.05
    with pytest.raises(ConfigError, match="impact_window must be a number"):
        load_scene("cheese").overridden(impact_window=-0.1)
    with pytest.raises(ConfigError, match=r"slope 95 must be a number in \[0, 90\)"):
        load_scene("cheese").overridden(slopes=(95,))
    with pytest.raises(ConfigError, match="resolution applies to procedural shapes"):
        load_scene("cheese").overridden(mesh="part.msh", resolution=3)
    with pytest.raises(ConfigError, match="needs an integer resolution"):
        load_scene("cheese").overridden(mesh="box:fine")


def test_cli_generate_takes_a_scene_file_and_flags(tmp_path, capsys):
    import json

    from licrom.data.dataset import MANIFEST_NAME

    scene = _write(tmp_path, MINIMAL + "[sweep]\nfrictions = [0.1, 0.9]\nslopes = [20.0]\n[time]\nsteps = 2\n")
    out = tmp_path / "data"
    assert main(["generate", str(out), "--scene", str(scene), "--density", "800", "--viscosity", "50", "--slope", "25", "-q"]) == 0
    assert "2 trajectories x 2 steps" in capsys.readouterr().out
    m = json.loads((out / MANIFEST_NAME).read_text())
    assert m["base_scene"]["material"]["viscosity"] == 50.0
    assert m["base_scene"]["material"]["density"] == 800.0 and [t["slope_deg"][0] for t in m["trajectories"]] == pytest.approx([25.0, 25.0])
    bad = _write(tmp_path, MINIMAL + "[[planes]]\nfriction = -1.0", "bad.toml")
    assert main(["generate", str(out), "--scene", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err == f"licrom: error: scene file '{bad}': planes[0].friction must be a number >= 0, got -1.0\n"
    assert main(["generate", str(out), "--preset", "cheese"]) == 2  # one way to name a scene: --scene
    assert capsys.readouterr().err.startswith("licrom: error: No such option '--preset'")


def test_cli_scene_copies_a_template(tmp_path, capsys):
    out = tmp_path / "mine.toml"
    assert main(["scene", "sphere", "-o", str(out)]) == 0
    assert "sphere bouncing down a 20 deg slope" in capsys.readouterr().out
    assert load_scene(out).dataset_spec().scenes() == load_scene("sphere").dataset_spec().scenes()


def test_cli_compare_runs_the_held_out_scenes_of_a_scene_file(tiny_demo, tiny_demo_scene, tmp_path, capsys):
    scene = _write(tmp_path, tiny_demo_scene.replace("[object]\nmesh = \"cheese\"", "[object]\nmesh = \"cheese\"\nresolution = 4")
                   + "[time]\nsteps = 30\n")
    assert main(["compare", str(tiny_demo[0] / "model.lcm"), "--scene", str(scene), "--cubature", "40"]) == 0
    captured = capsys.readouterr()
    assert "slope 20 deg, mu 0.1" in captured.out and "slope 20 deg, mu 0.9" in captured.out
    assert "compare: 100%" in captured.err  # the progress bar over the scenes


def test_non_utf8_and_deeply_nested_files_are_named_file_format_errors(tmp_path):
    latin1 = tmp_path / "latin1.toml"
    text = "description = 'Käse'\n" + MINIMAL
    latin1.write_bytes(text.encode("latin-1"))
    utf16 = tmp_path / "utf16.toml"
    utf16.write_bytes(MINIMAL.encode("utf-16"))
    for path in (latin1, utf16):
        with pytest.raises(FileFormatError, match=f"scene file '{path}' is not UTF-8 text.*must be UTF-8"):
            load_scene(path)
    deep = _write(tmp_path, MINIMAL + "[material]\ndensity = " + "[" * 5000 + "]" * 5000 + "\n", "deep.toml")
    with pytest.raises((FileFormatError, ConfigError), match=f"scene file '{deep}'.*nested too deeply"):
        load_scene(deep)
    (tmp_path / "utf8.toml").write_text(text, encoding="utf-8")
    assert load_scene(tmp_path / "utf8.toml").description == "Käse"


@pytest.mark.parametrize("initial", ["drop_height = 0.1\nrotation = [1e300, 0, 0]", "translation = [0, 0, 1]\nrotation = [1e300, 0, 0]"])
def test_a_huge_rotation_in_a_scene_file_is_refused_at_load(tmp_path, initial):
    path = _write(tmp_path, MINIMAL + "[[initial]]\n" + initial + "\n")
    with pytest.raises(ConfigError, match=r"initial\[0\].rotation must be a rotation vector of length <= 1e\+06 rad.*got length 1e\+300"):
        load_scene(path)
    with pytest.raises(ConfigError, match=r"DropSpec.rotation must be a rotation vector of length <= 1e\+06 rad"):
        DropSpec(0.1, (1e300, 0, 0))


def test_cli_scene_names_a_missing_or_surface_mesh_file(tmp_path, capsys):
    scene = _write(tmp_path, "version = 1\n[object]\nmesh = 'parts/part.msh'")
    assert main(["scene", str(scene)]) == 2
    assert capsys.readouterr().err == f"licrom: error: scene file '{scene}': object.mesh: mesh file not found: '{tmp_path / 'parts' / 'part.msh'}'\n"
    (tmp_path / "parts" / "part.msh").mkdir(parents=True)
    assert main(["scene", str(scene)]) == 2
    assert capsys.readouterr().err.endswith(f"mesh file not found: '{tmp_path / 'parts' / 'part.msh'}' (it is a folder)\n")
    surface = _write(tmp_path, "version = 1\n[object]\nmesh = 'part.obj'", "surface.toml")
    assert main(["scene", str(surface)]) == 2
    assert f"object.mesh: object mesh '{tmp_path / 'part.obj'}' is a surface; fill it with tets first" in capsys.readouterr().err
    (tmp_path / "parts" / "part.msh").rmdir()
    meshes.box(0.1, resolution=2).save(tmp_path / "parts" / "part.msh")
    assert main(["scene", str(scene)]) == 0
    assert "part.msh" in capsys.readouterr().out


def test_scene_template_on_a_mesh_file(tmp_path, capsys, monkeypatch):
    """`licrom scene demo -o FILE --mesh MESH`: the copy names the mesh relative to itself and has no resolution;
    a mesh file that is not there leaves no copy behind."""
    from licrom import meshes
    from licrom.data.scene_file import builtin_scene_text, with_mesh_file

    (tmp_path / "meshes").mkdir()
    meshes.cheese(resolution=4).save(tmp_path / "meshes" / "mine.msh")
    out = tmp_path / "scenes" / "mine.toml"
    monkeypatch.chdir(tmp_path)
    assert main(["scene", "demo", "-o", "scenes/mine.toml", "--mesh", "meshes/mine.msh"]) == 0
    text = out.read_text()
    assert 'mesh = "../meshes/mine.msh"' in text and "resolution" not in text.split("[material]")[0]
    assert load_scene(out).object.build().n_tets == meshes.cheese(resolution=4).n_tets
    missing = tmp_path / "other.toml"
    assert main(["scene", "demo", "-o", str(missing), "--mesh", str(tmp_path / "nope.msh")]) == 2
    assert "object.mesh" in capsys.readouterr().err and not missing.exists()
    assert main(["scene", "demo", "--mesh", "x.msh"]) == 2
    assert "--mesh needs --output" in capsys.readouterr().err
    with pytest.raises(ConfigError, match=r"no \[object\] table"):
        with_mesh_file(builtin_scene_text("demo").replace("[object]", "[thing]"), "x.msh", tmp_path / "s.toml")
