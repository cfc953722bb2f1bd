"""Batches split over devices and processes (dano.sharding, issue 31): the same results as one
device on 8 forced host devices, and one identification split over two jax.distributed
processes on the loopback address giving the same estimate as one process. Both run in
processes of their own (tests/sharding_worker.py): the device count and jax.distributed must
be set before JAX starts. Plus the helpers and the bad input, in this process (one device)."""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import dano
from dano import sharding
from dano.cli import main
from dano.errors import DanoError

from .sharding_worker import IDENTIFY, SCAN_FRICTIONS, box_scene, load_observation, slide_problem

WORKER = Path(__file__).with_name("sharding_worker.py")
DANO_ROOT = Path(dano.__file__).resolve().parents[1]  # the workers import the dano this process imported


def _env(**extra) -> dict:
    env = dict(os.environ, **extra)
    env.pop("DANO_EXPORT_CACHE", None)  # the exported programs' disk cache on (dano._compiled)
    env["PYTHONPATH"] = os.pathsep.join([str(DANO_ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    return env


def test_devices_are_checked_naming_the_option(capsys):
    n = jax.local_device_count()
    for bad in (0, -1, n + 1, 1.5, True):
        with pytest.raises(DanoError, match=r"^--devices must be 1 to \d+ .*got") as info:
            sharding.check_devices(bad, "--devices")
        assert "\n" not in str(info.value)
    assert sharding.check_devices(None) == n and sharding.check_devices(1) == 1
    with sharding.use_devices(1):
        assert sharding.devices_in_use() == 1 and sharding.batch_mesh().size == 1
    assert sharding.devices_in_use() == n
    for verb in (["bench", "--suite", "batched"], ["sysid", "soap"]):  # refused before any work
        assert main(verb + ["--devices", "0"]) == 1
        err = capsys.readouterr().err
        assert "--devices must be 1 to" in err and "got 0" in err and len(err.strip().splitlines()) == 1


def test_padding_shards_and_shares():
    x = np.arange(10.0).reshape(5, 2)
    tree = {"a": x, "b": (jnp.asarray(x[:, 0]),)}
    padded = sharding.pad_rows(tree, 8)
    assert padded["a"].shape == (8, 2) and np.all(padded["a"][5:] == x[-1])
    assert isinstance(padded["b"][0], jax.Array) and np.all(np.asarray(padded["b"][0])[5:] == 8.0)
    with pytest.raises(DanoError, match="cannot pad a batch of 5 rows to 4"):
        sharding.pad_rows(x, 4)
    assert [sharding.padded_size(r, 3) for r in (1, 3, 4, 6, 7)] == [3, 3, 6, 6, 9]
    with sharding.use_devices(1):
        assert sharding.shards_for(100) == 1 and sharding.mesh_of_size(1) is None
    for count in (0, 1, 7, 10):
        parts = [list(sharding.share(count, p, 3)) for p in range(3)]
        assert sum(parts, []) == list(range(count))  # every item once, in order
        assert max(map(len, parts)) - min(map(len, parts)) <= 1
    assert sharding.load_shares(["a", "bb"], len) == [1, 2] and sharding.allgather_objects({"x": 1}) == [{"x": 1}]


def test_sharded_vmap_on_one_device_is_vmap():
    def f(x, y, w):
        return jnp.sin(x * w) + y.sum(), x * 2

    x, y, w = jnp.linspace(0, 1, 5), jnp.ones((5, 3)), jnp.asarray(0.7)
    got = sharding.sharded_vmap(f, (0, 0, None), devices=1)(x, y, w)
    ref = jax.vmap(f, in_axes=(0, 0, None))(x, y, w)
    assert all(np.array_equal(a, b) for a, b in zip(got, ref))
    # compiled with its XLA options at the top level (an unknown one is refused there, so
    # they are passed); inside the user's jit or grad (JAX takes compiler options on a
    # top-level jit only) traced into theirs without them, same numbers
    from dano._jax_setup import YNN_OPTION

    with pytest.raises(Exception, match="no_such_option"):
        sharding.sharded_vmap(f, (0, 0, None), devices=1, compiler_options={"no_such_option": 1})(x, y, w)
    bogus = sharding.sharded_vmap(f, (0, 0, None), devices=1, compiler_options={"no_such_option": 1})
    assert all(np.array_equal(a, b) for a, b in zip(jax.jit(lambda x: bogus(x, y, w))(x), ref))
    with pytest.raises(DanoError, match="compiler_options must be a mapping"):
        sharding.sharded_vmap(f, compiler_options="WHILE")
    run = sharding.sharded_vmap(f, (0, 0, None), devices=1, compiler_options={YNN_OPTION: ""})
    assert all(np.array_equal(a, b) for a, b in zip(run(x, y, w), ref))
    inside = jax.jit(lambda x: run(x, y, w))(x)
    assert all(np.array_equal(a, b) for a, b in zip(inside, ref))
    g = jax.grad(lambda x: run(x, y, w)[0].sum())(x)
    np.testing.assert_allclose(g, w * jnp.cos(x * w), rtol=1e-12)
    with pytest.raises(DanoError, match="in_axes must be 0 or None"):
        sharding.sharded_vmap(f, (0, 1, None))(x, y, w)
    with pytest.raises(DanoError, match="at least one argument with axis 0"):
        sharding.sharded_vmap(f, None)(x, y, w)


def test_rows_mapped_in_chunks_equal_the_vmap():
    def f(x, y, w):
        return jnp.sin(x * w) + y.sum(), x * 2

    x, y, w = jnp.linspace(0, 1, 7), jnp.arange(21.0).reshape(7, 3), jnp.asarray(0.7)
    ref = jax.vmap(f, in_axes=(0, 0, None))(x, y, w)
    for size in (None, 1, 3, 7):  # 3: two chunks and a remainder of one
        got = jax.jit(sharding.map_rows(f, (0, 0, None), size))(x, y, w)
        assert all(np.array_equal(a, b) for a, b in zip(got, ref)), size


def test_batched_residuals_in_chunks_are_each_vectors_own(monkeypatch):
    """On a CPU the batch's vectors run a chunk at a time (sysid.problem.batch_chunk): the
    residuals of 5 vectors (padded to a batch of 16) one at a time and 3 at a time (a
    remainder) are those of each vector alone, in the order given."""
    from dano.experiments.sysid_examples import analytic_slides
    from dano.sysid import problem as sysid_problem

    dano.enable_float64()
    problem = slide_problem(box_scene(), analytic_slides(0, 0.05, 3, frames=12))
    thetas = np.array([[0.2], [0.3], [0.45], [0.6], [0.9]])
    got = {}
    monkeypatch.setattr(sysid_problem, "CPU_ROLLOUTS_PER_CHUNK", 10**9)
    assert sysid_problem.batch_chunk(problem.layout, sysid_problem.BATCH) is None  # one vmap
    for per_chunk in (4, 12):  # 4 padded segments: 1 vector a chunk, 3
        monkeypatch.setattr(sysid_problem, "CPU_ROLLOUTS_PER_CHUNK", per_chunk)
        expected = {4: 1, 12: 3}[per_chunk] if jax.default_backend() == "cpu" else None
        assert sysid_problem.batch_chunk(problem.layout, sysid_problem.BATCH) == expected
        got[per_chunk] = problem.batch_residuals(thetas)
    alone = np.stack([problem.residuals(t) for t in thetas])
    for per_chunk, r in got.items():
        np.testing.assert_allclose(r, alone, rtol=0, atol=1e-12, err_msg=str(per_chunk))
    assert np.ptp(np.sum(alone**2, axis=1)) > 1e-3  # the vectors give different residuals: order would show


def test_distributed_settings_are_checked(monkeypatch):
    for env, value, message in (("DANO_NUM_PROCESSES", "two", r"\$DANO_NUM_PROCESSES must be an integer"),
                                ("DANO_PROCESS_ID", "2", r"process_id \(\$DANO_PROCESS_ID\) must be 0 to 1, got 2"),
                                ("DANO_COORDINATOR_ADDRESS", "localhost", r"must be host:port")):
        with monkeypatch.context() as m:
            m.setenv("DANO_NUM_PROCESSES", "2")
            m.setenv("DANO_PROCESS_ID", "0")
            m.setenv("DANO_COORDINATOR_ADDRESS", "127.0.0.1:1234")
            m.setenv(env, value)
            with pytest.raises(DanoError, match=message):
                sharding.initialize()
    monkeypatch.setenv("DANO_NUM_PROCESSES", "2")
    monkeypatch.setenv("DANO_PROCESS_ID", "1")
    monkeypatch.setenv("DANO_COORDINATOR_ADDRESS", "127.0.0.1:1234")
    jnp.zeros(1).block_until_ready()  # this process has computed (whichever tests ran before this one)
    with pytest.raises(DanoError, match="before any JAX computation"):
        sharding.initialize_from_environment()
    monkeypatch.delenv("DANO_NUM_PROCESSES")
    assert sharding.initialize_from_environment() is None


@pytest.mark.slow  # 14-20 s with warm compilation caches, 36-90 s cold on the 2-core machine
def test_sharded_equals_unsharded_on_8_host_devices(tmp_path):
    """Rollouts under vmap (5 rows: padded to 6 on 2 devices, 5 of 8), the identification
    residual and its Jacobian (3 trajectories: split over 2 devices, padded to 4; over 3 of
    the 8) and the scan's batch, on 2 and 8 of 8 forced host devices, against 1 device, in
    float64; the 8-device programs loaded again from disk give the same."""
    out = tmp_path / "devices.json"
    proc = subprocess.run([sys.executable, str(WORKER), "devices", str(out)], capture_output=True, text=True,
                          timeout=600, env=_env(XLA_FLAGS="--xla_force_host_platform_device_count=8"))
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(out.read_text())
    assert report["devices"] == 8
    assert "--xla_force_host_platform_device_count=8" in report["xla_flags"]
    assert "--xla_cpu_use_fusion_emitters=false" in report["xla_flags"]  # dano's flag kept beside it
    ref = report["reference"]
    assert ref["finite"] and ref["jacobian_norm"] > 0 and ref["rollout_spread"] > 1e-3
    for n in (2, 8):
        got = report[f"devices_{n}"]
        assert got["rollout_shapes"] == ref["rollout_shapes"] and got["shapes"] == ref["shapes"]
        for key in ("rollout_max_abs_diff", "residual_max_abs_diff", "jacobian_max_abs_diff", "scan_max_abs_diff"):
            assert got[key] <= 1e-12, (n, key, got[key])
    # the sharded programs were exported to disk and load in place of tracing (dano._compiled)
    assert report["reloaded"]["programs_loaded"] == 2 and report["reloaded"]["max_abs_diff"] <= 1e-12


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow  # 22-32 s with warm caches (three processes on two cores), 60-100 s cold
def test_two_processes_identify_as_one(tmp_path):
    """Four trajectory files; two jax.distributed processes (CPU collectives by gloo, one
    device each) each load two of them, split the identification's rollouts between them and
    gather the residual and Jacobian: the same estimate, cost and scan as one process."""
    from dano.experiments.sysid_examples import analytic_slides
    from dano.sysid import identify

    data = tmp_path / "data"
    data.mkdir()
    for o in analytic_slides(1, 0.05, 4, frames=16):
        np.savez(data / f"{o.name}.npz", time=o.time, poses=o.poses["box"], qvel0=o.qvel0)
    port = _free_port()
    outs = [tmp_path / f"process{i}.json" for i in range(2)]
    procs = [subprocess.Popen([sys.executable, str(WORKER), "identify", str(outs[i]), str(data), str(port), "2",
                               str(i)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env())
             for i in range(2)]
    deadline, logs = time.monotonic() + 300, []
    try:
        for p in procs:
            logs.append(p.communicate(timeout=max(1.0, deadline - time.monotonic()))[0])
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    assert all(p.returncode == 0 for p in procs), "\n".join(log[-2000:] for log in logs)

    files = sorted(data.glob("*.npz"))
    problem = slide_problem(box_scene(), [load_observation(f) for f in files])
    one = identify(problem, **IDENTIFY)
    scan = 0.5 * np.sum(problem.batch_residuals(np.array(SCAN_FRICTIONS)) ** 2, axis=1)
    reports = [json.loads(o.read_text()) for o in outs]
    assert [r["loaded_here"] for r in reports] == [["slide_0.npz", "slide_1.npz"], ["slide_2.npz", "slide_3.npz"]]
    for r in reports:
        assert r["processes"] == 2 and r["devices"] == 2 and r["success"]
        assert r["observations"] == [f.stem for f in files]
        np.testing.assert_allclose(r["estimates"], one.estimates, rtol=1e-10)
        np.testing.assert_allclose(r["final_cost"], one.final_cost, rtol=1e-10)
        np.testing.assert_allclose(r["scan_costs"], scan, rtol=1e-10)
        assert r["nfev"] == one.nfev
    assert abs(one.estimates[0] - 0.45) < 0.05  # the slides' friction: a real fit, not a start left alone
