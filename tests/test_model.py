"""The learned-subspace model: affine modes, basis values and Jacobians, projection, encoder, file."""

import dataclasses
import zipfile

import numpy as np
import pytest
import torch
from licrom import FileFormatError, Scene, ShapeError, meshes
from licrom.errors import ConfigError
from licrom.learn.model import MODEL_FORMAT_VERSION, LicromNet, Model, ModelConfig
from licrom.learn.model.finalize import finalize_basis
from licrom.scene.scene import Plane
from licrom.subspace.affine import apply_affine, fit_affine
from licrom.subspace.basis import N_AFFINE, affine_jacobians, affine_values


@pytest.fixture(scope="module")
def mesh():
    return meshes.box((0.2, 0.1, 0.1), resolution=4)


def _random_model(mesh, r=3, seed=0, affine=True, finalize=True, fourier=0, frame="world"):
    torch.manual_seed(seed)
    net = LicromNet(ModelConfig(latent_dim=r, affine=affine, fourier_features=fourier, frame=frame))
    x = np.asarray(mesh.vertices)
    c = x.mean(axis=0)
    net.set_normalization(c, float(np.abs(x - c).max()), 1e-3)
    fin = finalize_basis(net, mesh) if finalize else None
    scenes = [Scene(planes=(Plane(friction=0.3),)), Scene(planes=(Plane(friction=0.7),))]
    return Model(net, mesh, scenes, finalization=fin, metadata={"note": "random"})


# --- affine modes ------------------------------------------------------------------------
def test_affine_mode_order(rng):
    x = rng.normal(size=(5, 3))
    a = affine_values(x)
    assert a.shape == (5, 3, N_AFFINE)
    for c in range(9):
        i, j = divmod(c, 3)
        expect = np.zeros((5, 3))
        expect[:, i] = x[:, j]
        np.testing.assert_array_equal(a[:, :, c], expect)
    for k in range(3):
        np.testing.assert_array_equal(a[:, :, 9 + k], np.tile(np.eye(3)[k], (5, 1)))
    # torch and numpy agree
    np.testing.assert_allclose(affine_values(torch.as_tensor(x)).numpy(), a)
    j = affine_jacobians(x)
    assert j.shape == (5, 3, 3, N_AFFINE)
    for c in range(9):
        i, jj = divmod(c, 3)
        assert j[0, i, jj, c] == 1.0 and j[0].sum(axis=(0, 1))[c] == 1.0
    assert not j[..., 9:].any()


def test_fit_affine_recovers_affine_field_and_is_orthogonal(mesh, rng):
    x = np.asarray(mesh.vertices)
    m = mesh.vertex_masses(1000.0)
    a_true = rng.normal(size=(2, 12))
    u = apply_affine(x, a_true)
    np.testing.assert_allclose(fit_affine(x, u, m), a_true, atol=1e-12)
    # the residual of a general field is mass-orthogonal to every affine mode
    v = rng.normal(size=(len(x), 3))
    res = v - apply_affine(x, fit_affine(x, v, m))
    basis = affine_values(x).reshape(-1, 12)
    np.testing.assert_allclose(basis.T @ (np.repeat(m, 3) * res.ravel()), 0.0, atol=1e-12)
    with pytest.raises(ShapeError):
        fit_affine(x, u[:, :-1], m)


# --- configuration -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs",
    [{"latent_dim": 0}, {"latent_dim": 2.5}, {"field_layers": 1}, {"field_width": -3}, {"encoder_point_widths": ()},
     {"encoder_fc_widths": (4, 0)}, {"affine": "yes"}, {"fourier_features": -1}, {"fourier_scale": 0.0},
     {"frame": "lab"}, {"frame": None}, {"field_width": "wide"}, {"field_width": 0}],
)
def test_model_config_rejects_bad_values(kwargs):
    with pytest.raises(ConfigError):
        ModelConfig(**kwargs)


