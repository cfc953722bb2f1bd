"""Compiled once per structure, across processes (dano._compiled, issue 32 item 1): a second
process loads the traced program instead of tracing it, with bit-identical results; another
structure traces anew; tracers get plain jax.jit; a damaged file is traced again."""

import dataclasses
import hashlib
import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano import _compiled
from dano._compiled import cached_jit, shape_bucket

# A box DANO sliding on the ground in a fresh process: prints the program counts and the
# final state. argv: cache folder, time step, steps.
SCRIPT = textwrap.dedent("""
    import json, sys
    import dano
    dano.enable_float64()
    dano.enable_compilation_cache(sys.argv[1])
    from dano import _compiled
    from dano.asset import build
    from dano.fields import BoxField
    from dano.sim import DanoObject, State, compose, rollout
    asset = build(BoxField((0.05, 0.05, 0.05)), mass=0.3, num_samples=300, mesh_resolution=0, name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=float(sys.argv[2]))
    qvel = [0.5, 0, 0, 0, 0, 0]
    traj = rollout(scene, State(scene.qpos0, qvel), steps=int(sys.argv[3]))
    print(json.dumps({"counts": dict(_compiled.COUNTS), "qpos": traj.qpos[-1].tolist(),
                      "compile_s": _compiled.COMPILE_SECONDS[0]}))
""")


def _run(cache, dt="0.01", steps="30"):
    env = {**os.environ, "NPROC": "1"}
    env.pop("DANO_EXPORT_CACHE", None)
    out = subprocess.run([sys.executable, "-c", SCRIPT, str(cache), dt, steps], capture_output=True, text=True,
                         env=env, timeout=600)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_second_process_loads_the_program_and_another_structure_traces_anew(tmp_path):
    first = _run(tmp_path)
    assert first["counts"].get("traced", 0) >= 1 and first["counts"].get("loaded", 0) == 0
    saved = sorted((tmp_path / "dano-exported").glob("*.jaxexp"))
    assert saved
    second = _run(tmp_path)
    assert second["counts"].get("traced", 0) == 0 and second["counts"].get("loaded", 0) >= 1
    assert second["qpos"] == first["qpos"]  # the same program: bit-identical
    # another structure (the time step is static, the step count a shape): traced anew
    third = _run(tmp_path, dt="0.005", steps="40")
    assert third["counts"].get("traced", 0) >= 1
    # a damaged program is removed and traced again, with the same result
    saved[0].write_bytes(b"dano-exported-1\n" + b"\0" * 20)
    fourth = _run(tmp_path)
    assert fourth["counts"].get("traced", 0) >= 1 and fourth["qpos"] == first["qpos"]


def _affine(scale, x, y):
    return {"sum": scale * x + y, "max": jnp.max(x)}


def test_values_are_arguments_statics_and_shapes_are_the_key(tmp_path, monkeypatch):
    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    try:
        f = cached_jit(_affine, static_argnums=(0,))
        a = f(2.0, jnp.arange(3.0), jnp.ones(3))
        b = f(2.0, jnp.arange(3.0) + 1, jnp.zeros(3))  # other values: the same program
        assert f.counts["traced"] == 1 and np.allclose(a["sum"], [1, 3, 5]) and np.allclose(b["sum"], [2, 4, 6])
        f(3.0, jnp.arange(3.0), jnp.ones(3))  # another static value
        f(2.0, jnp.arange(4.0), jnp.ones(4))  # another shape
        assert f.counts["traced"] == 3 and len(list(tmp_path.glob("*.jaxexp"))) == 3
        f.clear()  # as a new process would: loaded from disk, not traced
        c = f(2.0, jnp.arange(3.0), jnp.ones(3))
        assert f.counts["traced"] == 3 and f.counts["loaded"] == 1 and np.array_equal(c["sum"], a["sum"])
        # under a transformation (tracers): plain jax.jit, differentiable
        g = jax.grad(lambda x: f(2.0, x, jnp.ones(3))["sum"].sum())(jnp.arange(3.0))
        assert np.allclose(g, 2.0) and f.counts["traced"] == 3
        # a static argument that cannot be digested by content: plain jax.jit
        h = cached_jit(lambda fn, x: fn(x), static_argnums=(0,))
        assert np.allclose(h(jnp.sin, jnp.zeros(2)), 0.0) and h.counts["traced"] == 0 and h.counts["jit"] == 1
    finally:
        _compiled.set_directory(None)


_TRACES = []


def _slow_to_trace(tag, x):
    import threading
    import time

    start = time.perf_counter()
    time.sleep(0.2)  # (Python's lock released: another thread's trace could run meanwhile)
    _TRACES.append((tag, threading.get_ident(), start, time.perf_counter()))
    return x * 2.0


