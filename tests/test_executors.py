"""Executors of independent tasks, and a sweep run by each: the same files, bit for bit, and resume across them."""

import json
import operator
import sys

import numpy as np
import pytest
from licrom import ConfigError, ContactParams, Material, Scene, meshes
from licrom.data.dataset import MANIFEST_NAME, generate_dataset, load_manifest, local_devices
from licrom.executors import check_executor, run_tasks, task_resources
from licrom.scene.placement import drop_state

MATERIAL = Material(youngs_modulus=1e5, poisson_ratio=0.3)
CONTACT = ContactParams(normal_stiffness=1e7, friction_stiffness=1e7)
TIMINGS = ("step_seconds",)  # wall-clock time of each step: the only array that differs between runs


@pytest.fixture(scope="session")
def ray_cluster():
    """A local Ray cluster of 2 CPUs for the whole session (started once: it takes seconds)."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def _sweep(out, **kw):
    """4 runs (2 frictions x 2 slopes) of 5 steps of an 84-tet cheese dropped onto inclines."""
    mesh = meshes.cheese(resolution=4)
    scene = Scene(material=MATERIAL, contact=CONTACT)
    state = drop_state(mesh, MATERIAL.density, height=0.002, rotation=(0.1, 0.05, 0.0))
    return generate_dataset(out, mesh, scene, frictions=[0.2, 0.7], planes=[10.0, 30.0], initial_states=[state], steps=5,
                            initial_frame="plane", progress=False, name="sweep", device="cpu", **kw)


def _contents(out):
    """Every trajectory file's header and arrays (timings left out), by file name."""
    result = {}
    for entry in load_manifest(out)["trajectories"]:
        with np.load(out / entry["file"], allow_pickle=False) as data:
            result[entry["file"]] = {k: data[k] for k in data.files if k not in TIMINGS}
    return result


def _assert_same_files(a, b):
    ca, cb = _contents(a), _contents(b)
    assert sorted(ca) == sorted(cb) and len(ca) == 4
    for name in ca:
        assert sorted(ca[name]) == sorted(cb[name])
        for key, value in ca[name].items():
            assert value.dtype == cb[name][key].dtype and value.shape == cb[name][key].shape, (name, key)
            assert value.tobytes() == cb[name][key].tobytes(), (name, key)


def _runs(out):
    m = load_manifest(out)
    assert m["complete"]
    return [(e["index"], e["file"], e["status"], e["skipped"], e["device"]) for e in m["trajectories"]]


def test_run_tasks_gives_every_result_once_on_each_executor():
    args = [(i, 3) for i in range(5)]
    for jobs in (None, 1, 2):
        assert sorted(run_tasks(operator.mul, args, "local", jobs)) == [(i, 3 * i) for i in range(5)]


def test_a_failing_task_raises_in_the_caller():
    with pytest.raises(ZeroDivisionError):
        list(run_tasks(operator.truediv, [(1, 1), (1, 0), (2, 1)], "local", 2))


def test_executor_arguments_are_checked():
    assert check_executor("local", None) == ("local", 1) and check_executor("local", 3) == ("local", 3)
    with pytest.raises(ConfigError, match="executor must be one of local, ray"):
        check_executor("dask", None)
    for jobs in (0, -1, 1.5, True):
        with pytest.raises(ConfigError, match="jobs must be an integer >= 1"):
            check_executor("local", jobs)
    with pytest.raises(ConfigError, match="jobs applies to executor 'local' only"):
        check_executor("ray", 2)


def test_ray_tasks_ask_for_a_gpu_where_the_cluster_has_gpus(ray_cluster):
    assert task_resources({"CPU": 64.0, "GPU": 8.0}) == {"num_cpus": 1, "num_gpus": 1}
    assert task_resources({"CPU": 64.0}) == task_resources({"CPU": 2.0, "GPU": 0.0}) == {"num_cpus": 1, "num_gpus": 0}
    assert task_resources(ray_cluster.cluster_resources())["num_gpus"] == 0  # this test's cluster: 2 CPUs


def test_local_processes_take_the_gpus_in_turn(monkeypatch):
    from licrom.full import device as device_module

    warp = device_module.warp_ready()
    monkeypatch.setattr(warp, "get_cuda_device_count", lambda: 3)
    assert local_devices("cuda", 4) == ["cuda:0", "cuda:1", "cuda:2"]
    assert local_devices("cuda", 1) == ["cuda"] and local_devices("cuda:1", 4) == ["cuda:1"] and local_devices("cpu", 4) == ["cpu"]
    monkeypatch.setattr(warp, "get_cuda_device_count", lambda: 1)
    assert local_devices("cuda", 4) == ["cuda"]


def test_nothing_to_run_starts_no_ray_cluster(monkeypatch):
    import types

    def init(**kw):
        raise AssertionError("ray.init called without tasks")

    monkeypatch.setitem(sys.modules, "ray", types.SimpleNamespace(is_initialized=lambda: False, init=init))
    assert list(run_tasks(operator.mul, [], "ray")) == []