def test_the_auto_field_width_is_twice_r_and_at_least_256_once_r_is_known():
    assert ModelConfig().field_width == "auto"  # r not known yet
    assert [ModelConfig(latent_dim=r).field_width for r in (1, 120, 128, 129, 160, 250)] == [256, 256, 256, 320, 320, 512]
    # licrom.train replaces the chosen r into the config: the width follows it
    assert dataclasses.replace(ModelConfig(), latent_dim=250).field_width == 512
    assert ModelConfig(latent_dim=250, field_width=64).field_width == 64  # given: kept
    net = LicromNet(ModelConfig(latent_dim=200, field_layers=2, fourier_features=0))
    assert net.field.mlp[0].out_features == 448 and net.field.mlp[-1].in_features == 448


def test_model_config_defaults_are_licrom():
    assert ModelConfig().latent_dim == "auto"  # r chosen from the data by licrom.train
    c = ModelConfig(latent_dim=20)
    assert (c.field_layers, c.field_width, c.affine, c.frame) == (5, 256, True, "body")
    net = LicromNet(c)
    linears = [m for m in net.field.mlp if isinstance(m, torch.nn.Linear)]
    assert len(linears) == 5 and linears[0].in_features == 3 + 2 * c.fourier_features
    assert linears[-1].out_features == 3 * c.latent_dim and all(m.out_features == 256 for m in linears[:-1])
    # the field's last hidden layer is what its output layer combines
    x = torch.rand(7, 3)
    torch.testing.assert_close(net.field(x), net.field.mlp[-1](net.field.hidden(x)).reshape(7, 3, c.latent_dim))
    plain = LicromNet(ModelConfig(latent_dim=20, fourier_features=0))  # LiCROM's plain input
    assert plain.field.mlp[0].in_features == 3
    assert all(isinstance(m, (torch.nn.Linear, torch.nn.ELU)) for m in net.field.mlp)
    assert ModelConfig.from_dict(c.to_dict()) == c


# --- the basis ---------------------------------------------------------------------------
def test_values_shape_and_affine_block(mesh, rng):
    model = _random_model(mesh, r=3)
    assert (model.n_modes, model.n_learned, model.n_affine) == (15, 3, 12)
    x = rng.uniform(-0.05, 0.05, size=(7, 3))
    v = model.values(x)
    assert v.shape == (7, 3, 15) and v.dtype == np.float64
    np.testing.assert_array_equal(v[:, :, :12], affine_values(x))
    assert np.abs(v[:, :, 12:]).max() > 0