def test_threads_trace_one_at_a_time_and_a_structure_once(tmp_path, monkeypatch):
    """Programs traced from threads (a program compiling in the background while another is
    traced, dano._threads.in_background) are traced one after the other, and two threads
    asking for the same structure trace it once."""
    from concurrent.futures import ThreadPoolExecutor

    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    _TRACES.clear()
    try:
        f = cached_jit(_slow_to_trace, static_argnums=(0,))
        with ThreadPoolExecutor(4) as pool:
            out = list(pool.map(lambda a: f(*a), [("a", jnp.ones(2)), ("b", jnp.ones(2)), ("a", jnp.ones(2)),
                                                   ("b", jnp.ones(3))]))
        assert all(np.allclose(o, 2.0) for o in out)
        assert sorted(t[0] for t in _TRACES) == ["a", "b", "b"] and f.counts["traced"] == 3
        spans = sorted((t[2], t[3]) for t in _TRACES)
        assert all(later[0] >= earlier[1] for earlier, later in zip(spans, spans[1:]))  # no two at once
    finally:
        _compiled.set_directory(None)


def test_off_without_the_compilation_cache(monkeypatch):
    monkeypatch.setenv("DANO_EXPORT_CACHE", "0")
    f = cached_jit(_affine, static_argnums=(0,))
    assert np.allclose(f(1.0, jnp.ones(2), jnp.ones(2))["sum"], 2.0)
    assert f.counts["traced"] == 0 and f.counts["jit"] == 1


def test_a_call_on_its_own_output_compiles_once(tmp_path, monkeypatch):
    """A program continued from its own (committed) output beside fresh (uncommitted) inputs,
    as a rollout in chunks is, runs the one compiled executable: JAX lowers a jitted call
    once per pattern of committed arguments, and `dano simulate` compiled its rollout twice."""
    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    try:
        f = cached_jit(_affine, static_argnums=(0,))
        out = f(2.0, jnp.arange(3.0), jnp.ones(3))
        assert out["sum"].committed  # (what the next call is given)
        out = f(2.0, out["sum"], np.zeros(3))  # committed beside a NumPy array
        out = f(2.0, jnp.arange(3.0), out["sum"])
        (program,) = f._by_digest.values()
        assert f.counts["traced"] == 1 and program[0]._cache_size() == 1
        np.testing.assert_allclose(out["sum"], [2, 8, 14])
    finally:
        _compiled.set_directory(None)


@dataclasses.dataclass(frozen=True)
class _Scaled:
    """A static argument with a label that no trace reads (left out of the program's key)."""

    scale: float
    label: str = dataclasses.field(default="", metadata={"cache_key": False})


def _scaled(s, x):
    return s.scale * x


def _digest(x) -> bytes:
    h = hashlib.sha256()
    _compiled._digest_value(x, h)
    return h.digest()


def test_labels_are_not_in_the_key(tmp_path, monkeypatch):
    """Fields marked cache_key=False (a scene's name, an asset's provenance) are left out of the
    key: a problem built from a TOML, a saved config or a loaded .dano under another name loads
    the program instead of tracing it again; the values that a trace reads stay in the key."""
    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    try:
        f = cached_jit(_scaled, static_argnums=(0,))
        a = f(_Scaled(2.0, "first"), jnp.arange(3.0))
        b = f(_Scaled(2.0, "second"), jnp.arange(3.0))
        assert f.counts["traced"] == 1 and np.array_equal(a, b)
        f(_Scaled(3.0, "first"), jnp.arange(3.0))  # another value that the trace reads
        assert f.counts["traced"] == 2
    finally:
        _compiled.set_directory(None)
    from dano.asset import build
    from dano.fields import BoxField
    from dano.sim import DanoObject, compose

    asset = build(BoxField((0.05, 0.05, 0.05)), mass=0.3, num_samples=64, mesh_resolution=0, name="box")
    renamed = dataclasses.replace(asset, metadata={**asset.metadata, "source": "elsewhere.obj"})
    one, two = (compose([DanoObject("box", a, (0, 0, 0.05))], dt=0.01, name=n)
                for a, n in ((asset, "one"), (renamed, "two")))
    assert one.info.name != two.info.name and _digest(one.info) == _digest(two.info)
    assert _digest(asset) == _digest(renamed) != _digest(asset.scaled(2.0))


@pytest.mark.parametrize("cache", [True, False])
def test_compiler_options_on_top_level_calls_only(tmp_path, monkeypatch, cache):
    # a function with compiler options (a rollout's: no YNNPACK fusions on the CPU) takes
    # them on a call with concrete arguments; called inside the user's jax.jit, even with
    # concrete arguments only (closed over), it is traced into that jit as plain jax.jit
    # (JAX refuses compiler_options on a nested jit), with the disk cache on or off
    from dano._jax_setup import YNN_OPTION, batched_compiler_options, rollout_compiler_options

    if cache:
        monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
        _compiled.set_directory(tmp_path)
    else:
        monkeypatch.setenv("DANO_EXPORT_CACHE", "0")
    try:
        f = cached_jit(_affine, static_argnums=(0,), compiler_options=rollout_compiler_options)
        x, y = jnp.ones(2), jnp.arange(2.0)
        top = f(2.0, x, y)["sum"]
        inside = jax.jit(lambda: f(2.0, x, y)["sum"])()
        np.testing.assert_array_equal(top, _affine(2.0, x, y)["sum"])
        np.testing.assert_array_equal(inside, top)
        if jax.default_backend() == "cpu":  # this jaxlib knows the option
            assert rollout_compiler_options() == {YNN_OPTION: ""}
            assert batched_compiler_options() == {}  # batched programs keep XLA's defaults on the CPU
            assert f.lower(2.0, x, y).compile() is not None  # lower: that of the top-level jit
    finally:
        _compiled.set_directory(None)