def test_ray_missing_is_a_config_error_naming_the_extra(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    for args in ([(1, 2)], []):
        with pytest.raises(ConfigError, match=r'pip install "licrom\[ray\]"'):
            list(run_tasks(operator.mul, args, "ray"))
    with pytest.raises(ConfigError, match="Ray"):
        _sweep(tmp_path / "no_ray", executor="ray")


def test_a_ray_address_where_nothing_answers_is_refused_in_bounded_time(monkeypatch, tmp_path):
    import socket
    import time
    import types

    from licrom import executors

    def init(**kw):
        raise AssertionError("ray.init called: it retries an address where nothing answers for minutes")

    monkeypatch.setitem(sys.modules, "ray", types.SimpleNamespace(is_initialized=lambda: False, init=init))
    with socket.socket() as s:  # a port nothing listens on: the connection is refused at once
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{port}")
    with pytest.raises(ConfigError, match=rf"no Ray cluster at RAY_ADDRESS='127.0.0.1:{port}' \(.*refused\); start one there"):
        list(run_tasks(operator.mul, [(1, 2)], "ray"))

    def silent(address, timeout):  # an address that never answers (a firewall dropping packets)
        time.sleep(timeout)
        raise TimeoutError("timed out")

    monkeypatch.setattr(executors.socket, "create_connection", silent)
    monkeypatch.setenv("RAY_ADDRESS", "ray://10.9.8.7:10001")
    start = time.perf_counter()
    with pytest.raises(ConfigError, match=r"RAY_ADDRESS='ray://10.9.8.7:10001' \(nothing answered within 0.2 s\).* now 0.2 s"):
        list(run_tasks(operator.mul, [(1, 2)], "ray", ray_timeout=0.2))
    monkeypatch.setenv("LICROM_RAY_TIMEOUT", "0.1")
    with pytest.raises(ConfigError, match=r"nothing answered within 0.1 s"):
        _sweep(tmp_path / "sweep", executor="ray")
    assert time.perf_counter() - start < 5
    assert executors.RAY_TIMEOUT == 30.0 and executors.check_ray_timeout(45) == 45.0
    for bad in (0, -1.0, float("nan"), float("inf"), True, "10"):
        with pytest.raises(ConfigError, match=r"ray_timeout must be a finite number of seconds > 0"):
            list(run_tasks(operator.mul, [(1, 2)], "ray", ray_timeout=bad))
    monkeypatch.setenv("LICROM_RAY_TIMEOUT", "soon")
    with pytest.raises(ConfigError, match=r"LICROM_RAY_TIMEOUT must be a finite number of seconds > 0, got 'soon'"):
        list(run_tasks(operator.mul, [(1, 2)], "ray"))
    monkeypatch.delenv("LICROM_RAY_TIMEOUT")
    monkeypatch.setenv("RAY_ADDRESS", "nowhere")
    with pytest.raises(ConfigError, match=r"RAY_ADDRESS must be host:port or ray://host:port"):
        list(run_tasks(operator.mul, [(1, 2)], "ray"))


def test_local_pool_writes_the_serial_files_and_a_rerun_skips_them(tmp_path):
    serial, pool = tmp_path / "serial", tmp_path / "pool"
    _sweep(serial)
    _sweep(pool, jobs=2)
    _assert_same_files(serial, pool)
    runs = _runs(pool)
    assert [r[0] for r in runs] == [0, 1, 2, 3]  # in sweep order, whatever order they finished in
    assert all(status == "done" and not skipped and device == "cpu" for _, _, status, skipped, device in runs)
    m = json.loads((pool / MANIFEST_NAME).read_text())
    assert m["executor"] == "local" and m["jobs"] == 2
    assert not [f for f in pool.iterdir() if f.name.startswith(".")]  # no temporary files left
    # The serial executor finds the pool's files finished, and the pool the serial ones.
    _sweep(pool)
    _sweep(serial, jobs=2)
    assert all(r[3] for r in _runs(pool)) and all(r[3] for r in _runs(serial))


def test_ray_writes_the_local_files_and_resumes_across_executors(tmp_path, ray_cluster):
    local, on_ray = tmp_path / "local", tmp_path / "ray"
    _sweep(local)
    _sweep(on_ray, executor="ray")
    _assert_same_files(local, on_ray)
    runs = _runs(on_ray)
    assert [r[0] for r in runs] == [0, 1, 2, 3]
    assert all(status == "done" and not skipped and device == "cpu" for _, _, status, skipped, device in runs)
    assert json.loads((on_ray / MANIFEST_NAME).read_text())["executor"] == "ray"
    # One file lost: Ray redoes that one only, the same as before; the rest are skipped.
    lost = runs[2][1]
    before = _contents(on_ray)[lost]
    (on_ray / lost).unlink()
    _sweep(on_ray, executor="ray")
    assert [r[3] for r in _runs(on_ray)] == [True, True, False, True]
    assert all(v.tobytes() == before[k].tobytes() for k, v in _contents(on_ray)[lost].items())
    # Files made by the local executor are finished for Ray, and the other way round.
    _sweep(local, executor="ray")
    _sweep(on_ray)
    assert all(r[3] for r in _runs(local)) and all(r[3] for r in _runs(on_ray))