def test_values_at_the_model_vertices_are_kept_and_handed_out_as_copies(mesh):
    model = _random_model(mesh, r=3)
    fresh = model.values_and_jacobians(mesh.vertices)[0]  # a network pass of its own
    first = model.values(mesh.vertices)
    np.testing.assert_array_equal(first, fresh)
    first[:] = 0.0  # the caller's array: the model's stays as it was
    np.testing.assert_array_equal(model.values(mesh.vertices), fresh)
    np.testing.assert_allclose(model.reconstruct(np.ones(model.n_modes)), fresh.sum(axis=2), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("fourier", [0, 8])
def test_jacobians_match_finite_differences(mesh, rng, fourier):
    model = _random_model(mesh, r=4, fourier=fourier)
    x = rng.uniform(-0.08, 0.08, size=(6, 3)) * np.array([1.0, 0.5, 0.5])
    vals, jac = model.values_and_jacobians(x)
    assert jac.shape == (6, 3, 3, 16)
    np.testing.assert_allclose(vals, model.values(x), rtol=1e-12, atol=1e-15)
    h = 1e-6
    for j in range(3):
        e = np.zeros(3)
        e[j] = h
        fd = (model.values(x + e) - model.values(x - e)) / (2 * h)
        np.testing.assert_allclose(jac[:, :, j, :], fd, rtol=1e-6, atol=1e-7 * np.abs(fd).max())
    np.testing.assert_array_equal(model.jacobians(x), jac)


def test_values_are_batched_across_chunks(mesh, rng):
    from licrom.learn.model import config as model_module

    model = _random_model(mesh, r=2)
    x = rng.uniform(-0.05, 0.05, size=(model_module._CHUNK + 7, 3))
    v = model.values(x)
    # the same numbers up to round-off (a BLAS may block a batch differently by its size)
    np.testing.assert_allclose(v[-7:], model.values(x[-7:]), rtol=1e-10, atol=1e-12 * np.abs(v).max())
    _, j = model.values_and_jacobians(x[-3:])
    jall = model.jacobians(x)
    np.testing.assert_allclose(jall[-3:], j, rtol=1e-10, atol=1e-12 * np.abs(jall).max())


def test_bad_points_raise_shape_error(mesh):
    model = _random_model(mesh, r=2)
    with pytest.raises(ShapeError):
        model.values(np.zeros((4, 2)))
    with pytest.raises(ShapeError):
        model.jacobians(np.full((1, 3), np.nan))


def test_finalized_modes_are_mass_orthonormal_and_orthogonal_to_affine(mesh):
    model = _random_model(mesh, r=3)
    m = np.repeat(mesh.vertex_masses(1.0), 3)
    b = model.values(mesh.vertices).reshape(-1, model.n_modes)
    gram = b.T @ (m[:, None] * b)
    np.testing.assert_allclose(gram[:12, 12:], 0.0, atol=1e-10 * np.abs(gram).max())
    np.testing.assert_allclose(gram[12:, 12:], m.sum() / 3 * np.eye(3), rtol=1e-8, atol=1e-10)
    # the span equals that of [affine | raw field]
    raw = _random_model(mesh, r=3, finalize=False)
    braw = raw.values(mesh.vertices).reshape(-1, raw.n_modes)
    q, _ = np.linalg.qr(b)
    np.testing.assert_allclose(q @ (q.T @ braw), braw, atol=1e-9 * np.abs(braw).max())


def test_project_and_reconstruct(mesh, rng):
    model = _random_model(mesh, r=3)
    q_true = rng.normal(size=(4, model.n_modes)) * 1e-3
    u = model.reconstruct(q_true)
    assert u.shape == (4, mesh.n_vertices, 3)
    np.testing.assert_allclose(model.project(u), q_true, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(model.project(u[1]), q_true[1], rtol=1e-8, atol=1e-12)
    # the subspace is continuous: the same field sampled on another mesh projects to the same q
    fine = meshes.box((0.2, 0.1, 0.1), resolution=6)
    u_fine = model.reconstruct(q_true[0], mesh=fine)
    np.testing.assert_allclose(model.project(u_fine, mesh=fine), q_true[0], rtol=1e-7, atol=1e-12)
    with pytest.raises(ShapeError):
        model.project(np.zeros((3, 3)))


def test_encode_shapes(mesh, rng):
    model = _random_model(mesh, r=3)
    u = rng.normal(size=(mesh.n_vertices, 3)) * 1e-3
    z = model.encode(mesh.vertices, u)
    q = model.encode_q(mesh.vertices, u)
    assert z.shape == (3,) and q.shape == (15,)
    np.testing.assert_allclose(q[12:], z)
    # the affine part of q is the mass-weighted fit
    np.testing.assert_allclose(q[:12], fit_affine(mesh.vertices, u, mesh.vertex_masses(1.0)), rtol=1e-10, atol=1e-14)
    with pytest.raises(ShapeError):
        model.encode(mesh.vertices, u[:-1])


def test_encode_of_too_few_points_for_the_affine_fit_is_a_named_error(mesh, rng):
    one, u = mesh.vertices[:1], np.full((1, 3), 1e-3)
    flat = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.05, 0], [0.1, 0.05, 0], [0.05, 0.02, 0]])  # 5 points in one plane
    for model in (_random_model(mesh, r=3), _random_model(mesh, r=3, frame="body")):
        with pytest.raises(ShapeError, match=r"points must span 3-D space for the affine fit .* got 1 point\(s\), 1 of weight > 0, spanning a point"):
            model.encode(one, u)  # was numpy's LinAlgError: Singular matrix
        with pytest.raises(ShapeError, match="spanning a plane"):
            model.encode_q(flat, np.zeros((5, 3)))
        with pytest.raises(ShapeError, match="at least one point"):
            model.encode(np.zeros((0, 3)), np.zeros((0, 3)))
        tet = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.05, 0], [0, 0, 0.05]])  # 4 points that span the space are enough
        assert model.encode(tet, rng.normal(size=(4, 3)) * 1e-3).shape == (3,)
    # Without the affine fit one point is enough.
    plain = _random_model(mesh, r=3, affine=False)
    assert plain.encode(one, u).shape == (3,)
    with pytest.raises(ShapeError, match="at least one point"):
        plain.encode(np.zeros((0, 3)), np.zeros((0, 3)))  # was torch's IndexError