@dataclasses.dataclass(frozen=True)
class _WithHostFacts:
    """A static argument with a value that traces read and host-side facts that they must not."""

    scale: float
    facts: tuple = dataclasses.field(default=(), metadata=_compiled.HOST_ONLY)


def _reads_scale(s, x):
    return s.scale * x


def _reads_facts(s, x):
    return s.facts[0] * x


def test_host_only_fields_are_left_out_of_the_key_and_hidden_from_traces(tmp_path, monkeypatch):
    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    try:
        f = cached_jit(_reads_scale, static_argnums=(0,))
        a = f(_WithHostFacts(2.0, (1.0,)), jnp.arange(3.0))
        b = f(_WithHostFacts(2.0, (5.0,)), jnp.arange(3.0))  # other host facts: the same program
        assert f.counts["traced"] == 1 and np.array_equal(a, b)
        # a trace that reads a host-only fact would bake in what its key does not hold: it fails
        saved = set(tmp_path.glob("*.jaxexp"))
        g = cached_jit(_reads_facts, static_argnums=(0,))
        with pytest.raises(_compiled.TracedHostOnlyError, match="_WithHostFacts.facts is host-only"):
            g(_WithHostFacts(2.0, (1.0,)), jnp.arange(3.0))
        assert set(tmp_path.glob("*.jaxexp")) == saved  # (nothing kept)
    finally:
        _compiled.set_directory(None)


def test_objects_of_the_same_structure_share_their_programs(tmp_path, monkeypatch):
    """Issue 32 item 1, 'every new object pays this again': two objects of one structure
    (as many samples, other shapes, masses, visual meshes and names) share the rollout's
    program, and the second object's rollout from the shared program equals a rollout traced
    for it alone (plain jax.jit, no disk cache) bit for bit."""
    import dano
    from dano.asset import build
    from dano.fields import BoxField, SphereField
    from dano.sim import DanoObject, State, compose, rollout
    from dano.sim.rollout import _scan_steps_compiled

    dano.enable_float64()
    box = build(BoxField((0.06, 0.04, 0.03)), mass=0.3, num_samples=300, mesh_resolution=12, name="box")
    ball = build(SphereField(0.03), mass=0.2, num_samples=300, mesh_resolution=16, name="ball")
    assert box.mesh_vertices.shape != ball.mesh_vertices.shape  # (other visual meshes)

    def final(asset, name):
        scene = compose([DanoObject(name, asset, (0, 0, 0.05))], dt=0.01, name=name)
        return rollout(scene, State(scene.qpos0, [0.4, 0.1, 0, 0, 0, 1.0]), steps=30).qpos[-1]

    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path)
    try:
        before = _scan_steps_compiled.counts["traced"]
        final(box, "box")
        shared = final(ball, "ball")
        assert _scan_steps_compiled.counts["traced"] - before == 1  # the ball reused the box's program
    finally:
        _compiled.set_directory(None)
    monkeypatch.setenv("DANO_EXPORT_CACHE", "0")
    alone = final(ball, "ball")
    assert np.isfinite(alone).all() and abs(alone[2] - 0.03) < 0.01  # (resting on the ground)
    np.testing.assert_array_equal(shared, alone)


def test_shape_buckets_bound_the_padding():
    """Sizes share a bucket within the bound each bucket promises: three leading binary digits
    (at most 25 % more), and the identification's segment counts 1, 2, 4, 6, 8, 12, … (at most
    1.5×, 3 run as 4); a negative size is refused."""
    from dano.sysid.problem import segment_bucket

    assert [shape_bucket(n) for n in (0, 1, 8, 9, 19, 20, 97, 112, 113)] == [0, 1, 8, 10, 20, 20, 112, 112, 128]
    assert [shape_bucket(n, 1) for n in (3, 5, 64, 65)] == [4, 8, 64, 128]
    assert all(n <= shape_bucket(n) <= 1.25 * n for n in range(1, 5000))
    assert [segment_bucket(n) for n in range(1, 14)] == [1, 2, 4, 4, 6, 6, 8, 8, 12, 12, 12, 12, 16]
    assert all(n <= segment_bucket(n) <= 1.5 * n for n in range(1, 5000))
    with pytest.raises(ValueError, match="n >= 0"):
        shape_bucket(-1)