def test_model_without_affine_modes(mesh, rng):
    model = _random_model(mesh, r=3, affine=False)
    assert model.n_modes == 3 and model.n_affine == 0
    x = rng.uniform(-0.05, 0.05, size=(4, 3))
    assert model.values(x).shape == (4, 3, 3) and model.jacobians(x).shape == (4, 3, 3, 3)
    assert model.encode_q(mesh.vertices, np.zeros((mesh.n_vertices, 3))).shape == (3,)


# --- the file ----------------------------------------------------------------------------
@pytest.mark.parametrize("fourier", [0, 6])
def test_save_load_round_trip(mesh, tmp_path, rng, fourier):
    model = _random_model(mesh, r=3, seed=4, fourier=fourier)
    path = model.save(tmp_path / "m.lcm")
    assert path == tmp_path / "m.lcm" and path.is_file()
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind
    back = Model.load(path)
    x = rng.uniform(-0.05, 0.05, size=(5, 3))
    np.testing.assert_array_equal(back.values(x), model.values(x))
    np.testing.assert_array_equal(back.jacobians(x), model.jacobians(x))
    assert back.config == model.config and back.n_modes == model.n_modes
    assert back.mesh.same_as(mesh)
    assert back.scenes == model.scenes and back.default_scene == model.scenes[0]
    assert back.metadata == {"note": "random"}
    assert back.normalization == model.normalization
    u = rng.normal(size=(mesh.n_vertices, 3)) * 1e-3
    np.testing.assert_array_equal(back.encode(mesh.vertices, u), model.encode(mesh.vertices, u))
    # the file is a plain npz: no pickle needed
    with np.load(path, allow_pickle=False) as data:
        assert "header_json" in data.files


def test_load_rejects_truncated_foreign_and_unknown_files(mesh, tmp_path):
    model = _random_model(mesh, r=2)
    good = model.save(tmp_path / "good.lcm")
    raw = good.read_bytes()
    (tmp_path / "trunc.lcm").write_bytes(raw[: len(raw) // 2])
    (tmp_path / "junk.lcm").write_bytes(b"this is not a model file at all")
    with pytest.raises(FileFormatError, match="truncated or corrupt"):
        Model.load(tmp_path / "trunc.lcm")
    with pytest.raises(FileFormatError, match=r"not an \.npz \(zip\) archive"):
        Model.load(tmp_path / "junk.lcm")
    with pytest.raises(FileFormatError, match="not found"):
        Model.load(tmp_path / "missing.lcm")
    # a licrom file of another kind
    from licrom import Trajectory

    traj = Trajectory(mesh.vertices, mesh.tets, np.zeros((1, mesh.n_vertices, 3)), np.zeros((1, mesh.n_vertices, 3)), [0.0], Scene())
    tpath = traj.save(tmp_path / "t.npz")
    with pytest.raises(FileFormatError, match="trajectory"):
        Model.load(tpath)

    # unknown format version, and a file missing an array
    def rewrite(name, edit_header=None, drop=None):
        import json

        with np.load(good, allow_pickle=False) as d:
            arrays = {k: d[k] for k in d.files}
        header = json.loads(str(arrays["header_json"]))
        if edit_header:
            edit_header(header)
        arrays["header_json"] = np.array(json.dumps(header))
        if drop:
            arrays.pop(drop)
        with open(tmp_path / name, "wb") as fh:
            np.savez(fh, **arrays)
        return tmp_path / name

    with pytest.raises(FileFormatError, match="version"):
        Model.load(rewrite("v99.lcm", edit_header=lambda h: h.update(version=99)))
    with pytest.raises(FileFormatError):
        Model.load(rewrite("noarr.lcm", drop="net/field.mlp.0.weight"))
    with pytest.raises(FileFormatError):
        Model.load(rewrite("badcfg.lcm", edit_header=lambda h: h["model_config"].update(latent_dim=5)))
    assert zipfile.is_zipfile(good)


# --- frames --------------------------------------------------------------------------------
def test_unknown_frame_names_the_accepted_values():
    with pytest.raises(ConfigError, match="'body', 'world'"):
        ModelConfig(frame="inertial")


def test_body_frame_model_has_learned_modes_only(mesh, rng):
    body = _random_model(mesh, r=3, frame="body")
    world = _random_model(mesh, r=3, frame="world")
    assert body.frame == "body" and world.frame == "world"
    assert (body.n_modes, body.n_learned, body.n_affine) == (3, 3, 0)
    x = rng.uniform(-0.05, 0.05, size=(6, 3))
    # the same learned fields; the world-frame model stacks the 12 affine modes in front
    np.testing.assert_allclose(body.values(x), world.values(x)[:, :, 12:], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(body.jacobians(x), world.jacobians(x)[..., 12:], rtol=1e-12, atol=1e-15)
    # still mass-orthogonal to every affine mode, hence to the six rigid modes
    m = np.repeat(mesh.vertex_masses(1.0), 3)
    b = body.values(mesh.vertices).reshape(-1, 3)
    a = affine_values(mesh.vertices).reshape(-1, 12)
    np.testing.assert_allclose(a.T @ (m[:, None] * b), 0.0, atol=1e-10 * np.abs(b).max() * m.sum())


def test_body_frame_encoder_ignores_rigid_motion(mesh, rng):
    from scipy.spatial.transform import Rotation

    model = _random_model(mesh, r=3, frame="body")
    x = np.asarray(mesh.vertices)
    u = rng.normal(size=x.shape) * 1e-3
    z = model.encode_q(x, u)
    assert z.shape == (3,)
    # the same deformation, turned and moved as a whole: the same latent
    rot = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    moved = (x + u) @ rot.T + np.array([0.3, -0.2, 1.5]) - x
    np.testing.assert_allclose(model.encode_q(x, moved), z, rtol=1e-6, atol=1e-9 * np.abs(z).max())
    # a purely rigid motion has no body-frame deformation: project gives zero
    rigid = x @ rot.T + 0.1 - x
    from licrom.rigid import body_frame_displacements

    ub = body_frame_displacements(x + rigid, x, mesh.vertex_masses(1.0))
    np.testing.assert_allclose(model.project(ub), 0.0, atol=1e-12)


def test_body_frame_model_round_trip_keeps_frame(mesh, tmp_path, rng):
    import json

    model = _random_model(mesh, r=2, frame="body")
    path = model.save(tmp_path / "b.lcm")
    with np.load(path, allow_pickle=False) as d:
        header = json.loads(str(d["header_json"]))
    assert header["version"] == MODEL_FORMAT_VERSION == 3 and header["frame"] == "body" and header["model_config"]["frame"] == "body"
    back = Model.load(path)
    assert back.frame == "body" and back.n_modes == 2 and back.cubature is None  # nothing fitted: none stored
    # a version 2 file (before the cubature was stored) still loads
    with np.load(path, allow_pickle=False) as d:
        arrays = {k: d[k] for k in d.files}
    arrays["header_json"] = np.array(json.dumps({**header, "version": 2}))
    with open(tmp_path / "v2.lcm", "wb") as fh:
        np.savez_compressed(fh, **arrays)
    old = Model.load(tmp_path / "v2.lcm")
    assert old.frame == "body" and old.cubature is None
    x = rng.uniform(-0.05, 0.05, size=(4, 3))
    np.testing.assert_array_equal(back.values(x), model.values(x))


def test_old_world_frame_model_file_loads_as_world_frame():
    from pathlib import Path

    path = Path(__file__).parent / "data" / "world_v1.lcm"
    with np.load(path, allow_pickle=False) as d:
        import json

        assert json.loads(str(d["header_json"]))["version"] == 1  # written by the old format
    model = Model.load(path)
    assert model.frame == "world" and model.config.frame == "world"
    assert (model.n_affine, model.n_learned, model.n_modes) == (12, 2, 14)
    x = model.mesh.vertices
    v = model.values(x)
    np.testing.assert_array_equal(v[:, :, :12], affine_values(x))
    # the finalisation stored in the file still makes the learned block mass-orthonormal
    b = v.reshape(-1, 14)
    m = np.repeat(model.mesh.vertex_masses(1.0), 3)
    g = b.T @ (m[:, None] * b)
    np.testing.assert_allclose(g[12:, 12:], m.sum() / 3 * np.eye(2), rtol=1e-5, atol=1e-9 * m.sum())
    np.testing.assert_allclose(g[:12, 12:], 0.0, atol=1e-6 * np.abs(g).max())
    # and it still runs as a world-frame reduced model
    from licrom.errors import PhysicsWarning
    from licrom.reduced.base import ReducedSim
    from licrom.reduced.world import WorldFrameSim

    # The file's default scene (from synthetic data) has the body half in the ground, which is said.
    with pytest.warns(PhysicsWarning, match="inside a plane"):
        sim = ReducedSim(model)
    assert type(sim) is WorldFrameSim and isinstance(sim, ReducedSim) and sim.n_modes == 14
    traj = sim.run(5)
    assert traj.n_frames == 6 and np.isfinite(traj.displacements).all()
    assert traj.converged.all() and np.abs(traj.displacements[-1]).max() > 0.0


def test_save_onto_a_directory_is_an_output_error(mesh, tmp_path):
    from licrom import OutputError

    with pytest.raises(OutputError, match="is a directory"):
        _random_model(mesh, r=2).save(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_save_keeps_the_mode_of_the_file_it_replaces(mesh, tmp_path):
    import os

    path = tmp_path / "m.npz"
    _random_model(mesh, r=2).save(path)
    os.chmod(path, 0o600)
    _random_model(mesh, r=2, seed=1).save(path)
    assert (os.stat(path).st_mode & 0o7777) == 0o600
    assert Model.load(path).net.config.latent_dim == 2


def test_absurd_header_sizes_are_refused_before_the_network_is_built(mesh, tmp_path, monkeypatch):
    import json

    import licrom.learn.model.trained as trained
    from licrom.learn.model.networks import state_size

    good = _random_model(mesh, r=2).save(tmp_path / "good.lcm")
    with np.load(good, allow_pickle=False) as d:
        arrays = {k: d[k] for k in d.files}
    header = json.loads(str(arrays.pop("header_json")))
    header["model_config"]["latent_dim"] = header["n_learned"] = 10**6
    np.savez(tmp_path / "huge.lcm", **arrays, header_json=np.array(json.dumps(header)))

    def never(*args, **kwargs):
        raise AssertionError("the network was built from an absurd header")

    monkeypatch.setattr(trained, "LicromNet", never)
    # refused by the header check, or by ModelConfig's memory check (licrom._limits) before it
    with pytest.raises(FileFormatError, match=r"latent_dim=1000000.*needs (\d+ weights, the file holds \d+|about .* over the memory limit)"):
        Model.load(tmp_path / "huge.lcm.npz")
    # the size it checks is the network's own
    for cfg in (ModelConfig(latent_dim=20), ModelConfig(latent_dim=3, field_layers=2, field_width=7, fourier_features=0,
                                           encoder_point_widths=(5,), encoder_fc_widths=())):
        assert state_size(cfg) == sum(v.numel() for v in LicromNet(cfg).state_dict().values())


@pytest.mark.parametrize(("member", "edit", "message"), [
    ("net/field.mlp.0.weight", lambda a: np.full_like(a, np.nan), "member net/field.mlp.0.weight must be finite, it holds NaN or inf"),
    ("net/field.mlp.0.weight", lambda a: a.astype(np.complex64) * 1j, "member net/field.mlp.0.weight must hold real numbers"),
    ("net/x_center", lambda a: np.array([np.inf, 0, 0], dtype=a.dtype), "member net/x_center must be finite, it holds NaN or inf"),
    ("net/x_scale", lambda a: np.zeros_like(a), r"member net/x_scale is 0\.0; it must be > 0"),
    ("net/x_scale", lambda a: -a, "member net/x_scale .* must be > 0"),
    ("net/u_scale", lambda a: np.full_like(a, np.inf), "member net/u_scale must be finite, it holds NaN or inf"),
    ("mode_variance", lambda a: a[:1], r"member mode_variance has shape \(1,\); latent_dim=2 needs \(2,\)"),
    ("mode_transform", lambda a: np.full_like(a, np.nan), "member mode_transform must be finite, it holds NaN or inf"),
    ("affine_correction", lambda a: a[:6], "member affine_correction has shape"),
])
def test_load_refuses_non_finite_or_misshapen_members(mesh, tmp_path, member, edit, message):
    import json

    good = _random_model(mesh, r=2).save(tmp_path / "good.lcm")
    with np.load(good, allow_pickle=False) as d:
        arrays = {k: d[k] for k in d.files}
    header = json.loads(str(arrays.pop("header_json")))
    arrays[member] = edit(arrays[member])
    np.savez(tmp_path / "bad.npz", **arrays, header_json=np.array(json.dumps(header)))
    with pytest.raises(FileFormatError, match=message):
        Model.load(tmp_path / "bad.npz")


def test_bad_devices_and_non_finite_inputs_are_named(mesh):
    model = _random_model(mesh, r=2)
    with pytest.raises(ConfigError, match=r"device must be 'cpu', 'cuda', 'cuda:N' .* got 'bogus'"):
        model.to("bogus")
    with pytest.raises(ConfigError, match="device must be"):
        model.to(3.5)
    u = np.zeros((mesh.n_vertices, 3))
    q = model.project(u)  # the model still works on its device
    u[0, 0] = np.nan
    with pytest.raises(ShapeError, match="displacements hold NaN or inf"):
        model.project(u)
    with pytest.raises(ShapeError, match="displacements must be an array of real numbers"):
        model.project(np.full((mesh.n_vertices, 3), "x"))
    with pytest.raises(ShapeError, match="q holds NaN or inf"):
        model.reconstruct(np.full_like(q, np.nan))
    with pytest.raises(ShapeError, match="q holds NaN or inf"):
        model.reconstruct(np.full((2, q.size), np.inf))
    with pytest.raises(ShapeError, match="q must be an array of real numbers"):
        model.reconstruct(q + 1j)
    assert model.reconstruct(q).shape == (mesh.n_vertices, 3)


def test_fields_outside_the_mesh_are_those_of_its_nearest_point(mesh, rng):
    # The network extrapolates without bound beyond the mesh it was trained on; a point outside is
    # evaluated at a point of its nearest tet, and points of the mesh are left exactly where they are.
    model = _random_model(mesh, r=3)
    inside = rng.uniform(-0.08, 0.08, size=(5, 3)) * np.array([1.0, 0.5, 0.5])
    np.testing.assert_array_equal(model.field_points(inside), inside)
    lo, hi = mesh.bounds
    on_face = np.array([[hi[0], 0.01, -0.02], [0.03, lo[1], 0.02]])
    outside = on_face + np.array([[0.004, 0.0, 0.0], [0.0, -0.004, 0.0]])
    np.testing.assert_allclose(model.field_points(outside), on_face, atol=1e-12)
    v_out, j_out = model.values_and_jacobians(outside)
    v_face, j_face = model.values_and_jacobians(on_face)
    learned = slice(model.n_affine, None)
    np.testing.assert_allclose(v_out[:, :, learned], v_face[:, :, learned], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(j_out[..., learned], j_face[..., learned], rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(v_out[:, :, : model.n_affine], affine_values(outside))  # the affine modes are exact everywhere
    np.testing.assert_allclose(model.values(outside), v_out, rtol=1e-12, atol=1e-15)
